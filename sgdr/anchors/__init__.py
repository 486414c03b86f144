"""Anchors: volume sampling from Gaussian centres (`sampling`) and the IDW binding of Gaussians
to anchors (`binding`, Eq. 14). The springs between anchors are built by
`sgdr.physics.build_spring_model` (kNN, cKDTree)."""

from sgdr.anchors.binding import BINDING_FORMS, IDWBinding, idw_weights
from sgdr.anchors.config import AnchorConfig
from sgdr.anchors.sampling import SAMPLERS, AnchorInputError, sample_anchors, voxel_downsample

__all__ = [
    "BINDING_FORMS",
    "SAMPLERS",
    "AnchorConfig",
    "AnchorInputError",
    "IDWBinding",
    "idw_weights",
    "sample_anchors",
    "voxel_downsample",
]
