"""The diagnosis's discrepancy D of a finished run at fixed physics settings: a profile.

    python -m evaluation.studies.discrepancy_profile outputs/diagnose_suite_small/cream-ground_tilt-5-s0 \\
        --set preset=small '{"ground_tilt_deg": 5, "ground_tilt_azimuth_deg": -90}'
    python -m evaluation.studies.discrepancy_profile RUN --uniform-k '{}' '{"ground_tilt_deg": 5}'
    python -m evaluation.studies.discrepancy_profile RUN --values-from RUN_REIDENTIFIED '{"ground_offset": 0.015}'
    python -m evaluation.studies.discrepancy_profile RUN --first 14 --image-size 128 '{}' '{"ground_offset": 0.015}'

Each positional argument is a JSON object of `physics.*` extension settings
(`sgdr.physics.extensions`; `{}` is the run's own model). For each, the run's asset is rolled out
with those settings and scored with the diagnosis's measure (`diagnose.discrepancy`, render by
default) on the same fitting and held-out views as `experiments/diagnose.py`, over the fit frames
from `--first` (default 1), at `--image-size` pixels (default `diagnose.max_image_size`). Printed:
D on the fitting and the held-out views, first of the run's own model as it is ("base"), then
for each setting, and the held-out gain over the base (the share of its D above the floor it
removes; the floor: frame 0's D, once per frame, as the diagnosis computes it). No refit: the
asset's identified values as they are, unless (for the settings' rows, not the base)

- `--uniform-k`: the identified log10 k field replaced by its median (does a stiffness field
  absorb the effect?), or
- `--values-from RUN2`: the identified log10 k, κ, friction and restitution of another run folder's
  dynamic stage (e.g. the same sequence reconstructed with `physics.ground_tilt_deg=5`: the
  effect with the stiffness field identified beside it).

The last line printed is one JSON object with every row. Config overrides (preset, method,
seed) as `--set key=value`, as the run was made (`config.yaml` in the run folder).
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
from omegaconf import OmegaConf

import sgdr.backend
import sgdr.config
from sgdr.discrepancy.candidates import Evaluator
from sgdr.discrepancy.decision import excess_gain
from sgdr.discrepancy.measures import MEASURES
from sgdr.discrepancy.run import frame0_floor
from sgdr.physics.config import PhysicsConfig
from sgdr.posterior.rollouts import ROLLOUTS
from sgdr.run_folder import run_asset_and_sequence


def identified_values(run_dir: Path) -> dict:
    """log10_k [N_A], kappa, friction, restitution of a run folder's completed dynamic stage."""
    dyn = Path(run_dir) / "dynamics"
    if not (dyn / "DONE.json").is_file():
        raise FileNotFoundError(f"{dyn}: no completed dynamic stage (--values-from needs one)")
    d = json.loads((dyn / "dynamics.json").read_text())
    with np.load(dyn / "params.npz", allow_pickle=False) as z:
        k = np.asarray(z["log10_k"], float)
    return {
        "log10_k": k,
        "kappa": float(d["kappa"]),
        "friction": float(d["friction"]),
        "restitution": float(d["restitution"]),
    }


def profile(cfg, settings: list[dict], first: int = 1, image_size: int = 0, uniform_k: bool = False, values_from=None):
    """Rows {settings, d_fit, d_held_out, gain} for each entry of `settings` (module docstring)."""
    dc = cfg.diagnose
    if image_size:
        dc = replace(dc, max_image_size=int(image_size))
    known = set(PhysicsConfig.__dataclass_fields__)
    for s in settings:
        bad = sorted(set(s) - known)
        if bad:
            raise ValueError(f"settings {s}: {', '.join(bad)} are not physics.* settings")
    _, asset, _, seq = run_asset_and_sequence(Path(dc.run), dc.sequence, cfg.scene_file, "diagnose")
    if not 1 <= int(first) < int(seq.n_fit):
        raise ValueError(f"--first {first}: the fit frames are 1 .. {seq.n_fit - 1}")
    views = list(range(len(seq.cameras)))
    fit_views, held_views = views[0::2], views[1::2]
    frames = np.arange(int(first), seq.n_fit, int(dc.frame_stride))
    measure = MEASURES.get_named(dc.discrepancy, "diagnose.discrepancy")
    obs_fit = measure.observe(seq, fit_views, frames, dc, cfg.seed)
    obs_held = measure.observe(seq, held_views, frames, dc, cfg.seed)
    score = measure.scorer(asset, dc, cfg.render, cfg.seed)
    ev = Evaluator(asset, ROLLOUTS.get_named(dc.rollout, "diagnose.rollout"), obs_fit, obs_held, None, score)
    floor = frame0_floor(measure, seq, held_views, frames.size, dc, cfg.seed, score, ev.positions({}))
    repl = dict(values_from or {})
    n_anchors = np.asarray(asset.values["log10_k"]).shape
    if "log10_k" in repl and np.asarray(repl["log10_k"]).shape != n_anchors:
        raise ValueError(
            f"--values-from: log10_k has shape {np.asarray(repl['log10_k']).shape}, the asset's {n_anchors}"
        )
    if uniform_k:
        k = np.asarray(repl.get("log10_k", asset.values["log10_k"]), float)
        repl["log10_k"] = np.full_like(k, float(np.median(k)))
    base = {"settings": "base", "d_fit": ev.d({}, obs_fit), "d_held_out": ev.d({}, obs_held), "gain": 0.0}
    rows = [base]
    for s in settings:
        row = {"settings": s, "d_fit": ev.d(s, obs_fit, repl), "d_held_out": ev.d(s, obs_held, repl)}
        row["gain"] = excess_gain(row["d_held_out"], base["d_held_out"], floor, float(dc.floor_margin))
        rows.append(row)
    return {"frames": frames.tolist(), "image_size": int(dc.max_image_size), "floor_held_out": floor, "rows": rows}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(
        description=__doc__.split("\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("run", help="a finished run folder")
    p.add_argument(
        "settings", nargs="+", help="JSON objects of physics.* settings, e.g. '{}' '{\"ground_offset\": 0.01}'"
    )
    p.add_argument("--first", type=int, default=1, help="the first fit frame scored (default 1)")
    p.add_argument("--image-size", type=int, default=0, help="compare at this many pixels (0: diagnose.max_image_size)")
    p.add_argument("--uniform-k", action="store_true", help="the identified log10 k field replaced by its median")
    p.add_argument("--values-from", default="", help="another run folder whose identified dynamics replace the asset's")
    p.add_argument("--set", action="append", default=[], help="a config override (key=value), e.g. preset=small")
    args = p.parse_args(argv)
    try:
        settings = [json.loads(s) for s in args.settings]
    except json.JSONDecodeError as e:
        print(f"error: a settings argument is not JSON: {e}", file=sys.stderr)
        return 2
    if not all(isinstance(s, dict) for s in settings):
        print("error: each settings argument must be a JSON object, e.g. '{\"ground_offset\": 0.01}'", file=sys.stderr)
        return 2
    sgdr.config.register()
    cfg = OmegaConf.to_object(sgdr.config.compose([*args.set, f"diagnose.run={args.run}"]))
    sgdr.backend.init(cfg.backend, cfg.threads or None)
    try:
        values = identified_values(Path(args.values_from)) if args.values_from else None
        out = profile(cfg, settings, args.first, args.image_size, args.uniform_k, values)
    except (FileNotFoundError, ValueError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    print(
        f"frames {out['frames'][0]}-{out['frames'][-1]} at {out['image_size']} px; held-out floor {out['floor_held_out']:.4g}"
    )
    for r in out["rows"]:
        print(
            f"{r['settings'] if r['settings'] == 'base' else json.dumps(r['settings']):60s} fit D {r['d_fit']:10.4g}  held-out D {r['d_held_out']:10.4g}  gain {r['gain']:+.3f}"
        )
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
