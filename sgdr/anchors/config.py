"""Typed config schema of anchor sampling, springs and IDW binding (group key `anchors`)."""

from __future__ import annotations

from dataclasses import dataclass

from sgdr.checks import at_least, choice, non_negative, positive


@dataclass
class AnchorConfig:
    n_anchors: int = 2048  # N_A, anchors volume-sampled from the Gaussian centres
    n_k: int = 256  # springs per anchor (kNN, nearest first)
    sampler: str = "voxel"  # "voxel" (official: voxel downsample + random subset) | "fps"
    voxel_size: float = 0.01  # scene units, for the "voxel" sampler
    n_b: int = 16  # anchors bound to each Gaussian (Eq. 14)
    p_b: float = 0.5  # IDW weight exponent: w = 1 / d^p_b (Eq. 14)
    binding: str = "official"  # "official" (weighted anchor positions) | "displacement"
    min_distance: float = 1.0e-8  # scene units; IDW distances are floored here (a Gaussian on an anchor)


# Allowed values, checked before any work (sgdr.checks; names against their registries).
CHECKS = {
    "n_anchors": at_least(2),
    "n_k": at_least(1),
    "sampler": choice("sgdr.anchors.sampling:SAMPLERS"),
    "voxel_size": positive(),
    "n_b": at_least(1),
    "p_b": non_negative(),
    "binding": choice("sgdr.skin.binding:BINDING_FORMS"),
    "min_distance": positive(),
}
