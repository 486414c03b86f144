"""Dr.Jit <-> NumPy: the one place that moves arrays between Dr.Jit and the host.

Library code converts through these functions only (the stages' dataclasses, e.g.
`SimState.numpy`, `Gaussians.to_numpy`, are built on them). Host arrays are float64 unless
asked otherwise; device arrays are float32 (Dr.Jit's `Float` of the active backend, `ad()`).
Everything read back is detached: a host copy never carries gradients.
"""

from __future__ import annotations

import numpy as np

from sgdr.backend import ad


def to_numpy(x, dtype=np.float64) -> np.ndarray:
    """A detached host copy of a Dr.Jit value (Float [N] -> [N], Array3f [N] -> [3, N],
    TensorXf -> its shape), or of anything `np.asarray` takes. dtype None keeps Dr.Jit's."""
    import drjit as dr

    if dr.is_array_v(x):
        x = dr.detach(x).numpy()
    return np.asarray(x) if dtype is None else np.asarray(x, dtype=dtype)


def scalar(x) -> float:
    """A one-element Dr.Jit value (Float or TensorXf) -> Python float (detached)."""
    return float(to_numpy(x).reshape(-1)[0])


def points_to_array3(points: np.ndarray):
    """np [N, 3] -> Array3f [N] (float32)."""
    p = np.asarray(points, dtype=np.float32).reshape(-1, 3)
    return ad().Array3f(*[np.ascontiguousarray(p[:, k]) for k in range(3)])


def array3_to_points(a) -> np.ndarray:
    """Array3f [N] -> np [N, 3] float64 (detached)."""
    return to_numpy(a).T.reshape(-1, 3)
