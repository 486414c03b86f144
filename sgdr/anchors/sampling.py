"""Volume sampling V of anchors from Gaussian centres (Sec. 3.2 of the seed paper), by name.

- `voxel` (official): average the points of every occupied voxel of edge `voxel_size`, then
  keep a seeded random subset of n voxel centroids. If fewer than n voxels are occupied the
  voxel edge is halved until there are enough (at most 20 times).
- `fps`: farthest-point sampling, seeded start, exact (O(M n) NumPy).
"""

from __future__ import annotations

import numpy as np

from sgdr.registry import Registry


class AnchorInputError(ValueError):
    """Invalid input to anchor sampling or binding; the message names what is wrong."""


SAMPLERS = Registry("anchor sampler", "anchors.sampler", AnchorInputError)


def voxel_downsample(points: np.ndarray, voxel_size: float) -> np.ndarray:
    """Centroid of the points in every occupied voxel, [V, 3], in a deterministic order."""
    keys = np.floor(points / voxel_size).astype(np.int64)
    _, inverse, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    inverse = inverse.reshape(-1)
    sums = np.zeros((counts.shape[0], 3))
    np.add.at(sums, inverse, points)
    return sums / counts[:, None]


@SAMPLERS.register("voxel")
def sample_voxel(points: np.ndarray, n: int, voxel_size: float, rng: np.random.Generator) -> np.ndarray:
    if not voxel_size > 0:
        raise AnchorInputError(f"anchors.voxel_size={voxel_size} must be positive")
    size = float(voxel_size)
    for _ in range(20):
        centres = voxel_downsample(points, size)
        if centres.shape[0] >= n:
            return centres[np.sort(rng.choice(centres.shape[0], size=n, replace=False))]
        size *= 0.5
    raise AnchorInputError(f"voxel sampler: only {centres.shape[0]} occupied voxels at size {size:g}, need {n}")


@SAMPLERS.register("fps")
def sample_fps(points: np.ndarray, n: int, voxel_size: float, rng: np.random.Generator) -> np.ndarray:
    chosen = np.empty(n, dtype=np.int64)
    chosen[0] = rng.integers(points.shape[0])
    dist = np.sum((points - points[chosen[0]]) ** 2, axis=1)
    for a in range(1, n):
        chosen[a] = int(np.argmax(dist))
        dist = np.minimum(dist, np.sum((points - points[chosen[a]]) ** 2, axis=1))
    return points[chosen]


def sample_anchors(points: np.ndarray, n: int, sampler: str, voxel_size: float, seed: int) -> np.ndarray:
    """N_A = n anchors [n, 3] from points [M, 3] (world, scene units) with the named sampler."""
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise AnchorInputError(f"points must have shape [M, 3], got {points.shape}")
    if not np.all(np.isfinite(points)):
        raise AnchorInputError("points contain NaN/inf")
    if not 1 <= n <= points.shape[0]:
        raise AnchorInputError(f"anchors.n_anchors={n} must be in [1, M={points.shape[0]}] (number of points)")
    return SAMPLERS.get_named(sampler)(points, int(n), voxel_size, np.random.default_rng(seed))
