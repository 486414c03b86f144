"""When the object touches the ground: the anchors within a tolerance of the ground plane
(`touching`) and the first frame any does (`hit_frame`)."""

from __future__ import annotations

import numpy as np


def touching(anchors: np.ndarray, ground_point, ground_normal, tol: float | None = None) -> np.ndarray:
    """[T] bool: frames in which the lowest of `anchors` [T, N, 3] is within `tol` of the ground
    plane (default: 1e-3 of the object's extent at frame 0)."""
    n = np.asarray(ground_normal, float) / np.linalg.norm(ground_normal)
    heights = (np.asarray(anchors, float) - np.asarray(ground_point, float)) @ n  # [T, N]
    tol = 1e-3 * float(np.ptp(anchors[0], axis=0).max()) if tol is None else float(tol)
    return heights.min(axis=1) <= tol


def hit_frame(anchors: np.ndarray, ground_point, ground_normal, tol: float | None = None) -> int:
    """The first frame in which the lowest anchor touches the ground plane (`touching`); frames
    before it are free fall. 1 when it starts in contact."""
    frames = np.flatnonzero(touching(anchors, ground_point, ground_normal, tol))
    return int(max(frames[0], 1)) if frames.size else int(anchors.shape[0] - 1)
