"""The candidate extensions a diagnosis fits, and how one is fitted and judged.

Each candidate (`CANDIDATES`, a registry) names the cause it stands for, the `physics.*` setting
it frees (`sgdr.physics.extensions`; the setting's null value is the base model) and the search
interval. A candidate is fitted from the base fit: every identified parameter is kept, and only
the extension's one value is searched (scipy's bounded Brent search, `diagnose.evaluations`
rollouts) to minimise the silhouette discrepancy D (`sgdr.posterior.likelihood.discrepancy`, the
symmetric Chamfer distance between silhouettes and projected Gaussian centres, pixels²) summed
over the *fitting* views. It is judged on the *held-out* views (every other view; never used for
the fit) by its gain over the base (`sgdr.discrepancy.run`).

Why held-out views: one more free value always lowers the fitting loss a little; what transfers
to views the search never saw is what the data ask for. The threshold `diagnose.min_gain` is the
flexibility guard, calibrated on null data (docs/discrepancy.md).

Interval: the values the search evaluated whose fitting D lies within 5% of the best one (a
profile interval; coarse, from the search's own points).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from sgdr.registry import Registry


@dataclass(frozen=True)
class Candidate:
    cause: str  # the cause it stands for (diagnosis.json "cause")
    setting: str  # the physics.* setting it frees
    low: float  # search interval; in object sizes when `relative`
    high: float
    relative: bool = False  # the interval is in units of the object's size (lengths)


CANDIDATES = Registry("diagnosis candidate", "diagnose.candidates", ValueError)
CANDIDATES["air_drag"] = Candidate("air_drag", "air_drag", 0.0, 8.0)  # 1/s
CANDIDATES["gravity"] = Candidate("gravity", "gravity_scale", 0.6, 1.4)
CANDIDATES["ground_plane"] = Candidate("ground_plane", "ground_offset", -0.15, 0.15, relative=True)


@dataclass
class Fit:
    value: float  # the fitted setting
    interval: tuple  # (low, high) profile interval of the setting
    d_fit: float  # fitting-views D at the fitted value
    d_held_out: float  # held-out-views D at the fitted value
    d_future: float | None  # D over the future frames (all views), when the sequence has them
    evaluated: list  # [(value, fitting D)] in the order the search ran


class Evaluator:
    """D of the asset's rollouts with given physics settings, on fitting / held-out views and
    future frames; positions are cached per settings."""

    def __init__(self, asset, rollout, obs_fit, obs_held, obs_future, centre_map):
        from sgdr.physics import Ground

        self.asset, self.rollout = asset, rollout
        self.obs_fit, self.obs_held, self.obs_future = obs_fit, obs_held, obs_future
        self.centre_map = centre_map
        self.model, _ = asset.build()
        self.ground = Ground(asset.ground_point, asset.ground_normal)
        frames = [obs_fit.frames, obs_held.frames] + ([obs_future.frames] if obs_future is not None else [])
        self.n_frames = int(max(int(np.max(f)) for f in frames)) + 1
        self.cache: dict = {}

    def positions(self, settings: dict) -> np.ndarray | None:
        key = tuple(sorted(settings.items()))
        if key not in self.cache:
            cfg = replace(self.asset.physics, **settings)
            pos, stable = self.rollout(
                self.model,
                self.asset.values,
                {"log10_k_shift": np.zeros(1)},
                self.ground,
                self.n_frames,
                1.0 / self.asset.fps,
                self.asset.n_substeps,
                cfg,
            )
            self.cache[key] = pos[0] if stable[0] else None
        return self.cache[key]

    def d(self, settings: dict, obs) -> float:
        from sgdr.posterior.likelihood import discrepancy

        pos = self.positions(settings)
        if pos is None:
            return float("inf")
        return float(np.sum(discrepancy(obs, self.centre_map(pos[None, obs.frames]))))


def fit_candidate(ev: Evaluator, cand: Candidate, size: float, evaluations: int) -> Fit:
    from scipy.optimize import minimize_scalar

    scale = size if cand.relative else 1.0
    lo, hi = cand.low * scale, cand.high * scale
    evaluated = []

    def objective(value):
        d = ev.d({cand.setting: float(value)}, ev.obs_fit)
        evaluated.append((float(value), d))
        return d

    res = minimize_scalar(
        objective, bounds=(lo, hi), method="bounded", options={"maxiter": int(evaluations), "xatol": 1e-3 * (hi - lo)}
    )
    best = float(res.x)
    d_best = min(d for _, d in evaluated)
    near = [v for v, d in evaluated if d <= 1.05 * d_best]
    settings = {cand.setting: best}
    return Fit(
        value=best,
        interval=(float(min(near)), float(max(near))),
        d_fit=ev.d(settings, ev.obs_fit),
        d_held_out=ev.d(settings, ev.obs_held),
        d_future=ev.d(settings, ev.obs_future) if ev.obs_future is not None else None,
        evaluated=evaluated,
    )
