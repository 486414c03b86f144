"""`run_diagnosis(cfg)`: which extension a finished run's sequence asks for (docs/discrepancy.md).

1. The run's asset (its identified physics) and the observed sequence (the run's own, or
   `diagnose.sequence`, e.g. a twin with an injected effect).
2. Observations of the measure (`diagnose.discrepancy`, `sgdr.discrepancy.measures`): the fit frames after
   frame 0, except the last `diagnose.held_out_time` share of them, in the fitting views (even
   positions among the views) and in the held-out views (odd positions); the held-out time (those
   last fit frames) in all views; the future frames in all views when the sequence has them.
3. The base model's D on each, then every candidate (`sgdr.discrepancy.candidates`) fitted on
   the fitting views of the earlier frames and judged on the held-out views of those frames and on
   the open-loop rollout of the held-out time.
4. The decision (`diagnose.judge`: on the held-out views, the held-out time, or both): among the
   candidates whose gain reaches their threshold (`diagnose.min_gain_by_candidate` /
   `min_time_gain_by_candidate`, else `diagnose.min_gain` / `min_time_gain`), the largest gain
   names the cause; none passing: "none"; gain = 1 - (D(candidate) - floor) /
   (D(base) - floor), the share of the base's discrepancy above the floor it removes. A named
   cause's extended asset is written (`asset_extended/`) with the residual it removes per frame.
   The floor is frame 0's D in the same views, once per frame: the rest state is the static
   fit's and no extension changes it, so what it leaves (appearance, the measure's own
   representation error) is not the dynamics' to explain. Without the floor a gain is diluted by
   it, the more the better the dynamics already fit (`relative_gain` keeps 1 - D / D_base).
5. The residual diagnostics of the base fit (`sgdr.discrepancy.residuals`, when
   `diagnose.residuals`): `residuals.json` and residual_*.png beside diagnosis.json, the headline
   numbers in diagnosis.json "residuals".

Writes `diagnosis.json` (strict JSON) and returns it, and adds the 'Model discrepancy' section
to `<run>/report/report.html` when that page exists.
"""

from __future__ import annotations

import json
import logging
import shutil
import time
from dataclasses import dataclass, replace
from dataclasses import replace as dc_replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from sgdr.discrepancy.candidates import CANDIDATES, CONTROLS, Context, Evaluator, fit_candidate
from sgdr.discrepancy.decision import (
    decide,
    decision_gains,
    excess_gain,
    rivals,
    settle_mimics,
    threshold,
    time_threshold,
)
from sgdr.discrepancy.measures import MEASURES
from sgdr.discrepancy.report import plot_extension, section, write_plots
from sgdr.discrepancy.residuals import d_matrix, residual_diagnostics, summary
from sgdr.discrepancy.separate import separating_frames
from sgdr.discrepancy.truth import scene_of, truth_values
from sgdr.evaluate.score import strict_json
from sgdr.observe.contact import touching
from sgdr.physics.simulate import stable_substeps
from sgdr.posterior.rollouts import ROLLOUTS
from sgdr.report.html import add_section
from sgdr.run_folder import run_asset_and_sequence, run_sequence

log = logging.getLogger(__name__)


def frame0_floor(measure, seq, views, n_frames: int, dc, seed, score, positions) -> float:
    """The floor of a gain: frame 0's D in `views` (the rest state, which no extension changes),
    once per frame of an observation of `n_frames` frames; `positions` any rollout's [T, N_A, 3]
    (frame 0 is the rest state in each)."""
    zero = measure.observe(seq, views, np.array([0]), dc, seed)
    return float(n_frames * np.sum(score(zero, positions)))


def _same_sequence(a, b) -> bool:
    try:
        return Path(a).resolve() == Path(b).resolve()
    except OSError:
        return False


@dataclass
class Observed:
    """What the diagnosis compares with: the run's asset and sequence, the views and frames each
    part of the judgement uses, the measure's observations of them and the evaluator that scores
    a setting of the model on them."""

    run_dir: Path
    asset_dir: Path
    asset: object
    seq_dir: Path
    seq: object
    views: list
    fit_views: list
    held_views: list
    fit_frames: np.ndarray
    future: np.ndarray
    measure: object
    obs_fit: object
    obs_held: object
    obs_future: object
    score: object
    ev: Evaluator
    time_frames: np.ndarray  # the held-out time: the fit window's last frames (empty: none held out)
    obs_time: object  # their observation in all views (None: none held out)


def held_out_time_frames(n_fit: int, share: float, where) -> int:
    """How many of the fit window's last frames are held out (`diagnose.held_out_time`, a share of
    the fit frames after frame 0, at least one when the share is positive); at least two fit frames
    after frame 0 must stay before them."""
    if share <= 0:
        return 0
    n = max(1, int(round(float(share) * (n_fit - 1))))
    if n_fit - 1 - n < 2:
        raise ValueError(
            f"{where}: {n_fit} fit frames; holding out the last {n} (diagnose.held_out_time={share}) leaves "
            f"{n_fit - 1 - n} after frame 0 to fit, need 2 (lower diagnose.held_out_time, 0 = none held out)"
        )
    return n


def observe_run(cfg) -> Observed:
    """Step 1-2: the run's asset and sequence, the fitting views (even positions), the held-out
    views (odd positions), the fit frames after frame 0 and the future frames, each observed by
    `diagnose.discrepancy`'s measure."""
    dc = cfg.diagnose
    run_dir = Path(dc.run)
    asset_dir, asset, seq_dir, seq = run_asset_and_sequence(run_dir, dc.sequence, cfg.scene_file, "diagnose")
    if len(seq.cameras) < 2:
        raise ValueError(f"{seq_dir}: one view; the diagnosis needs held-out views (at least 2)")
    views = list(range(len(seq.cameras)))
    fit_views, held_views = views[0::2], views[1::2]
    fit_end = seq.n_fit - held_out_time_frames(seq.n_fit, float(dc.held_out_time), seq_dir)
    fit_frames = np.arange(1, fit_end, int(dc.frame_stride))
    if fit_frames.size == 0:
        raise ValueError(f"{seq_dir}: no fit frame after frame 0")
    time_frames = np.arange(fit_end, seq.n_fit)
    measure = MEASURES.get_named(dc.discrepancy, "diagnose.discrepancy")
    obs_fit = measure.observe(seq, fit_views, fit_frames, dc, cfg.seed)
    obs_held = measure.observe(seq, held_views, fit_frames, dc, cfg.seed)
    obs_time = measure.observe(seq, views, time_frames, dc, cfg.seed) if time_frames.size else None
    future = np.arange(seq.n_fit, seq.n_frames)
    obs_future = measure.observe(seq, views, future, dc, cfg.seed) if future.size else None
    score = measure.scorer(asset, dc, cfg.render, cfg.seed)
    rollout = ROLLOUTS.get_named(dc.rollout, "diagnose.rollout")
    ev = Evaluator(asset, rollout, obs_fit, obs_held, obs_future, score, obs_time)
    return Observed(run_dir, asset_dir, asset, seq_dir, seq, views, fit_views, held_views, fit_frames, future,
                    measure, obs_fit, obs_held, obs_future, score, ev, time_frames, obs_time)  # fmt: skip


def base_and_floor(o: Observed, dc, seed) -> tuple[dict, dict]:
    """The base model's D on the fitting, held-out, held-out-time and future observations, and the
    floor of each gain: frame 0's D (the rest state, which no extension changes) in the same views,
    once per frame of the observation: what the asset's appearance leaves that no dynamics can
    remove."""
    ev = o.ev
    base = {"d_fit": ev.d({}, o.obs_fit), "d_held_out": ev.d({}, o.obs_held)}
    base["d_time"] = ev.d_or_none({}, o.obs_time)
    base["d_future"] = ev.d_or_none({}, o.obs_future)
    if not np.isfinite(base["d_held_out"]):
        raise RuntimeError(f"{o.asset_dir}: the identified parameters' rollout is unstable")
    floor = {}
    parts = (("held_out", o.held_views, o.fit_frames.size), ("time", o.views, o.time_frames.size),
             ("future", o.views, o.future.size))  # fmt: skip
    for key, vs, n in parts:
        floor[key] = frame0_floor(o.measure, o.seq, vs, n, dc, seed, o.score, ev.positions({})) if n else None
    base["floor_held_out"], base["floor_time"], base["floor_future"] = floor["held_out"], floor["time"], floor["future"]
    return base, floor


def candidate_context(o: Observed) -> tuple[Context, bool]:
    """The candidates' context and whether the sequence is the run's own. v0 is refitted with
    gravity and drag only on the sequence the run fitted it to (its pre-hit frames under the base
    model); another sequence (a twin) keeps the asset's v0."""
    own = _same_sequence(o.seq_dir, run_sequence(o.run_dir))
    ctx = Context(
        values=o.asset.values,
        physics=o.asset.physics,
        anchors=np.asarray(o.asset.anchors, float),
        size=float(np.linalg.norm(np.ptp(np.asarray(o.asset.anchors, float), axis=0))),
        free_fall_times=np.arange(1, max(int(o.seq.hit_frame), 1)) / float(o.asset.fps) if own else np.zeros(0),
    )
    return ctx, own


def refit_base(ev, ctx, dc, base: dict, floor: dict) -> tuple[dict | None, dict, dict]:
    """Step 3a (`diagnose.rebase`): the base's own parameters refitted (`refit_controls`), twice.
    The second sweep has the budget each candidate's joint refit gets: a candidate at its null
    value plus that sweep must not beat the base by the sweep alone (on a tiny twin 10^0.5 stiffer
    a null stiffness ratio "gained" 0.42 that way). Returns (the refit's record or None, the
    replaced values, the base after the refit)."""
    if not dc.rebase:
        return None, {}, base
    margin = float(dc.floor_margin)
    rebase = refit_controls(ev, ctx, dc, dc.evaluations)
    refit_values = rebase.pop("replacements")
    second = refit_controls(ev, ctx, dc, max(4, int(dc.evaluations) // 2), None, refit_values)
    rebase["second_sweep"] = second["steps"]
    if second["d_fit"] < rebase["d_fit"]:
        refit_values = {**refit_values, **second["replacements"]}
        rebase.update({k: second[k] for k in ("d_fit", "d_held_out", "d_time", "d_future")})
    rebase["held_out_gain"] = excess_gain(rebase["d_held_out"], base["d_held_out"], floor["held_out"], margin)
    rebase["time_gain"] = optional_gain(rebase["d_time"], base["d_time"], floor["time"], margin)
    rebase["future_gain"] = optional_gain(rebase["d_future"], base["d_future"], floor["future"], margin)
    base = {**base, **{k: rebase[k] for k in ("d_fit", "d_held_out", "d_time", "d_future")}}
    log.info(
        "diagnose: base refit %s, held-out gain %.3f over the asset's fit",
        {n: st["values"] for n, st in rebase["steps"].items()}, rebase["held_out_gain"],
    )  # fmt: skip
    return rebase, refit_values, base


def fit_candidates(ev, ctx, dc, base, floor, asset_fit, rebase, asset_state, refit_state, flight, applied=None) -> dict:
    """Step 3b: every candidate of `diagnose.candidates` fitted and judged on the held-out views
    (the free-flight ones on the free-flight window when there is one). Each candidate is fitted
    from the run's own fit (where a twin's effect is alone: the refit's controls may have absorbed
    part of it, e.g. a tiny twin's ground offset 0.05 sizes fitted 0.0099 for 0.029 from the
    refit), then the controls are refitted beside it. When that ends above the refit base on the
    fitting views, the search lost its way from a fit the refit had moved far from (the MPM torus
    with gravity x0.85: gravity x1.24, held-out D twice the base's); the candidate is then fitted
    again from the refit base, the better fit kept. `applied` (a dict, when given) gets per
    candidate what its final rollout is: (the start "asset" | "refit", its physics settings, the
    values it and the controls refitted beside it replace)."""
    margin = float(dc.floor_margin)
    candidates = {}
    applied = {} if applied is None else applied

    def fitted(cand, start: str):
        values, settings, ctx.values = asset_state if start == "asset" else refit_state
        ev.reset(values, settings)
        nested = candidates.get(cand.starts_from)  # e.g. the tilt starts from the fitted offset
        warm = nested["values"] if nested is not None and not nested.get("at_null", False) else None
        fit = fit_candidate(ev, cand, ctx, dc.evaluations, start=warm)
        d_alone, joint = fit.d_held_out, None
        settings, repl = cand.apply(ctx, fit.values, fit.variant)
        if rebase is not None:  # the base's own parameters refitted with the candidate in place
            joint = refit_controls(ev, ctx, dc, max(4, int(dc.evaluations) // 2), settings, repl)
            repl = {**repl, **joint.pop("replacements")}
            fit = replace(fit, **{k: joint[k] for k in ("d_fit", "d_held_out", "d_time", "d_future")})
        return fit, joint, d_alone, start, (start, settings, repl)

    for name in dc.candidates:
        cand = CANDIDATES.get_named(name, "diagnose.candidates")
        if cand.window == "free_flight" and flight is not None:
            candidates[name] = judge_in_free_flight(cand, flight, ev, refit_state, ctx, base, floor, dc)
            applied[name] = ("refit", *candidates[name].pop("applied"))
            log.info("diagnose: %s = %s, free-flight held-out gain %.3f", name, candidates[name]["values"],
                     candidates[name]["gain"])  # fmt: skip
            continue
        fit, joint, d_alone, start, applied[name] = fitted(cand, "asset")
        if rebase is not None and fit.d_fit > base["d_fit"]:
            again = fitted(cand, "refit")
            if again[0].d_fit < fit.d_fit:
                fit, joint, d_alone, start, applied[name] = again
        # nested: the candidate at its null value is the base, so a fit worse than the base on the
        # fitting views is a search that lost its way, and a fit at the null value gains only
        # what the controls' refit beside it gains; either way the base's losses stand (gain 0)
        at_null = bool(fit.d_fit > base["d_fit"]) or cand.at_null(fit.values, ctx.size)
        if at_null:
            fit = replace(fit, **{k: base[k] for k in ("d_fit", "d_held_out", "d_time", "d_future")})
        candidates[name] = candidate_record(
            cand,
            fit,
            (base["d_held_out"], floor["held_out"]),
            (base["d_future"], floor["future"]),
            margin,
            joint,
            time=(base["d_time"], floor["time"]),
            gain_over_asset_fit=excess_gain(d_alone, asset_fit["d_held_out"], floor["held_out"], margin),
            at_null=at_null,
            window="fit",
        )
        candidates[name]["from"] = start
        log.info("diagnose: %s = %s, held-out gain %.3f", name, fit.values, candidates[name]["gain"])
    return candidates


def judge_at_truth(candidates: dict, o: Observed, ev, refit_state, ctx, base, floor, dc, flight) -> None:
    """With `diagnose.truth` and a sequence that records injected effects: each candidate also
    judged at the injected values (its record's "truth")."""
    truth = o.seq.gt_effects() if dc.truth and o.seq.gt_dir is not None else None
    if not (truth and truth.get("active")):
        return
    scene = scene_of(o.seq, o.asset)
    for name, rec in candidates.items():
        at = truth_values(name, truth, scene)
        if at is not None:
            cand = CANDIDATES.get_named(name, "diagnose.candidates")
            where = flight if rec["window"] == "free_flight" else None
            rec["truth"] = judge_truth(cand, at, where, ev, refit_state, ctx, base, floor, dc)
            log.info("diagnose: %s at the truth %s, held-out gain %.3f", name, at[0], rec["truth"]["gain"])


def name_cause(candidates: dict, dc) -> tuple[str | None, list[str], list[str]]:
    """Step 4 (`sgdr.discrepancy.decision`): the named candidate, its rivals (other causes that fit
    as well) and the free-flight mimics a tie was settled between (else []), each candidate decided
    on the gain `diagnose.judge` names (`decision_gains`); each candidate's record gets its
    thresholds, what it was decided on and its decision."""
    views = {n: threshold(dc, n) for n in candidates}
    time = {n: time_threshold(dc, n) for n in candidates}
    gains, thresholds = decision_gains(candidates, dc.judge, views, time)
    free = [n for n, c in candidates.items() if c["window"] == "free_flight"]
    best = decide(gains, thresholds, free)
    causes = {n: c["cause"] for n, c in candidates.items()}
    rival = rivals(gains, thresholds, best, causes, dc.mimic_margin, free)
    tie = [best, *rival] if rival else []
    window_gains = {n: c.get("fit_window_gain") for n, c in candidates.items()}
    best, rival = settle_mimics(best, rival, window_gains, dc.mimic_window_margin, thresholds)
    for name, c in candidates.items():
        c["min_gain"], c["min_time_gain"] = views[name], time[name]
        c["decided_on"] = "views" if dc.judge == "views" or c["window"] == "free_flight" else dc.judge
        c["decision"] = "cause" if name == best else "as good" if name in rival else "rejected"
    return best, rival, (tie if tie and not rival else [])


def write_outputs(record: dict, o: Observed, dc, rebase, refit_values, asset_state, ctx, t0: float,
                  named=None) -> dict:  # fmt: skip
    """Step 5 and the files: the refit asset when the refit carries to the held-out views
    (`diagnose.refit_min_gain`); for a named cause (`named`: its name, what it applied and the
    state it started from) the extended asset and the residual it removes per frame; the residual
    diagnostics of the run's own fit, diagnosis.json and the report's section."""
    out = Path(dc.out_dir) if dc.out_dir else o.run_dir / "diagnose"
    out.mkdir(parents=True, exist_ok=True)
    if named is not None:
        record["extension"] = write_extension(record, o, named, out)
    if refit_values and rebase["held_out_gain"] >= float(dc.refit_min_gain):
        record["refit_asset"] = str(write_refit_asset(o.asset, refit_values, out / "asset_refit", rebase))
        log.info("diagnose: the refit asset -> %s", record["refit_asset"])
    residuals, plots = None, None
    o.ev.reset(asset_state[0], asset_state[1])  # the residuals are the run's own fit's
    ctx.values = asset_state[2]
    if dc.residuals:
        parts = [(o.fit_views, o.obs_fit), (o.held_views, o.obs_held), (o.views, o.obs_time), (o.views, o.obs_future)]
        residuals, plots = write_residuals(o.ev, parts, o.seq, o.asset, dc, out, o.measure.unit)
        record["residuals"] = summary(residuals)
    record["seconds"] = time.time() - t0
    record = strict_json(record)
    (out / "diagnosis.json").write_text(json.dumps(record, indent=1, allow_nan=False))
    record["file"] = str(out / "diagnosis.json")
    report = o.run_dir / "report" / "report.html"
    if report.exists():
        add_section(report, section(record, residuals, plots))
        record["report"] = str(report)
    else:
        log.info("diagnose: %s missing, no report section added", report)
    return record


def run_diagnosis(cfg) -> dict:
    """The steps of the module's docstring; returns the record written to diagnosis.json."""
    dc = cfg.diagnose
    t0 = time.time()
    o = observe_run(cfg)
    base, floor = base_and_floor(o, dc, cfg.seed)
    ctx, own = candidate_context(o)
    asset_fit = dict(base)  # the asset's own fit, before any refit
    rebase, refit_values, base = refit_base(o.ev, ctx, dc, base, floor)
    asset_state = (dict(o.ev.values), dict(o.ev.settings), ctx.values)
    refit_state = ({**o.ev.values, **refit_values}, dict(o.ev.settings), {**ctx.values, **refit_values})
    flight = free_flight(o.seq, o.asset, o.measure, dc, cfg.seed, o.fit_views, o.held_views, o.fit_frames, o.score,
                         refit_values)  # fmt: skip
    applied: dict = {}
    candidates = fit_candidates(
        o.ev, ctx, dc, base, floor, asset_fit, rebase, asset_state, refit_state, flight, applied
    )
    judge_at_truth(candidates, o, o.ev, refit_state, ctx, base, floor, dc, flight)
    best, rival, settled = name_cause(candidates, dc)
    record = {
        "cause": candidates[best]["cause"] if best is not None else "none",
        # other causes that fit as well (gains within diagnose.mimic_margin): the data do not
        # tell them apart from the named one
        "ambiguous_with": [candidates[n]["cause"] for n in rival],
        "candidates": candidates,
        "base": base,
        "asset_fit": asset_fit,
        "rebase": rebase,
        "min_gain": float(dc.min_gain),
        "mimic_margin": float(dc.mimic_margin),
        "mimic_window_margin": float(dc.mimic_window_margin),
        # the free-flight mimics a tie was settled between by their gains over the whole fit
        # window (settle_mimics), the named one first in the free-flight gains' order; else []
        "settled_among": settled,
        "discrepancy": {"measure": dc.discrepancy, "unit": o.measure.unit},
        "v0_refit": bool(own),
        "fitting_views": [o.seq.cameras[v].name for v in o.fit_views],
        "held_out_views": [o.seq.cameras[v].name for v in o.held_views],
        "frames": o.fit_frames.tolist(),
        # the fit window's last frames, held out: every fit is scored on their open-loop rollout
        "time_frames": o.time_frames.tolist(),
        "judge": dc.judge,
        "free_flight": None if flight is None else flight["record"],
        "future_frames": o.future.tolist(),
        "sequence": str(o.seq_dir),
        "run": str(o.run_dir),
        "truth": o.seq.gt_effects() or {},
        "seconds": time.time() - t0,
    }
    if rival and flight is not None and all(candidates[n]["window"] == "free_flight" for n in [best, *rival]):
        record["separate"] = separate_mimics([best, *rival], applied, refit_state, ctx, o, flight)
    start = (refit_state if applied[best][0] == "refit" else asset_state) if best else None
    named = (best, applied[best], start, refit_state) if best else None
    return write_outputs(record, o, dc, rebase, refit_values, asset_state, ctx, t0, named)


def separate_mimics(names: list, applied: dict, refit_state, ctx, o: Observed, flight: dict) -> dict:
    """What would tell tied free-flight candidates apart (`sgdr.discrepancy.separate`): each one's
    fall as its fit applied it (gravity scale, drag, v0) from the refit base."""
    models = {}
    for n in names:
        _, settings, repl = applied[n]
        models[n] = (
            float(settings.get("gravity_scale", ctx.physics.gravity_scale)),
            float(settings.get("air_drag", ctx.physics.air_drag)),
            np.asarray(repl.get("v0", refit_state[0]["v0"]), float),
        )
    centre = np.asarray(o.asset.anchors, float).mean(axis=0)
    observed = int(flight["record"]["frames"][-1])
    out = separating_frames(models, refit_state[0]["gravity"], o.seq.cameras, centre, float(o.asset.fps), observed)
    log.info("diagnose: %s tie; %s free-flight frames would part them by a pixel", names, out["free_flight_frames"])
    return {"candidates": names, **out}


def free_flight(seq, asset, measure, dc, seed, fit_views, held_views, fit_frames, score, refit_values) -> dict | None:
    """The free-flight window's own evaluator: every fit frame before the sequence's hit frame
    (`diagnose.frame_stride` not applied), where gravity and drag act alone (the object falls
    rigidly: no contact, no stiffness); the
    images at up to `diagnose.free_flight_image_size`, the base the refit base (which the fall
    does not see). None when fewer than 2 such frames: the free-flight candidates then use the
    whole fit window like the rest."""

    frames = np.arange(1, min(int(seq.hit_frame), int(np.max(fit_frames)) + 1))  # every one: few, cheap
    if frames.size < 2:
        log.info("diagnose: %d fit frames before the hit frame %d: no free-flight window", frames.size, seq.hit_frame)
        return None
    fdc = dc_replace(dc, max_image_size=int(dc.free_flight_image_size))

    def evaluator(frames):
        obs_fit = measure.observe(seq, fit_views, frames, fdc, seed)
        obs_held = measure.observe(seq, held_views, frames, fdc, seed)
        ev = Evaluator(asset, ROLLOUTS.get_named(dc.rollout, "diagnose.rollout"), obs_fit, obs_held, None, score)
        ev.rebase(refit_values)
        return ev, obs_fit, obs_held

    ev, obs_fit, obs_held = evaluator(frames)
    # the base touches the recorded ground before the sequence's hit frame when the true ground is
    # lower (or the fall longer) than the model's: those frames are contact for the model, not free
    # flight, and would let gravity or drag stand in for the ground
    base_hit = first_touch(ev.positions({}), asset.ground_point, asset.ground_normal)
    if base_hit is not None and base_hit < frames[-1] + 1:
        frames = frames[frames < base_hit]
        log.info("diagnose: the base touches the ground at frame %d, before the hit frame %d", base_hit, seq.hit_frame)
        if frames.size < 2:
            log.info("diagnose: %d free-flight frames before the base's contact: no free-flight window", frames.size)
            return None
        ev, obs_fit, obs_held = evaluator(frames)
    floor = frame0_floor(measure, seq, held_views, frames.size, fdc, seed, score, ev.positions({}))
    base = {"d_fit": ev.d({}, obs_fit), "d_held_out": ev.d({}, obs_held), "floor_held_out": floor}
    record = {"frames": frames.tolist(), "hit_frame": int(seq.hit_frame), "base_hit_frame": base_hit, "base": base}
    return {"ev": ev, "base": base, "floor": floor, "record": record}


def first_touch(positions, ground_point, ground_normal) -> int | None:
    """The first frame after frame 0 in which a point of `positions` [T, N, 3] touches the ground
    (`sgdr.observe.contact.touching`); None when none does (or the rollout is unstable)."""

    if positions is None:
        return None
    frames = np.flatnonzero(touching(positions, ground_point, ground_normal)[1:]) + 1
    return int(frames[0]) if frames.size else None


def judge_in_free_flight(cand, flight, ev, refit_state, ctx, base, floor, dc) -> dict:
    """A free-flight candidate (gravity, drag) fitted on the fitting views' free-flight frames from
    the refit base, its gain the share of the base's free-flight discrepancy above that window's
    floor it removes on the held-out views; no controls refitted (the fall does not see them).
    Its future loss is its whole rollout's (the refit base with the fitted value), and so is its
    `fit_window_gain`: the held-out gain over the whole fit window, rebounds included, where weaker
    gravity (a slower rise) and drag (a faster one) part ways; recorded, not yet used to decide."""

    saved_ctx = ctx.values
    ctx.values = refit_state[2]
    try:
        fit = fit_candidate(flight["ev"], cand, ctx, dc.evaluations)
        settings, repl = cand.apply(ctx, fit.values, fit.variant)
    finally:
        ctx.values = saved_ctx
    fb = flight["base"]
    at_null = bool(fit.d_fit > fb["d_fit"]) or cand.at_null(fit.values, ctx.size)
    ev.reset(refit_state[0], refit_state[1])
    d_future = base["d_future"] if at_null else ev.d_or_none(settings, ev.obs_future, repl)
    d_time = base["d_time"] if at_null else ev.d_or_none(settings, ev.obs_time, repl)
    d_window = base["d_held_out"] if at_null else ev.d(settings, ev.obs_held, repl)
    if at_null:
        fit = replace(fit, d_fit=fb["d_fit"], d_held_out=fb["d_held_out"])
    fit = replace(fit, d_future=d_future, d_time=d_time)
    held, future = (fb["d_held_out"], flight["floor"]), (base["d_future"], floor["future"])
    margin = float(dc.floor_margin)
    window_gain = excess_gain(d_window, base["d_held_out"], floor["held_out"], margin)
    time = (base["d_time"], floor["time"])
    record = candidate_record(cand, fit, held, future, margin, None, time=time, gain_over_asset_fit=None)
    return {**record, "at_null": at_null, "from": "refit", "window": "free_flight", "fit_window_gain": window_gain,
            "applied": (settings, repl)}  # fmt: skip


def judge_truth(cand, at: tuple, flight: dict | None, ev, refit_state, ctx, base, floor, dc) -> dict:
    """A candidate judged at the injected truth `at` (values, variant; `sgdr.discrepancy.truth`) as
    its fit is: from the refit base, in the free-flight window when `flight` is given (no controls
    refitted), else on the fit window with the controls refitted beside it. Returns the values,
    the held-out loss and gain (and the gain with no controls refitted), the future gain."""
    saved = ctx.values
    ctx.values = refit_state[2]  # the candidate applied to, and the controls refitted on, the refit base
    try:
        return _judge_truth(cand, at, flight, ev, refit_state, ctx, base, floor, dc)
    finally:
        ctx.values = saved


def _judge_truth(cand, at: tuple, flight: dict | None, ev, refit_state, ctx, base, floor, dc) -> dict:
    values, variant = at
    settings, repl = cand.apply(ctx, values, variant)
    margin = float(dc.floor_margin)
    out = {"values": values, "variant": variant, "settings": {f"physics.{k}": v for k, v in settings.items()}}
    ev.reset(refit_state[0], refit_state[1])
    d_future = ev.d_or_none(settings, ev.obs_future, repl)
    d_time = ev.d_or_none(settings, ev.obs_time, repl)
    if flight is not None:
        fev, fb = flight["ev"], flight["base"]
        d_held = fev.d(settings, fev.obs_held, repl)
        out.update(
            window="free_flight",
            held_out_loss=d_held,
            gain=excess_gain(d_held, fb["d_held_out"], flight["floor"], margin),
        )
    else:
        d_alone = ev.d(settings, ev.obs_held, repl)
        d_held = d_alone
        if dc.rebase:
            joint = refit_controls(ev, ctx, dc, max(4, int(dc.evaluations) // 2), settings, repl)
            d_held, d_future, d_time = joint["d_held_out"], joint["d_future"], joint["d_time"]
            out["controls"] = {n: st["values"] for n, st in joint["steps"].items()}
        out.update(
            window="fit",
            held_out_loss=d_held,
            gain=excess_gain(d_held, base["d_held_out"], floor["held_out"], margin),
            gain_without_controls=excess_gain(d_alone, base["d_held_out"], floor["held_out"], margin),
        )
    out["time_loss"] = d_time
    out["time_gain"] = optional_gain(d_time, base["d_time"], floor["time"], margin)
    out["future_loss"] = d_future
    out["future_gain"] = optional_gain(d_future, base["d_future"], floor["future"], margin)
    return out


def optional_gain(d: float | None, d_base: float | None, floor: float | None, margin: float) -> float | None:
    """`excess_gain` on an optional observation (the held-out time, the future frames): None without it."""
    return None if d is None or d_base is None else excess_gain(d, d_base, floor, margin)


def candidate_record(
    cand, fit, held: tuple, future: tuple, margin: float, joint: dict | None, time: tuple = (None, None), **extra
) -> dict:
    """diagnosis.json's entry for a fitted candidate: its values and intervals, its losses (those of
    `fit`, already final), its gains over the base; held / time / future: (the base's D, the floor)
    on the held-out views, the held-out time and the future frames; joint: the controls refitted
    beside it (None: none)."""
    first = cand.params[0].name
    d_future = fit.d_future
    return {
        "cause": cand.cause,
        "changes": cand.describes,
        "value": fit.values[first],
        "interval": list(fit.interval[first]),
        "values": fit.values,
        "intervals": {k: list(v) for k, v in fit.interval.items()},
        "variant": fit.variant,
        "settings": {f"physics.{k}": v for k, v in fit.settings.items()},
        "fit_loss": fit.d_fit,
        "held_out_loss": fit.d_held_out,
        "gain": excess_gain(fit.d_held_out, held[0], held[1], margin),
        "relative_gain": 1.0 - fit.d_held_out / held[0],
        "time_loss": fit.d_time,
        "time_gain": optional_gain(fit.d_time, time[0], time[1], margin),
        "future_loss": d_future,
        "future_gain": optional_gain(d_future, future[0], future[1], margin),
        "evaluations": len(fit.evaluated),
        "controls": None if joint is None else {n: st["values"] for n, st in joint["steps"].items()},
        "controls_kept": None if joint is None else [n for n, st in joint["steps"].items() if st["kept"]],
        **extra,
    }


def refit_controls(ev, ctx, dc, evaluations: int, settings: dict | None = None, values: dict | None = None) -> dict:
    """The base model's own parameters (`diagnose.rebase`, `sgdr.discrepancy.candidates.CONTROLS`)
    refitted on the fitting views, one after another, each kept when it lowers the fitting D, on
    top of a candidate's physics `settings` and value replacements `values` (none: the asset's
    fit alone, the diagnosis's reference). `ev` and `ctx` are left as they were. Returns per
    control its fitted value and losses, the losses (d_fit, d_held_out, d_future) at the end, and
    `replacements`: the asset values the kept controls replace (arrays; not for diagnosis.json)."""

    saved = (dict(ev.values), dict(ev.settings), ctx.values)
    ev.rebase(values or {}, settings or {})
    ctx.values = {**ctx.values, **(values or {})}
    steps, kept, d_fit = {}, {}, ev.d({}, ev.obs_fit)
    try:
        for name in dc.rebase:
            cand = CONTROLS.get_named(name, "diagnose.rebase")
            fit = fit_candidate(ev, cand, ctx, evaluations)
            _, repl = cand.apply(ctx, fit.values, fit.variant)
            use = bool(repl) and fit.d_fit < d_fit
            steps[name] = {"values": fit.values, "fit_loss": fit.d_fit, "held_out_loss": fit.d_held_out, "kept": use}
            if use:
                ev.rebase(repl)
                ctx.values = {**ctx.values, **repl}
                kept.update(repl)
                d_fit = fit.d_fit
        out = {"steps": steps, "d_fit": ev.d({}, ev.obs_fit), "d_held_out": ev.d({}, ev.obs_held)}
        out["replacements"] = kept
        out["d_time"] = ev.d_or_none({}, ev.obs_time)
        out["d_future"] = ev.d_or_none({}, ev.obs_future)
    finally:
        ev.reset(saved[0], saved[1])
        ctx.values = saved[2]
    return out


def write_asset_copy(asset, replacements: dict, out: Path, note: tuple, settings: dict | None = None) -> Path:
    """A copy of the asset folder with `replacements` of its values and physics `settings`
    (`experiments/simulate.py` loads it like any asset); n_substeps raised to the stability bound of
    the new stiffness when needed. note: (key, entry) added to asset.json, saying where the values
    come from."""

    out = Path(out)
    if out.exists():
        shutil.rmtree(out)
    shutil.copytree(asset.root, out, ignore=shutil.ignore_patterns("DONE.json"))
    values = {**asset.values, **replacements}
    np.savez(out / "params.npz", **{k: np.asarray(v, np.float64) for k, v in values.items()})
    model, _ = asset.build()
    physics = replace(asset.physics, **(settings or {}))
    view = SimpleNamespace(log10_k=np.asarray(values["log10_k"], float), kappa=float(values["kappa"]))
    meta = json.loads((out / "asset.json").read_text())
    meta["physics"] = {**meta["physics"], **(settings or {})}
    meta["n_substeps"] = max(int(asset.n_substeps), stable_substeps(model, view, 1.0 / asset.fps, physics))
    meta[note[0]] = note[1]
    (out / "asset.json").write_text(json.dumps(meta, indent=1))
    return out


def write_refit_asset(asset, replacements: dict, out: Path, rebase: dict) -> Path:
    """The asset with the base refit's values (`write_asset_copy`); asset.json's "refit" entry
    says where they come from."""
    note = {
        "from": str(asset.root),
        "by": "experiments/diagnose.py (diagnose.rebase)",
        "values": {n: st["values"] for n, st in rebase["steps"].items() if st["kept"]},
        "second_sweep": {n: st["values"] for n, st in (rebase.get("second_sweep") or {}).items() if st["kept"]},
        "held_out_gain": rebase["held_out_gain"],
    }
    return write_asset_copy(asset, replacements, out, ("refit", note))


def write_extension(record: dict, o: Observed, named: tuple, out: Path) -> dict:
    """The named cause's extended model: the asset with it (`asset_extended/`: the candidate's
    physics settings, the values it and the controls refitted beside it replace), and the residual
    it removes: D per frame (mean over the views that observe it) of the refit base and of the
    extended model over the fit frames, the held-out time and the future, plotted in
    `extension_residual.png`. Returns diagnosis.json's "extension" entry."""
    name, (_, settings, repl), state, base_state = named
    c = record["candidates"][name]
    parts = [(o.fit_views, o.obs_fit), (o.held_views, o.obs_held), (o.views, o.obs_time), (o.views, o.obs_future)]
    n = int(o.seq.n_frames)
    o.ev.reset(state[0], state[1])
    d_ext = d_matrix(o.ev, parts, len(o.views), n, settings, repl)
    o.ev.reset(base_state[0], base_state[1])
    d_base = d_matrix(o.ev, parts, len(o.views), n)
    per_frame = {k: [None if not np.isfinite(x) else float(x) for x in _nanmean_cols(d)]
                 for k, d in (("base", d_base), ("extended", d_ext))}  # fmt: skip
    note = {
        "from": str(o.asset.root),
        "by": "experiments/diagnose.py (the named cause)",
        "candidate": name,
        "cause": c["cause"],
        "values": c["values"],
        "intervals": c["intervals"],
        "settings": c["settings"],
        "controls": c.get("controls"),
        "held_out_gain": c["gain"],
        "time_gain": c.get("time_gain"),
        "future_gain": c.get("future_gain"),
    }
    values = {**state[0], **repl}
    replaced = {k: v for k, v in values.items() if k in o.asset.values}
    asset_dir = write_asset_copy(o.asset, replaced, out / "asset_extended", ("extension", note), settings)
    plot = plot_extension(per_frame, record, name, out / "extension_residual.png")
    return {**note, "asset": str(asset_dir), "per_frame": per_frame, "plot": str(plot)}


def _nanmean_cols(d: np.ndarray) -> np.ndarray:
    """The mean over rows of [V, T], NaN where a column has no finite entry."""
    n = np.sum(np.isfinite(d), axis=0)
    return np.where(n > 0, np.nansum(d, axis=0) / np.maximum(n, 1), np.nan)


def write_residuals(ev, parts, seq, asset, dc, out: Path, unit: str) -> tuple[dict, dict]:
    """The residual diagnostics of the base rollout: residuals.json and the plots in `out`;
    returns (the strict-JSON record, {name: plot path}). unit: the measure's D unit."""

    t0 = time.time()
    pos = ev.positions({})
    d = d_matrix(ev, parts, len(seq.cameras), min(pos.shape[0], seq.n_frames))
    record, maps = residual_diagnostics(seq, asset, pos, d, int(dc.residual_grid))
    record["d"]["unit"] = unit
    record = strict_json(record)
    plots = write_plots(record, maps, out, int(dc.residual_views))
    record["seconds"] = time.time() - t0
    (out / "residuals.json").write_text(json.dumps(record, indent=1, allow_nan=False))
    log.info("diagnose: residuals in %.1f s -> %s", record["seconds"], out / "residuals.json")
    return record, {k: str(v) for k, v in plots.items()}
