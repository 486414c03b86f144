"""Typed config schema of the baselines (group key `baseline`, issue 16).

Each baseline has its own section: `baseline.dyngaus` (simplified Dynamic 3D Gaussians,
`sgdr.baselines.dyngaus`) and `baseline.deform4d` (simplified 4D Gaussian Splatting,
`sgdr.baselines.deform4d`). The sizes (Adam steps, neighbour counts, grid resolution) are set by
conf/preset/{tiny,small,paper}.yaml; the method (loss weights, regulariser kinds, learning rates)
by conf/method/ (the schema's defaults below are the method's values).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from sgdr.checks import Check, at_least, between, choice, non_negative, positive


@dataclass
class DynGausConfig:
    """Simplified Dynamic 3D Gaussians (Luiten et al., 3DV 2024): per-frame tracking of the frozen
    frame-0 Gaussians' centres (and rotations) with its physically-based priors."""

    # scale (preset)
    iterations: int = 200  # Adam steps per tracked frame (Luiten et al.: 2000 per timestep)
    n_neighbours: int = 20  # k of the kNN (frame-0 centres) the priors act on (Luiten et al.: 20)
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
    iterations: int = 300  # joint Adam steps over all fit frames
    warmup_iterations: int = 100  # Adam steps per frame of the sequential start (init: sequential)
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
    dyngaus: DynGausConfig = field(default_factory=DynGausConfig)  # method=dyngaus (sgdr.baselines.dyngaus)
    deform4d: Deform4DConfig = field(default_factory=Deform4DConfig)  # method=deform4d (sgdr.baselines.deform4d)


CHECKS: dict[str, Check] = {}

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
