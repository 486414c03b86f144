"""Typed config schema of anchor sampling, springs and IDW binding (group key `anchors`)."""

from __future__ import annotations

from dataclasses import dataclass


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
