"""`run_diagnosis(cfg)`: which extension a finished run's sequence asks for (docs/discrepancy.md).

1. The run's asset (its identified physics) and the observed sequence (the run's own, or
   `diagnose.sequence`, e.g. a twin with an injected effect).
2. Silhouette observations (`sgdr.posterior.likelihood.observation`): the fit frames after
   frame 0 in the fitting views (even positions among the views) and in the held-out views (odd
   positions), and the future frames in all views when the sequence has future frames.
3. The base model's D on each, then every candidate (`sgdr.discrepancy.candidates`) fitted on
   the fitting views and judged on the held-out ones.
4. The decision: the candidate with the largest held-out gain is the cause if that gain is at
   least `diagnose.min_gain`, else "none"; gain = 1 - D_held_out(candidate) / D_held_out(base).
5. The residual diagnostics of the base fit (`sgdr.discrepancy.residuals`, when
   `diagnose.residuals`): `residuals.json` and residual_*.png beside diagnosis.json, the headline
   numbers in diagnosis.json "residuals".

Writes `diagnosis.json` (strict JSON) and returns it, and adds the 'Model discrepancy' section
to `<run>/report/report.html` when that page exists.
"""

from __future__ import annotations

import json
import logging
import time
from pathlib import Path

import numpy as np

log = logging.getLogger(__name__)


def run_diagnosis(cfg) -> dict:
    from sgdr.discrepancy.candidates import CANDIDATES, Evaluator, fit_candidate
    from sgdr.discrepancy.residuals import summary
    from sgdr.posterior.likelihood import CentreMap, observation
    from sgdr.posterior.rollouts import ROLLOUTS
    from sgdr.posterior.run import run_asset_and_sequence, strict_values

    dc = cfg.diagnose
    t0 = time.time()
    run_dir = Path(dc.run)
    asset_dir, asset, seq_dir, seq = run_asset_and_sequence(run_dir, dc.sequence, cfg.scene_file, "diagnose")
    if len(seq.cameras) < 2:
        raise ValueError(f"{seq_dir}: one view; the diagnosis needs held-out views (at least 2)")
    views = list(range(len(seq.cameras)))
    fit_views, held_views = views[0::2], views[1::2]
    fit_frames = np.arange(1, seq.n_fit, int(dc.frame_stride))
    if fit_frames.size == 0:
        raise ValueError(f"{seq_dir}: no fit frame after frame 0")
    obs_fit = observation(seq, fit_views, fit_frames, dc.n_mask_points, seed=cfg.seed)
    obs_held = observation(seq, held_views, fit_frames, dc.n_mask_points, seed=cfg.seed)
    future = np.arange(seq.n_fit, seq.n_frames)
    obs_future = observation(seq, views, future, dc.n_mask_points, seed=cfg.seed) if future.size else None
    ev = Evaluator(
        asset, ROLLOUTS.get_named("loop"), obs_fit, obs_held, obs_future, CentreMap(asset, dc.n_points, cfg.seed)
    )
    size = float(np.linalg.norm(np.ptp(np.asarray(asset.anchors, float), axis=0)))
    base = {"d_fit": ev.d({}, obs_fit), "d_held_out": ev.d({}, obs_held)}
    base["d_future"] = ev.d({}, obs_future) if obs_future is not None else None
    if not np.isfinite(base["d_held_out"]):
        raise RuntimeError(f"{asset_dir}: the identified parameters' rollout is unstable")
    candidates = {}
    for name in dc.candidates:
        cand = CANDIDATES.get_named(name, "diagnose.candidates")
        fit = fit_candidate(ev, cand, size, dc.evaluations)
        gain = 1.0 - fit.d_held_out / base["d_held_out"]
        future_gain = 1.0 - fit.d_future / base["d_future"] if fit.d_future is not None and base["d_future"] else None
        candidates[name] = {
            "cause": cand.cause,
            "setting": f"physics.{cand.setting}",
            "value": fit.value,
            "interval": list(fit.interval),
            "fit_loss": fit.d_fit,
            "held_out_loss": fit.d_held_out,
            "gain": gain,
            "future_loss": fit.d_future,
            "future_gain": future_gain,
            "evaluations": len(fit.evaluated),
        }
        log.info("diagnose: %s = %.4g, held-out gain %.3f", name, fit.value, gain)
    best = max(candidates, key=lambda n: candidates[n]["gain"]) if candidates else None
    named = best is not None and candidates[best]["gain"] >= float(dc.min_gain)
    for name, c in candidates.items():
        c["decision"] = "cause" if named and name == best else "rejected"
    record = {
        "cause": candidates[best]["cause"] if named else "none",
        "candidates": candidates,
        "base": base,
        "min_gain": float(dc.min_gain),
        "fitting_views": [seq.cameras[v].name for v in fit_views],
        "held_out_views": [seq.cameras[v].name for v in held_views],
        "frames": fit_frames.tolist(),
        "future_frames": future.tolist(),
        "sequence": str(seq_dir),
        "run": str(run_dir),
        "truth": seq.gt_effects() or {},
        "seconds": time.time() - t0,
    }
    out = Path(dc.out_dir) if dc.out_dir else run_dir / "diagnose"
    out.mkdir(parents=True, exist_ok=True)
    residuals, plots = None, None
    if dc.residuals:
        parts = [(fit_views, obs_fit), (held_views, obs_held), (views, obs_future)]
        residuals, plots = write_residuals(ev, parts, seq, asset, dc, out)
        record["residuals"] = summary(residuals)
    record["seconds"] = time.time() - t0
    record = strict_values(record)
    (out / "diagnosis.json").write_text(json.dumps(record, indent=1, allow_nan=False))
    record["file"] = str(out / "diagnosis.json")
    report = run_dir / "report" / "report.html"
    if report.exists():
        from sgdr.discrepancy.report import section
        from sgdr.pipeline.report_html import add_section

        add_section(report, section(record, residuals, plots))
        record["report"] = str(report)
    else:
        log.info("diagnose: %s missing, no report section added", report)
    return record


def write_residuals(ev, parts, seq, asset, dc, out: Path) -> tuple[dict, dict]:
    """The residual diagnostics of the base rollout: residuals.json and the plots in `out`;
    returns (the strict-JSON record, {name: plot path})."""
    from sgdr.discrepancy.report import write_plots
    from sgdr.discrepancy.residuals import d_matrix, residual_diagnostics
    from sgdr.posterior.run import strict_values

    t0 = time.time()
    pos = ev.positions({})
    d = d_matrix(ev, parts, len(seq.cameras), min(pos.shape[0], seq.n_frames))
    record, maps = residual_diagnostics(seq, asset, pos, d, int(dc.residual_grid))
    record = strict_values(record)
    plots = write_plots(record, maps, out, int(dc.residual_views))
    record["seconds"] = time.time() - t0
    (out / "residuals.json").write_text(json.dumps(record, indent=1, allow_nan=False))
    log.info("diagnose: residuals in %.1f s -> %s", record["seconds"], out / "residuals.json")
    return record, {k: str(v) for k, v in plots.items()}
