"""Anchors (stage "anchors"): volume sampling of N_A anchor points from the static fit's
Gaussian centres (`sampling`). The springs between anchors are built by
`sgdr.physics.build_spring_model` (kNN, cKDTree); the skinning of Gaussians to anchors is
`sgdr.skin`."""

from sgdr.anchors.config import AnchorConfig
from sgdr.anchors.sampling import SAMPLERS, AnchorInputError, sample_anchors, voxel_downsample

__all__ = ["SAMPLERS", "AnchorConfig", "AnchorInputError", "sample_anchors", "voxel_downsample"]
