"""Typed config schema of the baselines (group key `baseline`): the methods the paper compares
Spring-Gaus with, each a `recon.model` choice (`sgdr.pipeline.run.MODELS`, `conf/method/`), one
section each: `baseline.pacnerf`, `baseline.dyngaus` (simplified Dynamic 3D Gaussians,
`sgdr.baselines.dyngaus`), `baseline.deform4d` (simplified 4D Gaussian Splatting,
`sgdr.baselines.deform4d`).

Scale keys (grid sizes, candidate counts, rounds, Adam steps, neighbour counts) are set by the
presets, method keys (the ground collider, the search ranges, loss weights, regulariser kinds,
learning rates) by the method files; defaults here are the small preset's scale and each
method's own values.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from sgdr.checks import Check, at_least, between, choice, non_negative, positive, vector


@dataclass
class PacNerfConfig:
    """PAC-NeRF's assumptions in sgdr's engines (docs/baselines.md): one global Neo-Hookean E
    and ν for MLS-MPM particles filled into the static reconstruction's volume, v0 from the
    shared velocity stage, a sticky ground; E and ν searched derivative-free with batched
    candidate rollouts (the MPM backward through recorded AD is compile-bound)."""

    # --- method
    collider: str = "sticky"  # MPM ground collider: sticky (PAC-NeRF's surface_sticky) | slip | friction
    ground_friction: float = 0.5  # Coulomb μ of the `friction` collider
    material: str = "neo_hookean"  # constitutive law (PAC-NeRF's compressible Neo-Hookean)
    density: float = 1.0e3  # kg / scene unit³ (PAC-NeRF's and the generator's); only E / density acts
    log10_E_range: list[float] = field(default_factory=lambda: [3.0, 5.5])  # the search box of log10 E, Pa
    nu_range: list[float] = field(default_factory=lambda: [0.05, 0.45])  # the search box of ν
    fill_threshold: float = 0.5  # a lattice point is inside when the Gaussians' occupancy there exceeds this
    bind_k: int = 8  # particles each Gaussian centre follows (inverse-distance weights of their displacements)
    cfl: float = 0.3  # MPM time step = cfl Δx / (P-wave speed of the stiffest candidate + a speed bound)
    # --- scale (presets)
    cells_per_size: int = 16  # MPM cells across the object's largest extent (particles: 2 per cell per axis)
    dx: float = 0.0  # MPM cell size, scene units, when > 0 (instead of cells_per_size); particles at dx / 2
    substeps: int = 0  # MPM substeps per frame; 0 = the fewest the CFL bound allows (PAC-NeRF's configs: 200)
    grid_E: int = 5  # candidate log10 E values per search round (>= 3)
    grid_nu: int = 3  # candidate ν values per search round (1: fixed; else >= 3); grid_E x grid_nu rollouts batched
    rounds: int = 5  # search rounds; each centres a grid of half the step on the best candidate so far
    n_views: int = 0  # views the search compares (0 = all; evenly spread otherwise)
    frame_stride: int = 1  # every n-th fit frame is compared in the search
    max_image_size: int = 64  # images compared at most this large (block means, intrinsics scaled)


@dataclass
class DynGausConfig:
    """Simplified Dynamic 3D Gaussians (Luiten et al., 3DV 2024): per-frame tracking of the frozen
    frame-0 Gaussians' centres (and rotations) with its physically-based priors."""

    # scale (preset)
    iterations: int = 80  # Adam steps per tracked frame (Luiten et al.: 2000 per timestep)
    n_neighbours: int = 16  # k of the kNN (frame-0 centres) the priors act on (Luiten et al.: 20)
    # method
    rotations: bool = True  # also optimise a rotation per Gaussian (the rigidity prior's R_i); false: centres only
    extrapolate: bool = True  # start frame t from t-1 plus the last frame's velocity (Luiten et al.'s init)
    views_per_step: int = 2  # random views rendered per Adam step (0 = every view; Luiten et al.: 1)
    lr_means: float = 3e-3  # Adam learning rate of the centres, scene units
    lr_rotations: float = 1e-2  # Adam learning rate of the rotation quaternions (unit length)
    lambda_dssim: float = 0.2  # λ of the image loss (1-λ) L1 + λ D-SSIM
    weight_falloff: float = 1.0  # λ_w of the neighbour weights w_ij = exp(-λ_w (d_ij / d̄)²), d̄: mean kNN distance
    # the priors' weights keep Luiten et al.'s ratios 4 : 4 : 2, scaled by 0.1 for our d̄-relative priors
    # (at 4 : 4 : 2 the rigid twin's centre error was 4-40x larger: the priors held the images off; docs/baselines.md)
    w_rigid: float = 0.4  # weight of the local-rigidity prior
    w_rot: float = 0.4  # weight of the rotation-similarity prior (only with rotations)
    w_iso: float = 0.2  # weight of the isometry prior


@dataclass
class Deform4DConfig:
    """Simplified 4D Gaussian Splatting (Wu et al., CVPR 2024): one displacement grid per fit frame
    over the object's box, trilinearly interpolated at the frozen frame-0 centres, fitted jointly."""

    # scale (preset)
    iterations: int = 60  # joint Adam steps over all fit frames
    warmup_iterations: int = 40  # Adam steps per frame of the sequential start (init: sequential)
    grid_resolution: int = 8  # grid nodes per axis of each frame's displacement grid
    # method
    init: str = "sequential"  # how the grids start: sequential (frame by frame, each from the last) | zero
    extrapolate: bool = True  # sequential start: frame t's grid from t-1's plus the last frame's change
    views_per_step: int = 2  # random views rendered per frame and Adam step (0 = every view)
    box_margin: float = 0.1  # the grid's box: the frame-0 centres' box padded by this fraction of its size per side
    lr: float = 3e-3  # Adam learning rate of the grid displacements, scene units
    lambda_dssim: float = 0.2  # λ of the image loss (1-λ) L1 + λ D-SSIM
    tv: str = "l2"  # kind of the spatial smoothness penalty on the grid (sgdr.baselines.deform4d.TV_PENALTIES)
    w_tv: float = 1e-3  # weight of the spatial penalty (differences of neighbouring nodes / cell size)
    w_time: float = 1e-3  # weight of the temporal smoothness (second difference over frames / cell size)²


@dataclass
class BaselineConfig:
    pacnerf: PacNerfConfig = field(default_factory=PacNerfConfig)
    dyngaus: DynGausConfig = field(default_factory=DynGausConfig)  # method=dyngaus (sgdr.baselines.dyngaus)
    deform4d: Deform4DConfig = field(default_factory=Deform4DConfig)  # method=deform4d (sgdr.baselines.deform4d)


def _range(lo: float, hi: float) -> Check:
    inner = vector(2, each=between(lo, hi))
    return Check(lambda v: inner.ok(v) and v[0] < v[1], f"[low, high] with {lo} <= low < high <= {hi}")


PACNERF_CHECKS = {
    "collider": choice("sgdr.synth.mpm:COLLIDERS"),
    "ground_friction": non_negative(),
    "material": choice("sgdr.synth.mpm:CONSTITUTIVE"),
    "density": positive(),
    "log10_E_range": _range(0.0, 9.0),
    "nu_range": _range(0.0, 0.49),
    "fill_threshold": between(0.0, 1.0, lo_open=True, hi_open=True),
    "bind_k": at_least(1),
    "cfl": between(0.0, 1.0, lo_open=True),
    "cells_per_size": at_least(4),
    "dx": non_negative("0: the object's largest extent / cells_per_size"),
    "substeps": non_negative("0: the fewest the CFL bound allows"),
    "grid_E": at_least(3),
    "grid_nu": Check(
        lambda n: isinstance(n, int) and (n == 1 or n >= 3), "1 (ν fixed at the middle of nu_range) or >= 3"
    ),
    "rounds": at_least(1),
    "n_views": non_negative("0: every view"),
    "frame_stride": at_least(1),
    "max_image_size": at_least(8),
}
CHECKS: dict = {}  # BaselineConfig holds sections only

DYNGAUS_CHECKS: dict[str, Check] = {
    "iterations": at_least(1),
    "n_neighbours": at_least(1),
    "views_per_step": at_least(0, "0: every view"),
    "lr_means": positive(),
    "lr_rotations": positive(),
    "lambda_dssim": between(0.0, 1.0),
    "weight_falloff": non_negative("0: equal weights"),
    "w_rigid": non_negative("0: off"),
    "w_rot": non_negative("0: off"),
    "w_iso": non_negative("0: off"),
}

DEFORM4D_CHECKS: dict[str, Check] = {
    "iterations": at_least(0),
    "warmup_iterations": at_least(0),
    "grid_resolution": at_least(2),
    "init": choice(("sequential", "zero")),
    "views_per_step": at_least(0, "0: every view"),
    "box_margin": non_negative(),
    "lr": positive(),
    "lambda_dssim": between(0.0, 1.0),
    "tv": choice("sgdr.baselines.deform4d:TV_PENALTIES"),
    "w_tv": non_negative("0: off"),
    "w_time": non_negative("0: off"),
}
