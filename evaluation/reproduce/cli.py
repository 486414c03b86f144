"""The paper's Tables 1-3 from sgdr's runs: `python -m evaluation.reproduce` (= `make reproduce`).

    python -m evaluation.reproduce                              # every cell at small, 2 jobs, then the tables
    python -m evaluation.reproduce --preset tiny                # the same at CI scale (results/tiny/)
    python -m evaluation.reproduce --tables-only                # only write the tables from the runs present
    python -m evaluation.reproduce --launcher submitit_slurm hydra.launcher.partition=gpu backend=cuda
    python -m evaluation.reproduce --methods spring_gaus,no_soft_vector --objects torus_hetero recon.iterations=2

What it does, in order:
1. The cells: every (method, object) pair a table needs (`TABLES`, the paper's layout). A cell is
   one run folder `<output_dir>/<object>_<preset>[_<method>]_s<seed>` (`run_dir_name`, the rule of
   `sgdr.run_folder.default_run_name`). A cell whose `metrics.json` exists is finished and
   skipped (`--rerun` sends it through the pipeline again, which verifies its stages and redoes
   only what changed); a method without `conf/method/<method>.yaml` in this checkout is not run
   and its cells say so.
2. The sequences the cells need, generated one after another (`experiments/generate.py -m`,
   complete ones skipped), so that parallel jobs never generate the same sequence twice.
3. The unfinished cells through Hydra multiruns of `experiments/reconstruct.py -m` (one multirun
   per set of objects that need the same methods: the seven objects' methods, then the ablation
   methods on `torus_hetero`), with the launcher of `--launcher` (`hydra/launcher=...`): `joblib`
   locally (`--jobs` processes, each with `threads = cores // jobs` Dr.Jit threads), `submitit_local`
   (batches of `--jobs`), `submitit_slurm` or sgdr's `slurm` (conf/hydra/launcher/slurm.yaml) on a
   cluster, `basic` (one after another). The multirun's own output goes to a log file beside
   Hydra's `multirun.yaml`; this module prints one progress line per finished cell.
4. The tables (`write_tables`): `<results>/tables.md`, `table{1,2,3}.csv`, `tables.json` (commit,
   machine, date, command; per cell its value, run folder and the run's own commit) and
   `tables.html` (one self-contained page), with the paper's numbers beside ours, the PAC-NeRF /
   Spring-Gaus ratio of mean future CD and which method has the lowest CD in Table 3, as measured.

A missing run is a visible "missing" cell with its reason, never a number; a score a method does
not have (null in its metrics.json, e.g. a fit-only method's future) shows the run's reason.
Units: our CD is the mean squared nearest-neighbour distance in scene units² x1e3 (the benchmark
lives in a unit cube, `sgdr.evaluate.geometry`); the paper's is in 1e3 mm² of its own scenes. Our
EMD is in scene units. The columns are comparable in direction, not in value.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Sequence
from pathlib import Path

from evaluation.reproduce.cells import collect
from evaluation.reproduce.formats import write_tables
from evaluation.reproduce.launch import LAUNCHERS, reproduce
from evaluation.reproduce.provenance import tables_record


def parse_args(argv: Sequence[str]):
    p = argparse.ArgumentParser(
        prog="python -m evaluation.reproduce", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--preset", default="small")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--launcher", default="joblib", choices=LAUNCHERS, help="hydra/launcher of the multiruns")
    p.add_argument("--jobs", type=int, default=2, help="runs at once (joblib n_jobs; submitit_local batch size)")
    p.add_argument("--threads", type=int, default=0, help="Dr.Jit threads per run (0: cores // jobs; slurm: the job's)")
    p.add_argument("--output-dir", default="outputs", help="recon.output_dir: where the run folders are")
    p.add_argument("--data-dir", default=None, help="data_dir (default: data at small, data/<preset> otherwise)")
    p.add_argument("--results", default=None, help="where the tables go (default: results at small, results/<preset>)")
    p.add_argument("--methods", type=lambda s: s.split(","), default=None, help="run only these methods (a,b)")
    p.add_argument("--objects", type=lambda s: s.split(","), default=None, help="run only these objects (a,b)")
    p.add_argument("--rerun", action="store_true", help="send finished cells through the pipeline again too")
    p.add_argument("--tables-only", action="store_true", help="run nothing: write the tables from the runs present")
    p.add_argument("overrides", nargs="*", help="Hydra overrides for every run, e.g. recon.iterations=2")
    args = p.parse_args(argv)
    for o in args.overrides:
        if "=" not in o:
            p.error(f"{o!r} is not a Hydra override (key=value)")
    args.data_dir = args.data_dir or ("data" if args.preset == "small" else f"data/{args.preset}")
    args.results = args.results or ("results" if args.preset == "small" else f"results/{args.preset}")
    return args


def main(argv: Sequence[str]) -> int:
    args = parse_args(argv)
    t0 = time.time()
    commands, ok = ([], True) if args.tables_only else reproduce(args, list(args.overrides))
    meta = tables_record(argv, args, commands, (time.time() - t0) / 60.0)
    res = collect(Path(args.output_dir), args.preset, args.seed, meta=meta)
    paths = write_tables(res, Path(args.results))
    n_ok = sum(r.metrics is not None for r in res.runs.values())
    print(f"[reproduce] {n_ok}/{len(res.runs)} cells have a run; {meta['minutes']:.1f} min", flush=True)
    print(f"[reproduce] {res.ratio['sentence']}", flush=True)
    print(f"[reproduce] {res.direction['sentence']}", flush=True)
    print(f"[reproduce] wrote {', '.join(str(p) for p in paths)}", flush=True)
    return 0 if ok else 1
