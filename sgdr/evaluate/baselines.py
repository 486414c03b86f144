"""The physics-free baseline for future prediction (issue 6, quality bar).

Given the reconstructed Gaussian centres of the last two observed (fit) frames, predict the
future without any physics, by rigidly translating the last frame's centres:

- `still`: held where they are;
- `constant_velocity`: moved with the last observed centre-of-mass velocity
  v = (c_{T-1} - c_{T-2}) / dt;
- `ballistic`: moved along the parabola c_{T-1} + v t + g t² / 2 of the centre of mass.

Moving candidates are kept above the ground plane: the translation along the ground normal
is clamped so the lowest point never goes below the ground (or below its own starting
height if it already was). That is a kinematic constraint, not a dynamics model.

Which candidate is "the" baseline: issue 6 defines it as ballistic or held still, "whichever
is better"; we score both on the future frames and report the better one, i.e. the baseline
gets an oracle choice between the two, stronger than any causal rule
(`ISSUE_BASELINES`). The constant-velocity variant is not part of that definition; it is
scored and reported beside it, because on bouncing objects it can be the strongest of all.
"""

from __future__ import annotations

import numpy as np

BASELINES = ("still", "constant_velocity", "ballistic")  # all variants scored
ISSUE_BASELINES = ("ballistic", "still")  # issue 6's baseline: the better of these two


def _clamp_above_ground(last: np.ndarray, shift: np.ndarray, point: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """Limit a translation `shift` [3] of the set `last` [M, 3] so its lowest point stays at
    or above min(0, its current height) relative to the plane (point [3], unit normal [3])."""
    heights = (last - point) @ normal  # [M]
    floor = min(0.0, float(heights.min()))
    lowest_after = float(heights.min() + shift @ normal)
    if lowest_after < floor:
        shift = shift + (floor - lowest_after) * normal
    return shift


def physics_free_predictions(
    prev: np.ndarray,
    last: np.ndarray,
    n_future: int,
    dt: float,
    gravity: np.ndarray,
    ground_point: np.ndarray,
    ground_normal: np.ndarray,
) -> dict[str, list[np.ndarray]]:
    """Future centres of every baseline: {name: [n_future x [M, 3]]}.

    prev, last: [M, 3] reconstructed centres of frames T-2 and T-1 (world, scene units);
    the k-th prediction (k = 1..n_future) is for frame T-1+k, time t = k dt seconds after the
    last observed frame. gravity [3] m/s² (scene units/s²), ground plane point [3], normal [3].
    """
    prev = np.asarray(prev, float)
    last = np.asarray(last, float)
    if prev.shape != last.shape or last.ndim != 2 or last.shape[1] != 3:
        raise ValueError(f"baseline: prev {prev.shape} and last {last.shape} must both be [M, 3]")
    g = np.asarray(gravity, float).reshape(3)
    p0 = np.asarray(ground_point, float).reshape(3)
    n = np.asarray(ground_normal, float).reshape(3)
    n = n / np.linalg.norm(n)
    v = (last.mean(0) - prev.mean(0)) / dt  # [3] centre-of-mass velocity, units/s
    out: dict[str, list[np.ndarray]] = {name: [] for name in BASELINES}
    for k in range(1, n_future + 1):
        t = k * dt
        out["still"].append(last.copy())
        out["constant_velocity"].append(last + _clamp_above_ground(last, v * t, p0, n))
        out["ballistic"].append(last + _clamp_above_ground(last, v * t + 0.5 * g * t * t, p0, n))
    return out
