"""Typed config schema of the Gaussian splat renderer (group key `render`)."""

from __future__ import annotations

from dataclasses import dataclass, field

from sgdr.checks import at_least, between, non_negative, positive, vector


@dataclass
class RenderConfig:
    tile_size: int = 16  # pixels per tile side for binning
    pixels_per_thread: int = 4  # rows of a tile column shaded by one thread (divides tile_size)
    dilation: float = 0.3  # screen-space covariance dilation, pixels² (3DGS low-pass)
    near: float = 0.01  # near plane, scene units; Gaussians in front of it are culled
    alpha_min: float = 1.0 / 255.0  # contributions below this alpha are skipped
    alpha_max: float = 0.99  # per-Gaussian alpha is clamped here (keeps T_i = T_{i+1}/(1-α) stable)
    transmittance_min: float = 1e-4  # early termination of front-to-back compositing
    guard_band: float = 1.3  # x/z, y/z are clamped to this multiple of the half field of view in J
    check_finite: bool = True  # raise a RenderError naming the field when a parameter is NaN/inf
    background: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])  # RGB


# Allowed values, checked before any work (sgdr.checks).
CHECKS = {
    "tile_size": at_least(1),
    "pixels_per_thread": at_least(1),
    "dilation": non_negative(),
    "near": positive(),
    "alpha_min": between(0.0, 1.0, lo_open=True, hi_open=True),
    "alpha_max": between(0.0, 1.0, lo_open=True, hi_open=True),
    "transmittance_min": between(0.0, 1.0, lo_open=True, hi_open=True),
    "guard_band": positive(),
    "background": vector(3, each=between(0.0, 1.0)),
}
