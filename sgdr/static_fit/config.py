"""Typed config schema of the static Gaussian fit (group key `static_fit`)."""

from __future__ import annotations

from dataclasses import dataclass

from sgdr.checks import at_least, between, non_negative, positive


@dataclass
class StaticFitConfig:
    n_init: int = 20000  # Gaussians initialised uniformly in the object's box
    s0: float = 0.01  # constant isotropic scale during the static fit, scene units
    iterations: int = 3000  # Adam steps
    views_per_step: int = 1  # views rendered per step
    lr_position: float = 1e-3  # Adam learning rate, centres (start of the exponential decay)
    lr_position_final: float = 1e-5  # Adam learning rate, centres, at the last step
    lr_color: float = 2.5e-2  # Adam learning rate, colour logits
    lr_opacity: float = 5e-2  # Adam learning rate, opacity logits
    init_opacity: float = 0.1  # initial opacity of every Gaussian (3DGS)
    lambda_dssim: float = 0.2  # λ in (1-λ) L1 + λ D-SSIM
    lambda_mask: float = 0.0  # weight of the |alpha - mask| term (0: photometric loss only, as the paper)
    prune_opacity: float = 0.005  # Gaussians below this opacity are pruned
    prune_every: int = 500  # steps between prunings (0: only at the end)
    carve_grid: int = 48  # voxels per side when the box is carved from the masks
    carve_extent: float = 0.5  # carving cube half-size, as a fraction of the mean camera distance
    box_margin: float = 0.05  # relative padding of the carved box
    # a real capture's static scan is in COLMAP's arbitrary units: it is fitted in a frame scaled so its carved box's
    # diagonal is this many scene units (the size s0 and the learning rates are meant for), then mapped back
    scan_size: float = 0.5
    register_iterations: int = 300  # a real capture: Adam steps of the registration into the dynamic frame
    register_lr: float = 0.01  # its learning rate (6D rotation, translation in object sizes, log scale)
    register_lambda_center: float = 1.0  # its mask-centre term's weight (the paper's LAMBDA_CENTER)
    register_lambda_rgb: float = 1.0  # its colour term's weight (0: masks only; needs the video frames)


# Allowed values, checked before any work (sgdr.checks).
CHECKS = {
    "n_init": at_least(1),
    "s0": positive(),
    "iterations": at_least(1),
    "views_per_step": at_least(1),
    "lr_position": non_negative(),
    "lr_position_final": non_negative(),
    "lr_color": non_negative(),
    "lr_opacity": non_negative(),
    "init_opacity": between(0.0, 1.0, lo_open=True, hi_open=True),
    "lambda_dssim": between(0.0, 1.0),
    "lambda_mask": non_negative(),
    "prune_opacity": between(0.0, 1.0, hi_open=True),
    "prune_every": non_negative("0: only at the end"),
    "carve_grid": at_least(2),
    "carve_extent": positive(),
    "box_margin": non_negative(),
    "scan_size": positive(),
    "register_iterations": non_negative(),
    "register_lr": positive(),
    "register_lambda_center": non_negative(),
    "register_lambda_rgb": non_negative(),
}
