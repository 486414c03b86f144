"""What the diagnosis's refits buy in the future: CD and EMD before and after (issue 15, §7).

    python -m evaluation.studies.refit_gain outputs/torus_small_s0 outputs/cream_small_s0 ...
    python -m evaluation.studies.refit_gain --objects torus,cross,cream,apple,paste,chess,banana --preset small

For each finished run with a diagnosis (`<run>/diagnose/diagnosis.json`, `make diagnose`) the
asset is rolled out over every frame three ways and scored against the sequence's ground-truth
particles on the future frames with the run's own measures (`sgdr.evaluate.geometry`: Chamfer x1e3,
EMD), so the numbers compare with the run's `future_cd` / `future_emd`:

- `asset`: the identified parameters as the run left them;
- `refit`: the base model's own parameters refitted by the diagnosis on the fitting views
  (`diagnosis.json` "rebase": a global log10 k shift, friction, restitution);
- `refit + <candidate>`: the candidate with the largest held-out gain, with the controls refitted
  with it in place (what adopting that extension would predict).

The last line printed is one JSON object (per run: the three variants' future CD and EMD); with
`--out FILE` the same object is written there.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

import sgdr.backend
from evaluation import ROOT

# Dr.Jit and the sgdr modules that import it: inside the functions, after `main` calls
# `sgdr.backend.init` (Dr.Jit reads DRJIT_LIBLLVM_PATH, which init sets, when it is first imported).


def _replacements(ctx, names_values: dict) -> dict:
    """Value replacements of the controls' fitted values, applied one after another (as the diagnosis did)."""
    from sgdr.discrepancy.candidates import CONTROLS

    out = {}
    for name, values in names_values.items():
        _, repl = CONTROLS.get_named(name, "diagnose.rebase").apply(ctx, values, None)
        out.update(repl)
        ctx.values = {**ctx.values, **repl}
    return out


def score_run(run_dir: Path, threads: int = 0) -> dict:
    """The future CD / EMD of the asset, its refit, and its refit with the best candidate."""
    from sgdr.discrepancy.candidates import CANDIDATES, Context
    from sgdr.evaluate.geometry import chamfer_distance, earth_movers_distance
    from sgdr.observe.silhouette import CentreMap
    from sgdr.physics import Ground
    from sgdr.posterior.rollouts import loop_rollout
    from sgdr.run_folder import run_asset_and_sequence

    diag_file = run_dir / "diagnose" / "diagnosis.json"
    if not diag_file.exists():
        raise SystemExit(f"error: {diag_file}: missing; run `make diagnose RUN={run_dir}` first")
    diag = json.loads(diag_file.read_text())
    if not diag.get("rebase"):
        raise SystemExit(f"error: {diag_file}: no base refit (diagnose.rebase was empty)")
    _, asset, _, seq = run_asset_and_sequence(run_dir, "", "", "diagnose")
    if seq.gt_dir is None:
        raise SystemExit(f"error: {run_dir}: its sequence has no gt/ particles to score against")
    model, _ = asset.build()
    ground = Ground(asset.ground_point, asset.ground_normal)
    centre_map = CentreMap(asset, 0)
    size = float(np.linalg.norm(np.ptp(np.asarray(asset.anchors, float), axis=0)))

    def context():
        own = bool(diag.get("v0_refit"))
        times = np.arange(1, max(int(seq.hit_frame), 1)) / float(asset.fps) if own else np.zeros(0)
        return Context(dict(asset.values), asset.physics, np.asarray(asset.anchors, float), size, times)

    def future_scores(values: dict, settings: dict) -> dict:
        cfg = replace(asset.physics, **settings)
        pos, stable = loop_rollout(
            model, {**asset.values, **values}, {"log10_k_shift": np.zeros(1)}, ground, seq.n_frames,
            1.0 / asset.fps, asset.n_substeps, cfg,
        )  # fmt: skip
        if not stable[0]:
            return {"future_cd": None, "future_emd": None, "stable": False}
        centres = centre_map(pos[0])
        frames = range(seq.n_fit, seq.n_frames)
        gts = [seq.gt_particles(f) for f in frames]
        cd = [chamfer_distance(centres[f], g) for f, g in zip(frames, gts)]
        emd = [earth_movers_distance(centres[f], g) for f, g in zip(frames, gts)]
        return {"future_cd": float(np.mean(cd)), "future_emd": float(np.mean(emd)), "stable": True}

    kept = {n: st["values"] for n, st in diag["rebase"]["steps"].items() if st["kept"]}
    # the second sweep of the controls (diagnoses since it exists), applied after the first
    second = {n: st["values"] for n, st in (diag["rebase"].get("second_sweep") or {}).items() if st["kept"]}
    out = {"run": str(run_dir), "cause": diag["cause"], "refit_values": kept}
    out["asset"] = future_scores({}, {})
    ctx = context()
    refit = {**_replacements(ctx, kept), **_replacements(ctx, second)}
    out["refit"] = future_scores(refit, {})
    cands = dict(diag["candidates"])
    if cands:
        best = max(cands, key=lambda n: cands[n]["gain"])
        c = cands[best]
        ctx = context()
        # a candidate fitted again from the refit base (diagnosis.json "from") starts from its values
        first = refit if c.get("from") == "refit" else {}
        ctx.values = {**ctx.values, **first}
        settings, repl = CANDIDATES.get_named(best, "diagnose.candidates").apply(ctx, c["values"], c["variant"])
        ctx.values = {**ctx.values, **repl}
        repl = {**first, **repl}
        # the controls the joint refit kept (a diagnosis written before `controls_kept` existed: all of them)
        # (a free-flight candidate refits none: "controls" null)
        names = c.get("controls_kept", list(c.get("controls") or {})) or []
        repl = {**repl, **_replacements(ctx, {n: c["controls"][n] for n in names})}
        out["best_candidate"] = {"name": best, "gain": c["gain"], "values": c["values"]}
        out["refit_and_candidate"] = future_scores(repl, settings)
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(
        description=__doc__.split("\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("runs", nargs="*", help="run folders with diagnose/diagnosis.json")
    p.add_argument("--objects", default="", help="instead of runs: outputs/<object>_<preset>_s0 for these objects")
    p.add_argument("--preset", default="small")
    p.add_argument("--out", default="", help="also write the JSON here")
    args = p.parse_args(argv)
    sgdr.backend.init("llvm", None)
    runs = [Path(r) for r in args.runs]
    runs += [ROOT / "outputs" / f"{o}_{args.preset}_s0" for o in args.objects.split(",") if o]
    if not runs:
        raise SystemExit("error: name run folders or --objects")
    result = {}
    for run in runs:
        r = score_run(run)
        result[run.name] = r
        line = f"{run.name}: future CD asset {r['asset']['future_cd']:.3g} -> refit {r['refit']['future_cd']:.3g}"
        if "refit_and_candidate" in r:
            line += f" -> + {r['best_candidate']['name']} {r['refit_and_candidate']['future_cd']:.3g}"
        print(line, flush=True)
    if args.out:
        Path(args.out).write_text(json.dumps(result, indent=1))
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
