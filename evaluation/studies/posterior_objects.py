"""The posterior on the seven MPM benchmark objects: predictive coverage and future CD (issue 14, §5).

    python -m evaluation.studies.posterior_objects                       # the preset's runs outputs/<object>_small_s0
    python -m evaluation.studies.posterior_objects --objects torus,cream --set posterior.n_steps=80
    python -m evaluation.studies.posterior_objects --summary             # the table, from the results file
    python -m evaluation.studies.posterior_objects --jobs 2 --threads 1  # two objects at a time
    python -m evaluation.studies.posterior_objects --summary --results results/posterior_objects_small_s1.jsonl \
        --pool results/posterior_objects_small_runs1206.jsonl    # γ left one object out over two draws

For each object's finished reconstruction (`outputs/<object>_<preset>_s0`, as `make reproduce` or
`make demo` leaves it) `experiments/posterior.py` computes the posterior of the run's physics on
the run's own MPM sequence, and one JSON line per object is appended to
`results/posterior_objects_<preset>.jsonl` (committed): whether it converged, the intervals, the
share of future frames whose true centre-of-mass height lies in the 5-95% predictive band (as a
height, and as a displacement from frame 0), and the future Chamfer distance of the posterior
median, of the point estimate and of the last fit frame held still (the run's physics-free
baseline), all three scored the same way (the Gaussian centres against the true particles, x1e3). A rerun skips objects already in the
file (`--rerun` runs them again; later lines supersede earlier ones). The data are generated
by the MPM, not by the spring-mass model: the truth is outside the model class, so these numbers
measure how the posterior behaves under misspecification, not its calibration (twins do that:
evaluation/studies/calibrate_posterior.py).

The summary also calibrates the forecast's model discrepancy (`posterior.discrepancy_growth`,
sgdr/posterior/forecast.py) leave-one-object-out: γ from every other object's future frames, the
held-out object's share of future frames whose true centre of mass lies in the 90% ball with it;
and γ from all of them, the default for data the calibration has not seen. `--pool FILE` adds
another draw of runs (e.g. the objects reconstructed at another seed) to the calibration; an
object is then left out with all its runs. `--offsets` scores every ball as
`posterior.discrepancy_offset=true` makes it (records written without it get their offsets
rendered from their run folders, about 10 s each); the two kinds are never calibrated together.
`--ensemble` scores each object's runs over all the draws as one ensemble (`posterior.ensemble`:
the mixture of their predictives, at `posterior.ensemble_growth`), `--ensemble-size k` every
combination of k of them, with γ calibrated leave-one-object-out on the ensembles too; nothing runs.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from evaluation import ROOT
from evaluation.studies.diagnose_suite import read_results as read_jsonl

OBJECTS = ("torus", "cross", "cream", "apple", "paste", "chess", "banana")


def read_results(path: Path) -> dict:
    """The last record per object (later lines supersede earlier ones)."""
    return read_jsonl(path, key="object")


def record_of(obj: str, run_dir: Path, post: dict, seconds: float, commit: str) -> dict:
    """The results line of one object from its posterior.json (and the run's metrics.json)."""
    d, pred = post["diagnostics"], post["predictive"]
    metrics_file = run_dir / "metrics.json"
    metrics = json.loads(metrics_file.read_text()) if metrics_file.exists() else {}
    return {
        "object": obj,
        "run": str(run_dir),
        "commit": commit,
        "converged": post["converged"],
        "failed": post["failed"],
        "tau_max": d.get("tau_max"),
        "rhat": d.get("rhat"),
        "ess_bulk": d.get("ess_bulk"),
        "acceptance": d.get("acceptance"),
        "map": post["map"],
        "median": d["median"],
        "q05": d["q05"],
        "q95": d["q95"],
        "likelihood": post["likelihood"].get("kind"),
        "sigma_px": post["likelihood"].get("sigma_px"),
        "profile_log10_k_shift": post["likelihood"].get("profile_log10_k_shift"),
        "surrogate": (post.get("sampler") or {}).get("surrogate"),
        "ball": _ball_case(pred.get("com_ball")),
        "ball_inside_future": (pred.get("com_ball") or {}).get("truth_inside_future"),
        "com_inside_fit": pred.get("com_height_truth_inside_fit"),
        "com_inside_future": pred.get("com_height_truth_inside_future"),
        "com_disp_inside_fit": pred.get("com_height_disp_truth_inside_fit"),
        "com_disp_inside_future": pred.get("com_height_disp_truth_inside_future"),
        "lowest_disp_inside_future": pred.get("lowest_height_disp_truth_inside_future"),
        "median_future_cd": pred.get("median_future_cd"),
        "map_future_cd": pred.get("map_future_cd"),
        # posterior.json written before the "still" of the last fit frame existed held the rest state:
        # the run's own still baseline is the same quantity (the point estimate's last fit frame)
        "still_future_cd": (
            pred.get("still_future_cd")
            if "still_cd_per_future_frame" in pred
            else (metrics.get("baseline_future_cd_by_variant") or {}).get("still")
        ),
        "run_future_cd": metrics.get("future_cd"),  # the run's own score (rendered Gaussians' centres, its evaluator)
        "run_still_future_cd": metrics.get("baseline_future_cd"),
        "rollouts": post["cost"]["rollouts"],
        "seconds": seconds,
    }


def _ball_case(ball: dict | None) -> dict | None:
    """What the leave-one-object-out calibration needs of the predictive ball (forecast.coverage)."""
    if not ball or not ball.get("truth"):
        return None
    case = {k: ball[k] for k in ("sigma_fit", "fps", "size", "draws", "centre", "truth", "growth", "level")}
    if ball.get("offset") is not None:  # posterior.discrepancy_offset: the draws already moved by it
        case["offset"] = ball["offset"]
    return case


def _run_dir(record: dict) -> Path:
    """The record's run folder (relative paths are the repository's)."""
    run = Path(record["run"])
    return run if run.is_absolute() else ROOT / run


def offset_case(record: dict, cfg) -> dict | None:
    """The record's ball case as posterior.discrepancy_offset would have made it: the offsets of
    its run's point prediction rendered again (`sgdr.posterior.run.point_offsets`, the run folder
    and its sequence must be on disk), the draws moved by them, σ_fit their scatter. A case that
    has them already is returned as it is."""
    import numpy as np

    from sgdr.posterior.forecast import with_offsets
    from sgdr.posterior.run import point_offsets
    from sgdr.run_folder import run_asset_and_sequence

    case = record.get("ball")
    if not case or case.get("offset") is not None:
        return case
    _, asset, _, seq = run_asset_and_sequence(_run_dir(record), "", cfg.scene_file, "posterior")
    offsets = point_offsets(cfg, asset, seq)
    draws = np.asarray(case["draws"], float)
    moved, sigma_fit, end = with_offsets(draws, offsets)
    centre = np.asarray(case["centre"], float) + (moved - draws)[0]
    return {**case, "draws": moved.tolist(), "centre": centre.tolist(), "sigma_fit": sigma_fit.tolist(),
            "offset": end.tolist()}  # fmt: skip


def leave_one_out(results: dict, level: float = 0.9, pool: tuple = ()) -> dict:
    """γ (posterior.discrepancy_growth) calibrated on every object but one and the held-out
    object's future coverage of the ball with it; and γ on all of them (the default for new data).
    Only objects whose record holds the ball's case take part. `pool`: the records of further
    draws of runs (dicts object -> record, e.g. the same objects reconstructed at another seed):
    their cases join the calibration, and an object is left out with every draw's run of it."""
    from sgdr.posterior.forecast import calibrate_growth, coverage

    cases = [(o, r["ball"]) for o, r in results.items() if r.get("ball")]
    every = cases + [(o, r["ball"]) for draw in pool for o, r in draw.items() if r.get("ball")]
    kinds = {c.get("offset") is not None for _, c in every}
    if len(kinds) > 1:
        raise ValueError(
            "the runs' balls mix posterior.discrepancy_offset=true and false; calibrate one kind "
            "(--offsets computes the offsets of the others from their run folders)"
        )
    out = {
        "objects": {},
        "calibration_runs": len(every),
        "growth_all": calibrate_growth([c for _, c in every], level) if every else None,
    }
    for obj, case in cases:
        others = [c for o, c in every if o != obj]
        if not others:
            continue
        growth = calibrate_growth(others, level)
        out["objects"][obj] = {"growth": growth, "inside_future": coverage(case, growth, level)}
    vals = [v["inside_future"] for v in out["objects"].values()]
    out["mean_inside_future"] = sum(vals) / len(vals) if vals else None
    out["min_inside_future"] = min(vals) if vals else None
    return out


def ensembles(results: dict, pool: tuple = (), size: int = 0) -> dict:
    """object -> [ensemble cases ({members: [ball cases]}, `forecast.ensemble_ball`)]: the object's
    runs over every draw (`results` and `pool`) as one ensemble, or (size > 0) every combination of
    `size` of them."""
    from itertools import combinations

    runs: dict = {}
    for draw in (results, *pool):
        for obj, r in draw.items():
            if r.get("ball"):
                runs.setdefault(obj, []).append(r["ball"])
    out = {}
    for obj, balls in runs.items():
        groups = [balls] if size <= 0 else [list(g) for g in combinations(balls, size)]
        if groups:  # an object with fewer runs than `size` has none
            out[obj] = [{"members": g} for g in groups]
    return out


def ensemble_summary(results: dict, pool: tuple = (), growth: float = 0.0, size: int = 0, level: float = 0.9) -> dict:
    """The ensembles of runs (`ensembles`): each object's share of future frames inside the ball
    at `growth` (mean and min over its ensembles), and γ calibrated leave-one-object-out on the
    other objects' ensembles with the held-out object's share at it; γ on all of them."""
    from sgdr.posterior.forecast import calibrate_growth, coverage

    ens = ensembles(results, pool, size)
    every = [e for groups in ens.values() for e in groups]
    if not every:
        raise ValueError(f"--ensemble-size {size}: no object has that many runs over the draws (results and --pool)")
    out = {"size": size, "growth": growth, "objects": {},
           "growth_all": calibrate_growth(every, level) if every else None}  # fmt: skip
    for obj, groups in ens.items():
        at = [coverage(e, growth, level) for e in groups]
        others = [e for o, g in ens.items() if o != obj for e in g]
        loo = calibrate_growth(others, level) if others else None
        held = [coverage(e, loo, level) for e in groups] if others else []
        out["objects"][obj] = {
            "ensembles": len(groups),
            "runs": len(groups[0]["members"]),
            "inside_future_mean": sum(at) / len(at),
            "inside_future_min": min(at),
            "loo_growth": loo,
            "loo_inside_future_mean": sum(held) / len(held) if held else None,
        }
    for key in ("inside_future_mean", "loo_inside_future_mean"):
        vals = [v[key] for v in out["objects"].values() if v[key] is not None]
        out[f"{key}_over_objects"] = sum(vals) / len(vals) if vals else None
        out[f"{key}_lowest_object"] = min(vals) if vals else None
    return out


def ensemble_markdown(s: dict) -> str:
    lines = [
        f"| object | runs per ensemble | ensembles | inside the 90% ball, future, at γ {s['growth']:g}: mean [min] "
        "| γ left one object out | inside at it |",
        "|---|---|---|---|---|---|",
    ]
    for obj, v in s["objects"].items():
        lines.append(
            f"| {obj} | {v['runs']} | {v['ensembles']} | {v['inside_future_mean']:.0%} [{v['inside_future_min']:.0%}] "
            f"| {_fmt(v['loo_growth'])} | {_fmt(v['loo_inside_future_mean'], '.0%')} |"
        )
    return "\n".join(lines)


def _fmt(x, spec=".3g"):
    return "-" if x is None else format(x, spec)


def markdown(results: dict, loo: dict) -> str:
    """The table of `results`, with `loo` = leave_one_out(...)["objects"]."""
    lines = [
        "| object | converged | log10 k shift 5-95% | com in band, future (height / displacement) "
        "| com in the 90% ball, future (leave-one-out γ) | future CD: posterior median / point estimate / still "
        "| minutes |",
        "|---|---|---|---|---|---|---|",
    ]
    for obj, r in results.items():
        shift = "-"
        if "log10_k_shift" in r["median"]:
            shift = f"{r['median']['log10_k_shift']:+.2f} [{r['q05']['log10_k_shift']:+.2f}, {r['q95']['log10_k_shift']:+.2f}]"
        cover = f"{_fmt(r['com_inside_future'], '.0%')} / {_fmt(r['com_disp_inside_future'], '.0%')}"
        cds = f"{_fmt(r['median_future_cd'])} / {_fmt(r['map_future_cd'])} / {_fmt(r['still_future_cd'])}"
        ball = f"{loo[obj]['inside_future']:.0%} (γ {loo[obj]['growth']:.3g})" if obj in loo else "-"
        lines.append(
            f"| {obj} | {'yes' if r['converged'] else 'no'} | {shift} | {cover} | {ball} | {cds} "
            f"| {r['seconds'] / 60:.1f} |"
        )
    return "\n".join(lines)


def summary(results: dict, pool: tuple = ()) -> dict:
    rows = list(results.values())

    def mean(key):
        vals = [r[key] for r in rows if r.get(key) is not None]
        return sum(vals) / len(vals) if vals else None

    return {
        "objects": len(rows),
        "converged": sum(bool(r["converged"]) for r in rows),
        "leave_one_out": leave_one_out(results, pool=pool),
        "ball_inside_future_mean": mean("ball_inside_future"),
        "com_inside_future_mean": mean("com_inside_future"),
        "com_disp_inside_future_mean": mean("com_disp_inside_future"),
        "median_future_cd_mean": mean("median_future_cd"),
        "map_future_cd_mean": mean("map_future_cd"),
        "still_future_cd_mean": mean("still_future_cd"),
        "median_beats_map": sum(
            r["median_future_cd"] < r["map_future_cd"]
            for r in rows
            if r.get("median_future_cd") and r.get("map_future_cd")
        ),
        "median_beats_still": sum(
            r["median_future_cd"] < r["still_future_cd"]
            for r in rows
            if r.get("median_future_cd") and r.get("still_future_cd")
        ),
    }


def report(results: dict, pool: tuple = ()) -> None:
    """Print the table and the summary (one leave-one-out calibration for both)."""
    s = summary(results, pool)
    print(markdown(results, s["leave_one_out"]["objects"]))
    print(json.dumps(s))


def _commit() -> str:
    proc = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True)
    return proc.stdout.strip() or "unknown"


def _offset_cases(args, results: dict, pool: tuple) -> tuple[dict, tuple]:
    """`results` and `pool` with every ball case as `offset_case` makes it."""
    from omegaconf import OmegaConf

    import sgdr.backend
    from sgdr.config import compose

    cfg = OmegaConf.to_object(compose([f"preset={args.preset}", *args.set]))
    sgdr.backend.init(cfg.backend, args.threads or None)
    records = [r for draw in (results, *pool) for r in draw.values() if r.get("ball")]
    missing = [r["run"] for r in records if not r["ball"].get("offset") and not (_run_dir(r) / "asset").is_dir()]
    if missing:  # before any rendering
        raise SystemExit("error: --offsets needs the run folders: no asset/ in " + ", ".join(missing))
    done = [{o: {**r, "ball": offset_case(r, cfg)} if r.get("ball") else r for o, r in draw.items()}
            for draw in (results, *pool)]  # fmt: skip
    return done[0], tuple(done[1:])


def main(argv=None) -> int:
    p = argparse.ArgumentParser(
        description=__doc__.split("\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--preset", default="small")
    p.add_argument("--objects", default=",".join(OBJECTS))
    p.add_argument("--runs", default="outputs/{object}_{preset}_s0", help="run folder pattern ({object}, {preset})")
    p.add_argument("--results", default="", help="default results/posterior_objects_<preset>.jsonl")
    p.add_argument("--threads", type=int, default=0)
    p.add_argument("--jobs", type=int, default=1, help="objects run at once (each with --threads)")
    p.add_argument("--set", action="append", default=[], help="a config override for every posterior (key=value)")
    p.add_argument("--rerun", action="store_true", help="run objects already in the results file again")
    p.add_argument("--summary", action="store_true", help="print the table and the summary, run nothing")
    p.add_argument(
        "--pool",
        action="append",
        default=[],
        help="another draw's results file whose runs join the discrepancy's calibration (leave one object out)",
    )
    p.add_argument(
        "--offsets",
        action="store_true",
        help="score the balls as posterior.discrepancy_offset=true would (the offsets rendered from each run folder)",
    )
    p.add_argument(
        "--ensemble",
        action="store_true",
        help="score each object's runs over the draws (the results file and --pool) as one ensemble (posterior.ensemble)",
    )
    p.add_argument("--ensemble-size", type=int, default=0, help="with --ensemble: every combination of this many runs")
    args = p.parse_args(argv)
    results_path = Path(args.results or ROOT / "results" / f"posterior_objects_{args.preset}.jsonl")
    results = read_results(results_path)
    missing_pool = [f for f in args.pool if not Path(f).is_file()]
    if missing_pool:
        raise SystemExit(f"error: --pool: no results file {', '.join(missing_pool)}")
    pool = tuple(read_results(Path(f)) for f in args.pool)
    if args.offsets:
        results, pool = _offset_cases(args, results, pool)
    if args.ensemble:
        from omegaconf import OmegaConf

        from sgdr.config import compose

        growth = OmegaConf.to_object(compose([f"preset={args.preset}", *args.set])).posterior.ensemble_growth
        try:
            s = ensemble_summary(results, pool, growth, args.ensemble_size)
        except ValueError as err:
            raise SystemExit(f"error: {err}") from None
        print(ensemble_markdown(s))
        print(json.dumps(s))
        return 0
    if args.summary:
        report(results, pool)
        return 0
    objects = [o for o in args.objects.split(",") if o]
    runs = {o: Path(args.runs.format(object=o, preset=args.preset)) for o in objects}
    missing = [f"{o}: {r}" for o, r in runs.items() if not (r / "asset").is_dir()]
    if missing:  # before any minutes of work
        raise SystemExit(
            "error: no finished run (asset/) for " + "; ".join(missing) + " (make reproduce, or --runs PATTERN)"
        )
    todo = [o for o in objects if args.rerun or o not in results]
    print(f"{len(todo)} of {len(objects)} objects to run; results append to {results_path}", flush=True)
    results_path.parent.mkdir(parents=True, exist_ok=True)

    def one(obj: str) -> None:
        run_dir = runs[obj]
        cmd = [sys.executable, "experiments/posterior.py", f"preset={args.preset}", f"posterior.run={run_dir}"]
        cmd += [f"threads={args.threads}", "tracking.enabled=false", *args.set]
        t0 = time.time()
        log_file = run_dir / "posterior.log"
        with log_file.open("w") as log:
            proc = subprocess.run(cmd, cwd=ROOT, stdout=log, stderr=subprocess.STDOUT, text=True)
        if proc.returncode != 0:
            tail = log_file.read_text().strip().splitlines()[-2:]
            print(f"{obj}: posterior failed ({log_file}): {' / '.join(tail)}", flush=True)
            return
        post = json.loads((run_dir / "posterior" / "posterior.json").read_text())
        rec = record_of(obj, run_dir, post, time.time() - t0, _commit())
        with lock, results_path.open("a") as f:
            f.write(json.dumps(rec) + "\n")
        print(f"{obj}: {post['headline'][:100]} ({rec['seconds'] / 60:.1f} min)", flush=True)

    lock = threading.Lock()
    with ThreadPoolExecutor(max(1, args.jobs)) as executor:
        list(executor.map(one, todo))
    report(read_results(results_path), pool)
    return 0


if __name__ == "__main__":
    sys.exit(main())
