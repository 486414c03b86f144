"""Typed config schema of the reconstruction pipeline (group key `recon`)."""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass
class ReconConfig:
    iterations: int = 200  # dynamic-reconstruction passes over the fit frames
    lambda_dssim: float = 0.05  # λ of the dynamic loss
    substep_schedule: list[int] = field(default_factory=lambda: [100, 150, 200])  # n_t over iters
    cameras_per_frame: int = 1  # random cameras rendered per frame (official: 1)
    lr_log10_k: float = 1e-2  # Adam, per-anchor log10 k_i
    lr_kappa: float = 1e-2  # Adam, soft vector κ
    lr_friction: float = 1e-2  # Adam, ground friction
    lr_restitution: float = 1e-2  # Adam, restitution (coulomb contact)
    lr_v0: float = 1e-2  # Adam, initial velocity
    v0_iterations: int = 100  # Adam steps of the initial-velocity stage
    refine_iterations: int = 300  # Adam steps refining scale, colour, opacity at IDW positions
    force: bool = False  # redo stages whose outputs exist
