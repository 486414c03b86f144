"""What would separate free-flight mimics the data cannot tell apart (a weaker gravity and air drag
tied on a short fall): how many frames of free flight the two fitted models need before their
predicted centres part by a pixel in some view, and how fast a sideways throw would have to be for
drag's slowing of the horizontal motion to show by the last free-flight frame observed.

Both models are closed-form falls from the same start (`candidates._fall_basis`: x(t) = x0 +
v0 φ(t) + s g ψ(t) under linear drag c), each with the gravity scale, drag and v0 its fit
applied (`sgdr.discrepancy.run`'s `applied`); each camera projects the object's centre moved by
either fall. Reported in diagnosis.json "separate", never used to decide.
"""

from __future__ import annotations

import numpy as np

from sgdr.discrepancy.candidates import _fall_basis


def _fall(scale: float, drag: float, v0: np.ndarray, g: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Displacements [T, 3] of a fall with gravity `scale` x g and linear `drag` (1/s)."""
    phi, psi = _fall_basis(float(drag), t)
    return phi[:, None] * v0[None, :] + float(scale) * psi[:, None] * g[None, :]


def _pixels(cameras, centre: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Per time, the largest distance (pixels) over the cameras between the projections of
    centre + a[t] and centre + b[t]."""
    out = np.zeros(a.shape[0])
    for cam in cameras:
        ua, za = cam.project(centre + a)
        ub, zb = cam.project(centre + b)
        d = np.linalg.norm(ua - ub, axis=1)
        out = np.maximum(out, np.where((za > 0) & (zb > 0), d, 0.0))
    return out


def separating_frames(models: dict, gravity, cameras, centre, fps: float, observed: int,
                      pixel: float = 1.0, max_seconds: float = 10.0) -> dict:  # fmt: skip
    """models: {name: (gravity scale, drag 1/s, v0 [3])} of two or more tied free-flight fits;
    gravity [3] the recorded gravity; cameras the sequence's; centre [3] the object's centre at
    frame 0; observed: the free-flight frames the data hold (the window's last frame number).
    Returns the first frame after which every pair of models' predicted centres differ by at least
    `pixel` in some view (None: not within `max_seconds`), the largest difference (pixels) over the
    observed frames, and the sideways speed (scene units / s) a throw would need for the drag
    models' horizontal slowing to part them from a drag-free one by `pixel` at the observed last
    frame (None when no model has drag, or all do)."""
    g = np.asarray(gravity, float).reshape(3)
    centre = np.asarray(centre, float).reshape(3)
    n = max(int(np.ceil(max_seconds * fps)), int(observed) + 1)
    t = np.arange(1, n + 1) / float(fps)
    names = sorted(models)
    falls = {k: _fall(models[k][0], models[k][1], np.asarray(models[k][2], float).reshape(3), g, t) for k in names}
    apart = np.full(n, np.inf)
    for i, a in enumerate(names):
        for b in names[i + 1 :]:
            apart = np.minimum(apart, _pixels(cameras, centre, falls[a], falls[b]))
    beyond = np.flatnonzero(apart >= pixel)
    first = int(beyond[0]) + 1 if beyond.size else None
    within = float(np.max(apart[: int(observed)])) if observed > 0 else 0.0
    drags = [float(models[k][1]) for k in names]
    sideways = None
    if any(c > 0 for c in drags) and any(c <= 0 for c in drags):
        c = max(drags)
        t_obs = np.array([max(int(observed), 1) / float(fps)])
        lag = float(t_obs[0] - _fall_basis(c, t_obs)[0][0])  # the distance a unit sideways speed loses to drag
        # the pixels one scene unit sideways (across gravity) spans at the object, in the view where
        # it spans most (a 1% step: the projection is not linear)
        up = -g / max(float(np.linalg.norm(g)), 1e-12)
        side = np.cross(up, [1.0, 0.0, 0.0] if abs(up[0]) < 0.9 else [0.0, 1.0, 0.0])
        side /= np.linalg.norm(side)
        step = 0.01
        span = max(
            float(np.linalg.norm(np.subtract(*cam.project(np.stack([centre + step * h, centre]))[0]))) / step
            for cam in cameras
            for h in (side, np.cross(up, side))
        )
        sideways = float(pixel / (span * lag)) if lag > 0 and span > 0 else None
    return {
        "free_flight_frames": first,
        "seconds": None if first is None else first / float(fps),
        "observed_frames": int(observed),
        "pixels_within_observed": within,
        "pixel": float(pixel),
        "sideways_speed": sideways,
    }
