"""MLS-MPM (moving least squares material point method) as Dr.Jit array programs.

The benchmark's ground-truth engine (and, in a later issue, the PAC-NeRF baseline): a
different physics model from the spring-mass system, so fitting its output is no inverse crime.

Method (Hu et al. 2018, "A moving least squares material point method", with APIC transfers):
- quadratic B-spline weights over the 3x3x3 grid nodes around each particle;
- P2G by atomic scatter-add (`dr.scatter_add`) of mass and APIC momentum
  m v + (m C - dt V 4/Δx² τ) (x_i - x_p), τ the Kirchhoff stress;
- grid update: v = p / m, gravity, linear air drag, slip walls at the domain sides, and a
  ground-plane collider (`sticky`, `slip`, Coulomb `friction` with coefficient μ) on the
  nodes less than Δx/2 above the plane;
- G2P by gather: v_p = Σ w v_i, C_p = 4/Δx² Σ w v_i (x_i - x_p)ᵀ, x += dt v_p,
  F ← (I + dt C_p) F, then an optional von Mises return mapping (plastic yield).

Constitutive laws (Kirchhoff stress τ = P Fᵀ, Lamé μ, λ from E, ν):
- `neo_hookean`, the compressible form PAC-NeRF uses: τ = μ (F Fᵀ - I) + λ ln J I;
- `fixed_corotated`: τ = 2μ (F - R) Fᵀ + λ (J - 1) J I, R from `dr.polar_decomp`.

Split as in the rest of sgdr: `MPMModel` never changes (grid, particle masses and volumes,
collider, time step), `MPMParams` holds what a later issue differentiates (global E, ν, v0,
gravity, drag, yield stress: Dr.Jit arrays of width 1), `MPMState` evolves (x, v, C, F).
A substep is a pure function `substep(model, params, state) -> state`.

Units: scene units (the benchmark's unit cube = 1) for length, seconds, kg; E in Pa.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import drjit as dr
import numpy as np

from sgdr.arrays import to_numpy
from sgdr.backend import ad
from sgdr.registry import Registry
from sgdr.synth.linalg import diag_conjugate, outer, sym_eig3


class MPMError(RuntimeError):
    """An MPM setting that cannot work (time step beyond CFL, particles leaving the grid...)."""


# ---------------------------------------------------------------------------- data
@dataclass
class MPMModel:
    """What never changes during a simulation."""

    n_grid: int  # grid nodes per side; the grid spans origin + [0, n_grid Δx]^3
    dx: float  # Δx, node spacing, scene units
    origin: tuple  # (3,) world position of node (0, 0, 0)
    dt: float  # substep, seconds
    particle_mass: object  # Float [P], kg
    particle_vol: object  # Float [P], rest volume, scene units³
    particle_E_scale: object  # Float [P], E of the particle / global E (heterogeneity)
    material: str  # constitutive law: "neo_hookean" | "fixed_corotated"
    collider: str  # ground collider: "sticky" | "slip" | "friction"
    friction: float  # Coulomb μ of the "friction" collider
    ground_point: tuple  # (3,) a point on the ground plane, world
    ground_normal: tuple  # (3,) unit normal pointing up, away from the ground
    wall_cells: int  # nodes this close to a domain side are slip walls
    plastic: bool  # apply the von Mises return mapping (params.yield_stress)
    n_samples: int = 1  # independent simulations batched in one program, each on its own grid
    sample: object = None  # UInt32 [P], the simulation of each particle (n_samples > 1); params.E/nu [n_samples]

    @property
    def n_particles(self) -> int:
        return dr.width(self.particle_mass)

    def particle_E_nu(self, params):
        """(E, ν) of every particle: the global values times the heterogeneity, or, for a batch,
        the particle's own simulation's values (params.E, params.nu of width n_samples)."""
        t = ad()
        if self.n_samples == 1:
            return params.E * self.particle_E_scale, params.nu
        E = dr.gather(t.Float, params.E, self.sample)
        return E * self.particle_E_scale, dr.gather(t.Float, params.nu, self.sample)


@dataclass
class MPMParams:
    """Global physical parameters, Dr.Jit arrays of width 1 (differentiable later)."""

    E: object  # Float [1], Young's modulus, Pa
    nu: object  # Float [1], Poisson ratio
    gravity: object  # Array3f [1], m/s² (scene units / s²)
    drag: object  # Float [1], linear air drag rate, 1/s
    yield_stress: object  # Float [1], von Mises yield stress, Pa (used when model.plastic)

    @staticmethod
    def create(E, nu, gravity, drag=0.0, yield_stress=0.0) -> MPMParams:
        t = ad()
        g = [float(c) for c in gravity]
        return MPMParams(
            E=t.Float(float(E)),
            nu=t.Float(float(nu)),
            gravity=t.Array3f(*g),
            drag=t.Float(float(drag)),
            yield_stress=t.Float(float(yield_stress)),
        )


@dataclass
class MPMState:
    """What evolves: particle position x, velocity v, APIC affine C, deformation gradient F."""

    x: object  # Array3f [P], world
    v: object  # Array3f [P], scene units / s
    C: object  # Matrix3f [P], 1/s
    F: object  # Matrix3f [P], elastic deformation gradient

    @staticmethod
    def at_rest(x: np.ndarray, v0) -> MPMState:
        """Undeformed particles at x [P, 3] moving with the common velocity v0.

        v0: three numbers, or an Array3f [1] (keeps its gradient: d/dv0 flows into v).
        """
        t = ad()
        n = len(x)
        X = t.Array3f(np.ascontiguousarray(np.asarray(x, dtype=np.float32).T))
        if not isinstance(v0, t.Array3f):
            v0 = t.Array3f(*[float(c) for c in v0])
        V = v0 + dr.zeros(t.Array3f, n)
        C = dr.zeros(t.Matrix3f, n)
        F = dr.identity(t.Matrix3f, n)
        return MPMState(X, V, C, F)


def create_model(
    x_rest: np.ndarray,  # [P, 3] world
    particle_volume: float,  # rest volume of each particle, scene units³
    density: float,  # kg / scene unit³
    n_grid: int,
    dx: float,
    origin,
    dt: float,
    material: str,
    collider: str,
    friction: float,
    ground_point,
    ground_normal,
    wall_cells: int = 3,
    E_scale: np.ndarray | None = None,  # [P] per-particle E multiplier
    plastic: bool = False,
) -> MPMModel:
    """Build an `MPMModel`; checks the names and that every particle is inside the walls."""
    t = ad()
    CONSTITUTIVE.get_named(material)
    COLLIDERS.get_named(collider)
    n = len(x_rest)
    lo = np.asarray(origin, dtype=np.float64) + wall_cells * dx
    hi = np.asarray(origin, dtype=np.float64) + (n_grid - wall_cells) * dx
    if np.any(x_rest < lo) or np.any(x_rest > hi):
        raise MPMError(
            f"particles outside the MPM domain interior [{lo}, {hi}]: move the object or enlarge synth.mpm_grid"
        )
    normal = np.asarray(ground_normal, dtype=np.float64)
    scale = np.ones(n) if E_scale is None else np.asarray(E_scale, dtype=np.float64)
    return MPMModel(
        n_grid=int(n_grid),
        dx=float(dx),
        origin=tuple(float(c) for c in origin),
        dt=float(dt),
        particle_mass=dr.full(t.Float, float(density * particle_volume), n),
        particle_vol=dr.full(t.Float, float(particle_volume), n),
        particle_E_scale=t.Float(scale.astype(np.float32)),
        material=material,
        collider=collider,
        friction=float(friction),
        ground_point=tuple(float(c) for c in ground_point),
        ground_normal=tuple(float(c) for c in normal / np.linalg.norm(normal)),
        wall_cells=int(wall_cells),
        plastic=bool(plastic),
    )


# ---------------------------------------------------------------------------- material
def lame(E, nu):
    """Lamé parameters (μ, λ) from Young's modulus E and Poisson ratio ν."""
    mu = E / (2.0 * (1.0 + nu))
    lam = E * nu / ((1.0 + nu) * (1.0 - 2.0 * nu))
    return mu, lam


def kirchhoff_neo_hookean(F, mu, lam):
    """τ = μ (F Fᵀ - I) + λ ln J I (PAC-NeRF's compressible Neo-Hookean)."""
    I = dr.identity(type(F))
    J = dr.maximum(dr.det(F), 1e-6)
    return mu * (F @ F.T - I) + (lam * dr.log(J)) * I


def kirchhoff_fixed_corotated(F, mu, lam):
    """τ = 2μ (F - R) Fᵀ + λ (J - 1) J I, with F = R S the polar decomposition."""
    I = dr.identity(type(F))
    R, _ = dr.polar_decomp(F)
    J = dr.det(F)
    return (2.0 * mu) * ((F - R) @ F.T) + (lam * (J - 1.0) * J) * I


CONSTITUTIVE = Registry(
    "MPM material",
    "synth.material",
    MPMError,
    {"neo_hookean": kirchhoff_neo_hookean, "fixed_corotated": kirchhoff_fixed_corotated},
)


def von_mises_return(F, mu, yield_stress):
    """Project F onto the von Mises yield surface in Hencky strain space.

    With b = F Fᵀ = Q diag(λ) Qᵀ the Hencky strain is ε = ½ log λ; the deviatoric Kirchhoff
    stress of the Hencky model is 2μ dev ε. Where ‖2μ dev ε‖ > τ_y, dev ε is scaled back
    radially to the surface: ε' = ε - (‖dev ε‖ - τ_y / 2μ) dev ε / ‖dev ε‖ (volume kept), and
    F' = Q diag(exp(ε' - ε)) Qᵀ F (same rotation, new stretch).
    """
    lam_b, Q = sym_eig3(F @ F.T)
    eps = [0.5 * dr.log(dr.maximum(l, 1e-12)) for l in lam_b]
    mean = (eps[0] + eps[1] + eps[2]) / 3.0
    dev = [e - mean for e in eps]
    norm = dr.sqrt(dr.maximum(dev[0] ** 2 + dev[1] ** 2 + dev[2] ** 2, 1e-20))
    excess = dr.maximum(norm - yield_stress / (2.0 * mu), 0.0)
    shrink = [dr.exp(-excess * d / norm) for d in dev]
    return diag_conjugate(Q, shrink) @ F


# ---------------------------------------------------------------------------- colliders
def collider_sticky(v, n, vn, friction):
    """Nodes under the ground stop."""
    return v * 0.0


def collider_slip(v, n, vn, friction):
    """Nodes under the ground lose their velocity into the ground; tangential motion is free."""
    return dr.select(vn < 0, v - vn * n, v)


def collider_friction(v, n, vn, friction):
    """Coulomb friction: approaching nodes lose v_n and μ|v_n| of their tangential speed."""
    vt = v - vn * n
    speed = dr.norm(vt)
    keep = dr.maximum(1.0 + friction * vn / dr.maximum(speed, 1e-12), 0.0)
    return dr.select(vn < 0, vt * keep, v)


COLLIDERS = Registry(
    "MPM ground collider",
    "synth.ground",
    MPMError,
    {"sticky": collider_sticky, "slip": collider_slip, "friction": collider_friction},
)


# ---------------------------------------------------------------------------- transfers
def _stencil(model: MPMModel, x):
    """Base node (Int [P] x3), fractional offset fx (Array3f [P]) and B-spline weights."""
    t = ad()
    origin = t.Array3f(*model.origin)
    xg = (x - origin) / model.dx
    base = t.Array3i(dr.floor(xg - 0.5))
    fx = xg - t.Array3f(base)
    w = [0.5 * dr.square(1.5 - fx), 0.75 - dr.square(fx - 1.0), 0.5 * dr.square(fx - 0.5)]
    return base, fx, w


def _offsets():
    return [(i, j, k) for i in range(3) for j in range(3) for k in range(3)]


def _node_index(model, base, i, j, k):
    t = ad()
    n = model.n_grid
    idx = t.UInt32(((base.x + i) * n + (base.y + j)) * n + (base.z + k))
    if model.n_samples > 1:  # each simulation of a batch has its own n³ block of nodes
        idx = idx + model.sample * (n**3)
    return idx


def p2g(model: MPMModel, params: MPMParams, state: MPMState):
    """Particle-to-grid: returns (grid mass Float [n³], grid momentum Array3f [n³])."""
    t = ad()
    n3 = model.n_grid**3 * model.n_samples
    mu, lam = lame(*model.particle_E_nu(params))
    tau = CONSTITUTIVE[model.material](state.F, mu, lam)
    m = model.particle_mass
    affine = (-model.dt * 4.0 / model.dx**2) * model.particle_vol * tau + m * state.C
    base, fx, w = _stencil(model, state.x)
    grid_m = dr.zeros(t.Float, n3)
    grid_p = dr.zeros(t.Array3f, n3)
    mv = m * state.v
    for i, j, k in _offsets():
        weight = w[i].x * w[j].y * w[k].z
        dpos = (t.Array3f(i, j, k) - fx) * model.dx
        idx = _node_index(model, base, i, j, k)
        dr.scatter_add(grid_m, weight * m, idx)
        dr.scatter_add(grid_p, weight * (mv + affine @ dpos), idx)
    return grid_m, grid_p


def grid_update(model: MPMModel, params: MPMParams, grid_m, grid_p):
    """Grid velocities after gravity, drag, walls and the ground collider: Array3f [n³]."""
    t = ad()
    n = model.n_grid
    idx = dr.arange(t.UInt32, n**3 * model.n_samples)
    if model.n_samples > 1:
        idx = idx % (n**3)  # the node within its simulation's block
    ijk = t.Array3i(t.Int(idx // (n * n)), t.Int((idx // n) % n), t.Int(idx % n))
    v = dr.select(grid_m > 0, grid_p / dr.maximum(grid_m, 1e-30), 0.0)
    v = (v + model.dt * params.gravity) / (1.0 + model.dt * params.drag)
    # Slip walls at the domain sides: no velocity out of the domain.
    lo, hi = model.wall_cells, n - model.wall_cells
    for a in range(3):
        out = ((ijk[a] < lo) & (v[a] < 0)) | ((ijk[a] >= hi) & (v[a] > 0))
        v[a] = dr.select(out, 0.0, v[a])
    # Ground plane: nodes in the contact band (less than half a cell above the plane; with
    # the plane on a node layer, the nodes on and under it) get the collider's velocity.
    # Particles then rest about half a cell above the plane instead of sinking into it.
    X = t.Array3f(*model.origin) + t.Array3f(ijk) * model.dx
    normal = t.Array3f(*model.ground_normal)
    below = dr.dot(X - t.Array3f(*model.ground_point), normal) < 0.5 * model.dx
    vn = dr.dot(v, normal)
    v_contact = COLLIDERS[model.collider](v, normal, vn, model.friction)
    return dr.select(below & (grid_m > 0), v_contact, v)


def g2p(model: MPMModel, params: MPMParams, state: MPMState, grid_v) -> MPMState:
    """Grid-to-particle: new v, C (APIC), x, F (with the plastic return mapping if enabled)."""
    t = ad()
    base, fx, w = _stencil(model, state.x)
    v, B = None, None  # accumulators start from the first term: no width literal (dr.freeze)
    for i, j, k in _offsets():
        weight = w[i].x * w[j].y * w[k].z
        dpos = (t.Array3f(i, j, k) - fx) * model.dx
        gv = dr.gather(t.Array3f, grid_v, _node_index(model, base, i, j, k))
        dv, dB = weight * gv, weight * outer(gv, dpos, t.Matrix3f)
        v, B = (dv, dB) if v is None else (v + dv, B + dB)
    C = (4.0 / model.dx**2) * B
    x = state.x + model.dt * v
    F = (dr.identity(t.Matrix3f) + model.dt * C) @ state.F
    if model.plastic:
        mu, _ = lame(*model.particle_E_nu(params))
        F = von_mises_return(F, mu, params.yield_stress)
    return MPMState(x, v, C, F)


def substep(model: MPMModel, params: MPMParams, state: MPMState) -> MPMState:
    """One MLS-MPM step of model.dt seconds (P2G, grid update, G2P)."""
    grid_m, grid_p = p2g(model, params, state)
    dr.eval(grid_m, grid_p)
    grid_v = grid_update(model, params, grid_m, grid_p)
    dr.eval(grid_v)
    new = g2p(model, params, state, grid_v)
    dr.eval(new.x, new.v, new.C, new.F)
    return new


# ---------------------------------------------------------------------------- time step
def wave_speed(E_max: float, nu: float, density: float) -> float:
    """P-wave speed sqrt((λ + 2μ) / ρ) of the stiffest particle, scene units / s."""
    mu, lam = lame(E_max, nu)
    return math.sqrt((lam + 2.0 * mu) / density)


def cfl_substeps(dt_frame, dx, E_max, nu, density, cfl, v_max) -> int:
    """The fewest substeps per frame with dt <= cfl Δx / (wave speed + v_max)."""
    c = wave_speed(E_max, nu, density) + v_max
    return max(1, math.ceil(dt_frame * c / (cfl * dx)))


def check_cfl(dt, dx, E_max, nu, density, cfl, v_max, where="synth.substeps"):
    """Raise `MPMError` if dt exceeds the CFL bound cfl Δx / (wave speed + v_max)."""
    c = wave_speed(E_max, nu, density) + v_max
    bound = cfl * dx / c
    if dt > bound * (1.0 + 1e-9):
        raise MPMError(
            f"MPM time step dt = {dt:.3e} s exceeds the CFL bound {bound:.3e} s "
            f"(cfl {cfl}, Δx {dx:.4f}, wave speed + v_max {c:.3f} units/s): raise {where}, "
            "lower E or coarsen synth.mpm_grid"
        )


_frozen_substep = None


def frozen_substep():
    """`substep` under `dr.freeze`: traced once, then replayed (~25x faster on the CPU).

    For forward simulation only: frozen functions return zero gradients when the backward
    pass starts outside them, so differentiable rollouts must call `substep` itself.
    """
    global _frozen_substep
    if _frozen_substep is None:
        # one recording per distinct model (time step, particle and batch sizes): the PAC-NeRF
        # baseline's search records one per round (sgdr.baselines.pacnerf), which is not a misuse
        from sgdr.backend import frozen

        _frozen_substep = frozen(substep, warn_after=100)
    return _frozen_substep


def simulate(model, params, state, n_frames, substeps_per_frame, cfl=1.0, progress=None, frozen=True):
    """Run n_frames - 1 frames of substeps; returns ([n_frames, P, 3] float32 positions, state).

    Frame 0 is `state` itself. After every frame the particle speed is checked against the
    CFL bound (moving more than cfl Δx per substep raises `MPMError`), and non-finite
    positions raise too. progress: optional callable(frame) after each frame. frozen: replay
    the substep with `dr.freeze` (forward only; pass False when gradients are needed).
    """
    step = frozen_substep() if frozen else substep
    frames = [to_numpy(state.x, None).T.copy()]
    for f in range(1, n_frames):
        for _ in range(substeps_per_frame):
            state = step(model, params, state)
        x = to_numpy(state.x, None).T.copy()
        v_max = float(np.abs(to_numpy(state.v, None)).max())
        if not np.all(np.isfinite(x)):
            raise MPMError(f"MPM diverged (non-finite positions) in frame {f}: lower synth.cfl")
        if v_max * model.dt > cfl * model.dx:
            raise MPMError(
                f"frame {f}: particles move {v_max * model.dt / model.dx:.2f} cells per substep "
                f"(> cfl {cfl}); raise synth.substeps or lower synth.cfl"
            )
        frames.append(x)
        if progress is not None:
            progress(f)
    return np.stack(frames).astype(np.float32), state
