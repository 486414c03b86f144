"""The diagnosis's decision rules: the gain of a candidate over the base (`excess_gain`), the
threshold each candidate needs (`threshold`), the cause named (`decide`), the causes that fit as
well (`rivals`) and the free-flight ties settled by the whole fit window (`settle_mimics`).
`sgdr.discrepancy.run` applies them to one run; `evaluation`'s diagnosis suite re-decides its
recorded cases with them at other thresholds."""

from __future__ import annotations

import numpy as np


def excess_gain(d: float, d_base: float, floor: float | None, margin: float = 0.05) -> float:
    """(d_base - d) / room with room = d_base - floor: the share of the base's discrepancy above
    the floor that a candidate removes, 1 - (d - floor) / (d_base - floor). The room is at least
    `margin` x floor (`diagnose.floor_margin`): a base already at its floor (a twin of the asset
    itself) leaves nothing to explain, and a tiny, chance improvement there must not read as a
    large share of nothing."""
    if not np.isfinite(d):
        return -float("inf")
    floor = 0.0 if floor is None else float(floor)
    room = max(float(d_base) - floor, float(margin) * floor, 1e-12 * abs(float(d_base)), 1e-300)
    return (float(d_base) - float(d)) / room


def threshold(dc, name: str) -> float:
    """The held-out gain candidate `name` needs to be named: `diagnose.min_gain_by_candidate[name]`,
    else `diagnose.min_gain`."""
    return float((dc.min_gain_by_candidate or {}).get(name, dc.min_gain))


def time_threshold(dc, name: str) -> float:
    """The held-out-time gain candidate `name` needs (`diagnose.judge` "time" or "both"):
    `diagnose.min_time_gain_by_candidate[name]`, else `diagnose.min_time_gain`."""
    return float((dc.min_time_gain_by_candidate or {}).get(name, dc.min_time_gain))


def decision_gains(candidates: dict, judge: str, views: dict, time: dict) -> tuple[dict, dict]:
    """The gain each candidate is decided on and the threshold it must reach, under `judge`
    (`diagnose.judge`): "views" its held-out-view gain against `views[name]`; "time" its
    held-out-time gain ("time_gain") against `time[name]`; "both" the time gain against
    `time[name]`, and only when its view gain reaches `views[name]` too (else -inf). A
    free-flight candidate (window "free_flight") is decided on its window's held-out views in
    every mode: the fall is a few frames, too short to hold out the last ones. A candidate without
    a time gain (none held out) cannot pass under "time" or "both"."""
    if judge not in ("views", "time", "both"):
        raise ValueError(f"diagnose.judge={judge!r}: expected views, time or both")
    gains, thresholds = {}, {}
    for n, c in candidates.items():
        if judge == "views" or c.get("window") == "free_flight":
            gains[n], thresholds[n] = c["gain"], views[n]
            continue
        t = c.get("time_gain")
        t = -float("inf") if t is None or not np.isfinite(t) else float(t)
        if judge == "both" and not (c["gain"] is not None and np.isfinite(c["gain"]) and c["gain"] >= views[n]):
            t = -float("inf")
        gains[n], thresholds[n] = t, time[n]
    return gains, thresholds


def _choice_pool(gains: dict, thresholds: dict, first=()) -> list[str]:
    """The candidates a cause is chosen from: those at or above their own threshold, and of those
    only the ones in `first` (the free-flight candidates) when any of them passes."""
    passing = [n for n, g in gains.items() if g is not None and np.isfinite(g) and g >= thresholds[n]]
    first = set(first)
    early = [n for n in passing if n in first]
    return early or passing


def decide(gains: dict, thresholds: dict, first=()) -> str | None:
    """The candidate named: the largest gain among those at or above their own threshold (None:
    no candidate passes, the cause is "none"). Candidates in `first` (the free-flight ones) come
    first: when one of them passes, the largest of those is named. What changes the fall changes
    the contact after it, so a contact-borne candidate may fit its consequence over the whole
    window (the MPM apple with drag 2 /s: a ground raised 5% of its size gained 0.51, drag 0.42 in
    free flight); nothing that acts at contact changes the free flight."""
    pool = _choice_pool(gains, thresholds, first)
    return max(pool, key=lambda n: gains[n]) if pool else None


def rivals(gains: dict, thresholds: dict, best: str | None, causes: dict, margin: float, first=()) -> list[str]:
    """The candidates of another cause that explain the data about as well as `best`: among those
    `decide` chose from (the passing free-flight ones when one passes, else all passing), those
    whose gain is within `margin` (`diagnose.mimic_margin`) of the best's. Weaker gravity and air
    drag both slow a fall and fit its few free-flight frames alike (the MPM suite: their gains
    differed by 0.009-0.025 in all five cases where both passed, and the larger one was wrong once),
    so the named cause is then a coin flip the report must not hide."""
    if best is None:
        return []
    return sorted(
        (
            n
            for n in _choice_pool(gains, thresholds, first)
            if causes[n] != causes[best] and gains[best] - gains[n] < float(margin)
        ),
        key=lambda n: -gains[n],
    )


def settle_mimics(
    best: str | None, rival: list[str], window_gains: dict, margin: float, thresholds: dict
) -> tuple[str | None, list[str]]:
    """The named candidate and its rivals after the whole fit window has had its say: when the
    named one and every rival are free-flight candidates with a `fit_window_gain` (each one's
    held-out gain over the whole fit window with its free-flight value), and one of them both
    explains the whole window (its window gain at least its own threshold) and beats every other
    there by at least `margin` (`diagnose.mimic_window_margin`), that one is named and the
    ambiguity is settled; else nothing changes. Weaker gravity and air drag fit a few frames of
    fall alike but part ways after a bounce: drag slows the rise more than the fall, a weaker
    gravity slows both alike (the tiny drag twin: drag 0.933, gravity 0.737). On MPM data the
    contact misfit can make both window gains negative; the one that hurts less is then no
    evidence (the MPM torus with drag 2 /s: gravity -0.64, drag -1.74), hence the threshold."""
    if best is None or not rival:
        return best, rival
    group = [best, *rival]
    w = {n: window_gains.get(n) for n in group}
    if any(v is None or not np.isfinite(v) for v in w.values()):
        return best, rival
    top = max(group, key=lambda n: w[n])
    if w[top] >= thresholds[top] and all(w[top] - w[n] >= float(margin) for n in group if n != top):
        return top, []
    return best, rival
