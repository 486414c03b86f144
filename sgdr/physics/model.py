"""What the simulator is made of: the static `SpringModel`, the learnable `PhysParams`, the
evolving `SimState`, and the `Ground` plane (data of the sequence).

Notation follows the seed paper (Zhong et al. 2024, Eqs. 5-17): N_A anchors x_i, each tied to
its n_k nearest anchors j by springs of rest length l_ij (kNN at rest, nearest first), mass
m_i = m0, per-anchor stiffness k_i (learned as log10 k_i), soft vector η_j from κ (Eq. 15),
damping ζ_ij = ζ0 / l_ij (Eq. 17), ground friction μ and restitution e, initial velocity v0,
gravity g. Positions are world coordinates in scene units, velocities scene units / s.

Only `PhysParams` is ever `dr.enable_grad`-ed; `SpringModel` never changes after
`build_spring_model`; `SimState` is produced by `simulate_frame` / `rollout`.
"""

from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import numpy as np
from scipy.spatial import cKDTree

from sgdr.arrays import array3_to_points, to_numpy
from sgdr.backend import ad
from sgdr.physics.config import PhysicsConfig


class PhysicsInputError(ValueError):
    """Invalid input to the simulator; the message names the array/field and what is wrong."""


def _as_points(name: str, a, n: int | None = None) -> np.ndarray:
    a = np.asarray(a, dtype=np.float64)
    if a.ndim != 2 or a.shape[1] != 3:
        raise PhysicsInputError(f"{name} must have shape [N, 3], got {a.shape}")
    if n is not None and a.shape[0] != n:
        raise PhysicsInputError(f"{name} has {a.shape[0]} rows, expected {n} (one per anchor)")
    if not np.all(np.isfinite(a)):
        bad = int(np.count_nonzero(~np.isfinite(a).all(axis=1)))
        raise PhysicsInputError(f"{name} contains NaN/inf in {bad} row(s)")
    return a


def _vec3(name: str, a) -> np.ndarray:
    a = np.asarray(a, dtype=np.float64).reshape(-1)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise PhysicsInputError(f"{name} must be 3 finite numbers, got {a!r}")
    return a


@dataclass
class Ground:
    """Ground plane from sequence data: `point` [3] on the plane, unit `normal` [3] pointing up
    (away from the ground, into the free half-space). World frame, scene units."""

    point: np.ndarray  # [3] world
    normal: np.ndarray  # [3] unit, up

    def __post_init__(self):
        self.point = _vec3("Ground.point", self.point)
        n = _vec3("Ground.normal", self.normal)
        norm = float(np.linalg.norm(n))
        if norm < 1e-12:
            raise PhysicsInputError("Ground.normal has zero length")
        self.normal = n / norm


@dataclass
class SpringModel:
    """Static spring topology (Eqs. 5-7, 16): never changes, never carries gradients.

    Springs are stored per anchor: spring s = i * n_k + r (r = 0..n_k-1, nearest first) joins
    anchor i to anchor `spring_j[s]`. The incoming lists (`in_spring`, `in_offset`) let the
    symmetric variant gather, for each anchor, the springs that point at it, so both variants
    run as one gather-only sum loop per anchor.
    """

    x_rest: object  # Array3f [N_A] rest positions, world, scene units
    spring_j: object  # UInt32 [N_A * n_k] neighbour j of spring s = i * n_k + r
    spring_rest_length: object  # Float [N_A * n_k] l_ij > 0, scene units
    particle_mass: object  # Float [N_A] m_i = m0
    in_spring: object  # UInt32 [N_A * n_k] springs s sorted by their target anchor j
    in_offset: object  # UInt32 [N_A + 1] in_spring[in_offset[j]:in_offset[j+1]] point at j
    n_k: int  # springs per anchor
    n_c: int  # springs with full weight η_j = 1 (Eq. 15)
    n_anchors: int  # N_A

    def numpy(self) -> dict:
        """Float64/int64 NumPy copies of the static arrays (for the NumPy reference and tests)."""
        return {
            "x_rest": array3_to_points(self.x_rest),
            "spring_j": to_numpy(self.spring_j, np.int64),
            "spring_rest_length": to_numpy(self.spring_rest_length),
            "particle_mass": to_numpy(self.particle_mass),
            "n_k": self.n_k,
            "n_c": self.n_c,
        }


def knn_springs(x_rest: np.ndarray, n_k: int, min_length: float) -> tuple[np.ndarray, np.ndarray]:
    """n_k nearest neighbours of every anchor (cKDTree), nearest first, self excluded.

    Returns (j [N_A, n_k] int64, l [N_A, n_k] float64 rest lengths). Raises if two anchors
    coincide (a zero rest length has no spring direction)."""
    n = x_rest.shape[0]
    dist, idx = cKDTree(x_rest).query(x_rest, k=n_k + 1)
    own = idx == np.arange(n)[:, None]
    # Usually self is column 0; with ties it may sit elsewhere (or be pushed out): drop it
    # where found, else drop the farthest column.
    no_self = ~own.any(axis=1)
    own[no_self, -1] = True
    keep = ~own
    j = idx[keep].reshape(n, n_k)
    l = dist[keep].reshape(n, n_k)
    if np.any(l <= min_length):
        a = int(np.argwhere(l <= min_length)[0, 0])
        raise PhysicsInputError(
            f"x_rest: anchor {a} coincides with a neighbour (distance <= physics.min_length="
            f"{min_length}); remove duplicate anchors"
        )
    return j, l


def build_spring_model(x_rest: np.ndarray, n_k: int, cfg: PhysicsConfig) -> SpringModel:
    """Springs from kNN at rest (Eqs. 5-7): x_rest [N_A, 3] world, scene units; n_k neighbours.

    Masses are m_i = cfg.m0 (paper: m0 = 1). With cfg.soft_vector false (the ablation without
    soft vector) every spring has full weight: n_c = n_k, so η_j = 1 whatever κ (Eq. 15)."""
    t = ad()
    x_rest = _as_points("x_rest", x_rest)
    n = x_rest.shape[0]
    if not isinstance(n_k, (int, np.integer)) or n_k < 1:
        raise PhysicsInputError(f"n_k must be a positive integer, got {n_k!r}")
    if n_k >= n:
        raise PhysicsInputError(f"n_k={n_k} must be smaller than the number of anchors N_A={n}")
    if not cfg.m0 > 0:
        raise PhysicsInputError(f"physics.m0={cfg.m0} must be positive (anchor mass)")
    if cfg.n_c < 0:
        raise PhysicsInputError(f"physics.n_c={cfg.n_c} must be >= 0")
    j, l = knn_springs(x_rest, int(n_k), cfg.min_length)
    flat_j = j.reshape(-1)
    in_spring = np.argsort(flat_j, kind="stable")
    in_offset = np.concatenate([[0], np.cumsum(np.bincount(flat_j, minlength=n))])
    return SpringModel(
        x_rest=t.Array3f(*(x_rest.T.astype(np.float32))),
        spring_j=t.UInt32(flat_j.astype(np.uint32)),
        spring_rest_length=t.Float(l.reshape(-1).astype(np.float32)),
        particle_mass=dr.full(t.Float, float(cfg.m0), n),
        in_spring=t.UInt32(in_spring.astype(np.uint32)),
        in_offset=t.UInt32(in_offset.astype(np.uint32)),
        n_k=int(n_k),
        n_c=int(min(cfg.n_c, n_k)) if cfg.soft_vector else int(n_k),
        n_anchors=n,
    )


def with_masses(model: SpringModel, masses: np.ndarray) -> SpringModel:
    """A copy of `model` with per-anchor masses [N_A] (all > 0)."""
    t = ad()
    m = np.asarray(masses, dtype=np.float64).reshape(-1)
    if m.shape != (model.n_anchors,):
        raise PhysicsInputError(f"masses has {m.shape[0]} entries, expected N_A={model.n_anchors}")
    if not np.all(np.isfinite(m)) or np.any(m <= 0):
        raise PhysicsInputError(f"masses must be finite and positive (min {np.nanmin(m)})")
    out = SpringModel(**{f: getattr(model, f) for f in model.__dataclass_fields__})
    out.particle_mass = t.Float(m.astype(np.float32))
    return out


@dataclass
class PhysParams:
    """Learnable physical parameters (the only fields that are ever `dr.enable_grad`-ed)."""

    log10_k: object  # Float [N_A] log10 of k_i, stiffness per anchor (k_ij = k_i / l_ij, Eq. 16)
    kappa: object  # Float [1] κ of the soft vector η_j (Eq. 15)
    v0: object  # Array3f [1] initial velocity, scene units / s
    friction: object  # Float [1] μ (meaning depends on physics.contact)
    restitution: object  # Float [1] e in [0, 1] ("coulomb" contact)
    zeta0: object  # Float [1] ζ0, damping (ζ_ij = ζ0 / l_ij, Eq. 17)
    gravity: object  # Array3f [1] g, scene units / s², world frame

    @staticmethod
    def init(model: SpringModel, cfg: PhysicsConfig, v0=(0.0, 0.0, 0.0), gravity=(0.0, 0.0, -9.8)) -> PhysParams:
        t = ad()
        v0 = _vec3("v0", v0)
        gravity = _vec3("gravity", gravity)
        params = PhysParams(
            log10_k=dr.full(t.Float, float(cfg.log10_k_init), model.n_anchors),
            kappa=t.Float(float(cfg.kappa_init)),
            v0=t.Array3f(*map(float, v0)),
            friction=t.Float(float(cfg.friction_init)),
            restitution=t.Float(float(cfg.restitution_init)),
            zeta0=t.Float(float(cfg.zeta0)),
            gravity=t.Array3f(*map(float, gravity)),
        )
        # memory-backed, not literals: a literal is baked into the kernels, so changing its
        # value (an optimiser step) would recompile them
        dr.make_opaque(params)
        return params

    def detach(self) -> PhysParams:
        return PhysParams(**{f: dr.detach(getattr(self, f)) for f in self.__dataclass_fields__})

    def validate(self, model: SpringModel) -> None:
        """Sizes and values; raises PhysicsInputError naming the field."""
        if dr.width(self.log10_k) != model.n_anchors:
            raise PhysicsInputError(
                f"PhysParams.log10_k has {dr.width(self.log10_k)} entries, expected N_A={model.n_anchors}"
            )
        for f in ("kappa", "v0", "friction", "restitution", "zeta0", "gravity"):
            if dr.width(getattr(self, f)) != 1:
                raise PhysicsInputError(f"PhysParams.{f} must hold one value, has {dr.width(getattr(self, f))}")
        for f in self.__dataclass_fields__:
            if not bool(dr.all(dr.isfinite(dr.detach(getattr(self, f))), axis=None)):
                raise PhysicsInputError(f"PhysParams.{f} contains NaN/inf")


@dataclass
class SimState:
    """Evolving state of the anchors: positions `x` and velocities `v`, Array3f [N_A] each."""

    x: object  # Array3f [N_A] world, scene units
    v: object  # Array3f [N_A] scene units / s
    rest: object = None  # Float [N_A n_k] spring rest lengths once plasticity moves them; None: the model's

    @staticmethod
    def at_rest(model: SpringModel, v0) -> SimState:
        """Anchors at their rest positions moving with one velocity v0 (Array3f [1], e.g.
        `params.v0`, keeps its gradient; or 3 numbers)."""
        t = ad()
        if not dr.is_array_v(v0):
            v0 = t.Array3f(*map(float, _vec3("v0", v0)))
        x = t.Array3f(model.x_rest)
        v = dr.zeros(t.Array3f, model.n_anchors) + v0
        return SimState(x=x, v=v)

    @staticmethod
    def from_numpy(x: np.ndarray, v: np.ndarray) -> SimState:
        t = ad()
        x = _as_points("SimState.x", x)
        v = _as_points("SimState.v", v, x.shape[0])
        return SimState(x=t.Array3f(*x.T.astype(np.float32)), v=t.Array3f(*v.T.astype(np.float32)))

    def detach(self) -> SimState:
        return SimState(
            x=dr.detach(self.x), v=dr.detach(self.v), rest=None if self.rest is None else dr.detach(self.rest)
        )

    def numpy(self) -> tuple[np.ndarray, np.ndarray]:
        """(x [N_A, 3], v [N_A, 3]) float64."""
        return array3_to_points(self.x), array3_to_points(self.v)
