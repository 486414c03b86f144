"""What a frame is compared with: its target images (`frame_targets`) and the ground plane the
simulation uses (`raised_ground`: the sequence's ground raised by the contact margin)."""

from __future__ import annotations

import numpy as np

from sgdr.physics import Ground
from sgdr.render.images import to_tensor


def frame_targets(seq, frame: int) -> list:
    """Ground-truth images of every view of `frame` as TensorXf [H, W, 3]."""
    return [to_tensor(seq.image(v, frame)) for v in range(len(seq.cameras))]


def raised_ground(seq, margin: float):
    """The sequence's ground plane moved `margin` scene units along its normal, as a `Ground`:
    the plane the anchors (interior points) collide with."""

    normal = np.asarray(seq.ground_normal, float) / np.linalg.norm(np.asarray(seq.ground_normal, float))
    return Ground(np.asarray(seq.ground_point, float) + float(margin) * normal, normal)
