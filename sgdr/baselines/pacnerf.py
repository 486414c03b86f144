"""The PAC-NeRF baseline (Li et al., ICLR 2023) in sgdr's engines; simplified, see docs/baselines.md.

PAC-NeRF's assumptions, kept: one global, homogeneous Neo-Hookean material (E, ν) simulated by
MLS-MPM particles that fill the object's volume as reconstructed from the first frame, the
initial velocity from the free-fall frames, a sticky ground (its configs' `surface_sticky`), E
and ν identified from the same images as every other method. Differences, by necessity:

- the volume is the static 3D Gaussians' (sgdr's frame-0 reconstruction) instead of a voxel
  radiance field: particles fill a lattice (2 per MPM cell and axis) where the Gaussians'
  occupancy exceeds `fill_threshold`, enclosed cavities filled (`fill_particles`); never the
  generator's particles;
- appearance: the refined frame-0 Gaussians, each centre moved by the inverse-distance average
  of its `bind_k` nearest particles' displacements, rendered by sgdr's renderer and scored like
  every other method (PAC-NeRF advects its colour field with the particles);
- v0 is the shared velocity stage's (PAC-NeRF fits it on the first frames too);
- E and ν: PAC-NeRF runs Adam on log10 E and ν through its differentiable MPM. sgdr's MPM
  backward through recorded AD is compile-bound (25-40 substeps did not finish in 10 min), so
  the two global values are searched derivative-free (`search`): rounds of a grid of candidates
  over (log10 E, ν), all of a round simulated in one batched Dr.Jit program (each candidate on
  its own grid, `sgdr.synth.mpm` with `n_samples`), the next round's grid centred on the best so
  far and one grid step wide. The loss is the diagnosis's rendered measure: |RGBA difference|
  per observed silhouette pixel over the compared views and fit frames.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.ndimage import binary_fill_holes
from scipy.spatial import cKDTree

from sgdr.backend import ad
from sgdr.observe.images import block_mean, downscale_factor, downscaled
from sgdr.render.images import posed, render_rgba_numpy
from sgdr.render.reference import quat_to_matrix
from sgdr.skin import IDWBinding
from sgdr.synth import mpm


class PacNerfError(ValueError):
    """A setting or an input the baseline cannot work with (names the config key)."""


# ---------------------------------------------------------------------------- volume
def occupancy(gaussians: dict, points: np.ndarray) -> np.ndarray:
    """[N] occupancy 1 - Π_g (1 - α_g exp(-½ d_gᵀ Σ_g⁻¹ d_g)) of the Gaussians (NumPy dict of
    `Gaussians.to_numpy`) at points [N, 3]; each Gaussian acts within 3 of its largest σ."""

    means = gaussians["means"]
    scales = np.exp(gaussians["log_scales"])
    alpha = 1.0 / (1.0 + np.exp(-gaussians["opacity_logits"]))
    R = quat_to_matrix(gaussians["rotations"])
    inv_cov = R @ (np.eye(3)[None] / (scales**2)[:, None, :]) @ np.transpose(R, (0, 2, 1))
    log_free = np.zeros(len(points))
    tree = cKDTree(points)
    for g, near in enumerate(tree.query_ball_point(means, 3.0 * scales.max(1))):
        if not near:
            continue
        d = points[near] - means[g]
        m2 = np.einsum("ni,ij,nj->n", d, inv_cov[g], d)
        np.add.at(log_free, near, np.log1p(-np.minimum(alpha[g] * np.exp(-0.5 * m2), 1.0 - 1e-6)))
    return 1.0 - np.exp(log_free)


def fill_particles(gaussians: dict, spacing: float, threshold: float) -> np.ndarray:
    """Particles [P, 3] on a lattice of `spacing` filling the Gaussians' volume: the points whose
    occupancy exceeds `threshold`, with enclosed cavities filled (a surface-heavy fit still gives
    a solid object, as PAC-NeRF's density field does)."""

    means = gaussians["means"]
    lo = means.min(0) - 2 * spacing
    hi = means.max(0) + 2 * spacing
    axes = [np.arange(lo[a], hi[a] + spacing, spacing) for a in range(3)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), -1)
    inside = occupancy(gaussians, grid.reshape(-1, 3)).reshape(grid.shape[:3]) > threshold
    inside = binary_fill_holes(inside)
    if not inside.any():
        raise PacNerfError(
            f"no lattice point of the static Gaussians exceeds occupancy baseline.pacnerf.fill_threshold={threshold}"
        )
    return grid[inside]


# ---------------------------------------------------------------------------- scene
@dataclass
class Scene:
    """What every rollout of one object shares."""

    particles: np.ndarray  # [P, 3] rest positions (frame 0), world
    spacing: float  # particle lattice spacing = Δx / 2
    origin: np.ndarray  # [3] MPM grid origin
    n_grid: int  # nodes per side
    dx: float
    v0: np.ndarray  # [3]
    gravity: np.ndarray  # [3]
    ground_point: np.ndarray
    ground_normal: np.ndarray
    dt_frame: float
    wall_cells: int = 3


def plan_scene(particles, spacing, v0, gravity, ground_point, ground_normal, dt_frame, n_frames, wall_cells=3):
    """The MPM domain (a cube, axis-aligned) that holds the particles over `n_frames`: their box,
    the ground under them (with wall cells below it), the horizontal drift of v0, and margins."""
    dx = 2.0 * spacing
    ground_point = np.asarray(ground_point, float)
    normal = np.asarray(ground_normal, float) / np.linalg.norm(ground_normal)
    p = np.asarray(particles, float)
    heights = (p - ground_point) @ normal
    on_ground = p - np.outer(heights, normal)  # the particles dropped onto the plane
    v = np.asarray(v0, float)
    drift = (v - (v @ normal) * normal) * dt_frame * n_frames
    extent = float((p.max(0) - p.min(0)).max())
    pts = np.concatenate([p, on_ground - (wall_cells + 2) * dx * normal, p + drift, on_ground + drift])
    lo = pts.min(0) - 0.25 * extent - (wall_cells + 2) * dx
    hi = pts.max(0) + 0.25 * extent + (wall_cells + 2) * dx
    size = float((hi - lo).max())
    n_grid = int(math.ceil(size / dx)) + 2
    centre = 0.5 * (lo + hi)
    origin = centre - 0.5 * (n_grid - 1) * dx
    # the ground on a node layer along the normal's main axis, as in the generator: the collider
    # band (nodes less than Δx/2 above the plane) is then the layer on the plane and those below
    a = int(np.argmax(np.abs(normal)))
    origin[a] += (ground_point[a] - origin[a]) / dx % 1.0 * dx
    return Scene(
        p,
        float(spacing),
        origin,
        n_grid,
        dx,
        v,
        np.asarray(gravity, float),
        np.asarray(ground_point, float),
        normal,
        float(dt_frame),
        wall_cells,
    )


def substeps_for(scene: Scene, cfg, E_max: float, nu_max: float, n_frames: int) -> int:
    """MPM substeps per frame: `cfg.substeps`, checked against the CFL bound of the stiffest
    candidate, or (0) the fewest that bound allows."""
    v_bound = float(np.linalg.norm(scene.v0)) + float(np.linalg.norm(scene.gravity)) * scene.dt_frame * n_frames + 1.0
    fewest = mpm.cfl_substeps(scene.dt_frame, scene.dx, E_max, nu_max, cfg.density, cfg.cfl, v_bound)
    if cfg.substeps:
        if cfg.substeps < fewest:
            raise PacNerfError(
                f"baseline.pacnerf.substeps={cfg.substeps} is below the CFL bound of the stiffest candidate "
                f"(E {E_max:.3g} Pa, ν {nu_max:.3g}, Δx {scene.dx:.4g}): at least {fewest} substeps per frame; raise "
                "it, set it to 0 (automatic), lower baseline.pacnerf.log10_E_range or coarsen baseline.pacnerf.dx / "
                "cells_per_size"
            )
        return int(cfg.substeps)
    return fewest


def rollout(scene: Scene, cfg, E, nu, n_frames: int, progress=None) -> np.ndarray:
    """Particle positions [S, n_frames, P, 3] of S candidates (E, ν arrays [S]) simulated in one
    batched MPM program (each on its own grid); frame 0 is the rest state."""

    t = ad()
    E, nu = np.atleast_1d(np.asarray(E, float)), np.atleast_1d(np.asarray(nu, float))
    S, P = len(E), len(scene.particles)
    x = np.tile(scene.particles, (S, 1))
    substeps = substeps_for(scene, cfg, float(E.max()), float(nu.max()), n_frames)
    try:
        model = mpm.create_model(
            x,
            scene.spacing**3,
            cfg.density,
            n_grid=scene.n_grid,
            dx=scene.dx,
            origin=scene.origin,
            dt=scene.dt_frame / substeps,
            material=cfg.material,
            collider=cfg.collider,
            friction=cfg.ground_friction,
            ground_point=scene.ground_point,
            ground_normal=scene.ground_normal,
            wall_cells=scene.wall_cells,
        )
    except mpm.MPMError as exc:
        raise PacNerfError(f"PAC-NeRF baseline: {exc}") from exc
    if S > 1:
        model = replace(model, n_samples=S, sample=t.UInt32(np.repeat(np.arange(S, dtype=np.uint32), P)))
    params = mpm.MPMParams.create(1.0, 0.3, scene.gravity)
    params.E, params.nu = t.Float(E.astype(np.float32)), t.Float(nu.astype(np.float32))
    state = mpm.MPMState.at_rest(x, scene.v0)
    frames, _ = mpm.simulate(model, params, state, n_frames, substeps, cfg.cfl, progress)
    return frames.reshape(n_frames, S, P, 3).transpose(1, 0, 2, 3)


# ---------------------------------------------------------------------------- appearance
class ParticleSkin:
    """Gaussian centres that follow the particles: each centre moves by the inverse-distance
    average of its `k` nearest particles' displacements (sgdr.skin's displacement binding)."""

    def __init__(self, gaussians, particles: np.ndarray, k: int):
        self.gaussians = gaussians.detach()
        centres = gaussians.to_numpy()["means"]
        self.binding = IDWBinding.build(centres, particles, min(int(k), len(particles)), 2.0, "displacement")

    def centres(self, x: np.ndarray):
        """Array3f [M] of the centres for particle positions x [P, 3]."""

        return self.binding.apply(ad().Array3f(*np.asarray(x, np.float32).T))

    def posed(self, x: np.ndarray):
        return posed(self.gaussians, self.centres(x))


@dataclass
class Observation:
    """The images the search compares: [V, F, h, w, 4] premultiplied RGBA at the compared size."""

    cameras: list
    frames: np.ndarray
    images: np.ndarray


def observe(seq, cfg) -> Observation:
    """Views (all, or `n_views` evenly spread) and fit frames 1.. (every `frame_stride`-th, the
    last fit frame always) at most `max_image_size` pixels wide."""

    n_v = len(seq.cameras)
    views = np.arange(n_v) if not cfg.n_views or cfg.n_views >= n_v else np.linspace(0, n_v - 1, cfg.n_views)
    views = sorted({int(round(v)) for v in views})
    frames = sorted({*range(1, int(seq.n_fit), int(cfg.frame_stride)), int(seq.n_fit) - 1} - {0})
    if not frames:
        raise PacNerfError("the sequence has one fit frame: nothing to identify E and ν from (n_fit must be >= 2)")
    cam0 = seq.cameras[views[0]]
    k = downscale_factor(cam0.width, cam0.height, cfg.max_image_size)
    cams = [downscaled(seq.cameras[v], k) for v in views]
    images = [[block_mean(seq.image(v, f), k) for f in frames] for v in views]
    return Observation(cams, np.asarray(frames, int), np.asarray(images, np.float32))


def image_discrepancy(skin: ParticleSkin, obs: Observation, positions: np.ndarray, render_cfg) -> float:
    """Mean over compared views and frames of Σ|render - image| (RGBA) / observed silhouette area;
    positions: [T, P, 3] particle frames."""
    import drjit as dr

    total = []
    with dr.suspend_grad():
        for j, f in enumerate(obs.frames):
            g = skin.posed(positions[int(f)])
            for i, cam in enumerate(obs.cameras):
                diff = np.abs(render_rgba_numpy(g, cam, render_cfg) - obs.images[i, j]).sum()
                total.append(float(diff) / max(float(obs.images[i, j, ..., 3].sum()), 1.0))
    return float(np.mean(total))


# ---------------------------------------------------------------------------- identification
@dataclass
class SearchResult:
    E: float
    nu: float
    loss: float
    substeps: int  # MPM substeps per frame of the best candidate's own (single) rollout
    evaluated: list = field(default_factory=list)  # [{round, log10_E, nu, loss}] every candidate
    round_best: list = field(default_factory=list)  # best loss after each round
    at_bound: list = field(default_factory=list)  # "log10_E low" ... when the best lies on the search box's edge


def grid_axis(lo: float, hi: float, n: int) -> np.ndarray:
    return np.linspace(lo, hi, n) if n > 1 else np.array([0.5 * (lo + hi)])


def next_box(box, best: float, n: int, bounds) -> list:
    """The next round's interval: centred on the best value, half the grid step of this round
    per point (the next step is half this one), within the search bounds; with ±(n - 1)/4 steps
    it covers half a step either side of the best, where a unimodal loss's minimum lies."""
    if n == 1:
        return list(box)
    step = (box[1] - box[0]) / (n - 1)
    half = 0.25 * (n - 1) * step
    lo, hi = best - half, best + half
    if lo < bounds[0]:  # at a bound: keep the width, inside the bounds
        lo, hi = bounds[0], bounds[0] + 2 * half
    elif hi > bounds[1]:
        lo, hi = bounds[1] - 2 * half, bounds[1]
    return [max(lo, bounds[0]), min(hi, bounds[1])]


def search(scene: Scene, skin: ParticleSkin, obs: Observation, cfg, render_cfg, progress: bool = False):
    """Derivative-free identification of (log10 E, ν) (module docstring): `cfg.rounds` rounds of
    a `grid_E` x `grid_nu` grid, batched; each next grid is centred on the best so far with half
    the step (`next_box`)."""
    E_box = [float(v) for v in cfg.log10_E_range]
    nu_box = [float(v) for v in cfg.nu_range]
    box = [list(E_box), list(nu_box)]
    n_frames = int(obs.frames.max()) + 1
    evaluated, round_best = [], []
    best = None
    rounds = range(int(cfg.rounds))
    bar = None
    if progress:  # one step per round; within a round the postfix says where it is
        from tqdm import tqdm

        rounds = bar = tqdm(rounds, desc="PAC-NeRF E, ν search", leave=False)
    for r in rounds:
        ge, gn = grid_axis(*box[0], int(cfg.grid_E)), grid_axis(*box[1], int(cfg.grid_nu))
        cand = np.array([(e, n) for e in ge for n in gn])
        label = f"{len(cand)} candidates, frame"
        step = (lambda f, label=label: bar.set_postfix_str(f"{label} {f}/{n_frames - 1}")) if bar else None
        frames = rollout(scene, cfg, 10.0 ** cand[:, 0], cand[:, 1], n_frames, step)
        if bar:
            bar.set_postfix_str(f"rendering {len(cand)} candidates" + (f", best {best['loss']:.4g}" if best else ""))
        for (lE, nu), pos in zip(cand, frames):
            loss = image_discrepancy(skin, obs, pos, render_cfg)
            if not math.isfinite(loss):
                continue
            evaluated.append({"round": r, "log10_E": float(lE), "nu": float(nu), "loss": loss})
            if best is None or loss < best["loss"]:
                best = evaluated[-1]
        if best is None:
            raise PacNerfError("every candidate of the first round diverged: narrow baseline.pacnerf.log10_E_range")
        round_best.append(best["loss"])
        box = [
            next_box(box[0], best["log10_E"], int(cfg.grid_E), E_box),
            next_box(box[1], best["nu"], int(cfg.grid_nu), nu_box),
        ]
    tol_E = 1e-6 * (E_box[1] - E_box[0])
    tol_nu = 1e-6 * (nu_box[1] - nu_box[0])
    at_bound = [
        name
        for name, value, edge, tol in (
            ("log10_E low", best["log10_E"], E_box[0], tol_E),
            ("log10_E high", best["log10_E"], E_box[1], tol_E),
            ("nu low", best["nu"], nu_box[0], tol_nu),
            ("nu high", best["nu"], nu_box[1], tol_nu),
        )
        if abs(value - edge) <= tol and (name.startswith("log10_E") or int(cfg.grid_nu) > 1)
    ]
    E = 10.0 ** best["log10_E"]
    return SearchResult(
        E,
        best["nu"],
        best["loss"],
        substeps_for(scene, cfg, E, best["nu"], n_frames),
        evaluated,
        round_best,
        at_bound,
    )
