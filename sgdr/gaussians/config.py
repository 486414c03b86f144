"""Typed config schema of the static Gaussian fit (group key `static_fit`)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class StaticFitConfig:
    n_init: int = 20000  # Gaussians initialised uniformly in the object's box
    s0: float = 0.01  # constant isotropic scale during the static fit, scene units
    iterations: int = 3000  # Adam steps
    views_per_step: int = 1  # views rendered per step
    lr_position: float = 1e-3  # Adam learning rate, centres
    lr_color: float = 2.5e-2  # Adam learning rate, colour logits
    lr_opacity: float = 5e-2  # Adam learning rate, opacity logits
    lambda_dssim: float = 0.2  # λ in (1-λ) L1 + λ D-SSIM
    prune_opacity: float = 0.005  # Gaussians below this opacity are pruned
    prune_every: int = 500  # steps between prunings
