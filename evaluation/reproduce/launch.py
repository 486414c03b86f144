"""Running the cells the tables need: Hydra multiruns of sgdr's drivers.

1. The cells: every (method, object) pair a table needs (`needed_cells`). A cell whose
   `metrics.json` exists is finished and skipped (`--rerun` sends it through the pipeline again,
   which verifies its stages and redoes only what changed); a method without
   `conf/method/<method>.yaml` in this checkout is not run and its cells say so.
2. The sequences the cells need, generated one after another (`experiments/generate.py -m`,
   complete ones skipped), so that parallel jobs never generate the same sequence twice.
3. The unfinished cells through Hydra multiruns of `experiments/reconstruct.py -m` (one multirun
   per set of objects that need the same methods, `plan_multiruns`), with the launcher of
   `--launcher` (`launcher_overrides`). The multirun's own output goes to a log file beside
   Hydra's `multirun.yaml`; `Progress` prints one line per finished cell.
"""

from __future__ import annotations

import datetime as _dt
import json
import os
import shlex
import subprocess
import sys
import threading
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

from omegaconf import OmegaConf

from evaluation import ROOT
from evaluation.reproduce.cells import method_available, run_dir_name
from evaluation.reproduce.tables import TABLES, TableSpec
from sgdr.config import compose
from sgdr.tracking.tracker import ensure_store

Pair = tuple[str, str]  # a cell: (method, object)


def needed_cells(
    tables: Sequence[TableSpec] = TABLES, methods: Iterable[str] | None = None, objects: Iterable[str] | None = None
) -> list[tuple[str, str]]:
    """The (method, object) pairs the tables need, in table order, optionally narrowed."""
    methods, objects = (set(methods) if methods else None), (set(objects) if objects else None)
    out = []
    for spec in tables:
        for obj in spec.objects:
            for method in spec.methods:
                if (
                    (method, obj) not in out
                    and (methods is None or method in methods)
                    and (objects is None or obj in objects)
                ):
                    out.append((method, obj))
    return out


def plan_multiruns(cells: Sequence[tuple[str, str]]) -> list[tuple[tuple[str, ...], tuple[str, ...]]]:
    """Group cells into Hydra sweeps `method=a,b synth.object=x,y` (a product each): the objects
    that need the same methods share one sweep. Exact: the sweeps' products are the cells."""
    by_obj: dict[str, list[str]] = {}
    for method, obj in cells:
        by_obj.setdefault(obj, []).append(method)
    groups: dict[tuple[str, ...], list[str]] = {}
    for obj, methods in by_obj.items():
        groups.setdefault(tuple(methods), []).append(obj)
    return [(methods, tuple(objs)) for methods, objs in groups.items()]


LAUNCHERS = ("joblib", "submitit_local", "submitit_slurm", "slurm", "basic")


def launcher_overrides(launcher: str, jobs: int, threads: int) -> list[str]:
    """Hydra overrides choosing the launcher and its parallelism, and each run's share of the
    machine: `threads` Dr.Jit threads and as many processes for the evaluation's EMDs
    (`recon.eval_workers`; on a cluster node every CPU of the job, the default)."""
    if launcher == "basic":
        return [f"threads={threads}", f"recon.eval_workers={threads}"]
    if launcher in ("submitit_slurm", "slurm"):  # a node of its own: the job's CPUs (or --threads)
        return [f"hydra/launcher={launcher}", *([f"threads={threads}"] if threads else [])]
    out = [f"hydra/launcher={launcher}", f"threads={threads}"]
    if launcher == "joblib":
        # the EMDs in the run's own process: a loky worker's spawned children fail to start
        # ("cannot find context for 'loky'": they inherit loky's start method, unknown to them)
        out += [f"hydra.launcher.n_jobs={jobs}", "recon.eval_workers=1"]
    elif launcher == "submitit_local":  # the local executor starts every job of a batch at once
        out += [f"hydra.sweeper.max_batch_size={jobs}", f"recon.eval_workers={threads}"]
    return out


class Progress:
    """Prints one line per cell whose metrics.json appears (or is rewritten) after `start`."""

    def __init__(self, cells: Sequence[tuple[str, str]], paths: dict[tuple[str, str], Path], total: int, done: int):
        self.pending = {c: paths[c] / "metrics.json" for c in cells}
        self.total, self.done = total, done
        self.start = time.time()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, daemon=True)

    def __enter__(self):
        self._thread.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join()
        self.poll()

    def _loop(self):
        while not self._stop.wait(5.0):
            self.poll()

    def poll(self):
        for cell, f in list(self.pending.items()):
            try:
                fresh = f.stat().st_mtime >= self.start
            except OSError:
                continue
            if not fresh:
                continue
            try:
                m = json.loads(f.read_text())
            except (OSError, json.JSONDecodeError):
                continue  # being written: the next poll reads it
            del self.pending[cell]
            self.done += 1
            scores = ", ".join(
                f"{k} {m[k]:.3g}" for k in ("fit_cd", "future_cd", "fit_psnr") if isinstance(m.get(k), (int, float))
            )
            minutes = m.get("minutes")
            took = f"{minutes:.1f} min" if isinstance(minutes, (int, float)) else "?"
            print(
                f"[reproduce] {self.done}/{self.total} {cell[0]} on {cell[1]} finished ({took}; {scores})", flush=True
            )


def run_logged(cmd: list[str], log_path: Path, env: dict) -> int:
    """Run `cmd` with its output appended to `log_path`; its exit status."""
    log_path.parent.mkdir(parents=True, exist_ok=True)
    with open(log_path, "a") as log:
        log.write(f"==== {_dt.datetime.now().isoformat(timespec='seconds')} | {shlex.join(cmd)}\n")
        log.flush()
        return subprocess.call(cmd, cwd=ROOT, stdout=log, stderr=subprocess.STDOUT, env=env)


def _tail(path: Path, n: int = 15) -> str:
    try:
        return "\n".join(path.read_text(errors="replace").splitlines()[-n:])
    except OSError:
        return ""


def prepare_store(overrides: list[str]) -> None:
    """Create the MLflow store and experiment the runs log to before parallel jobs start (two
    jobs creating a fresh SQLite store at once race on its schema migration)."""
    cfg = compose([o for o in overrides if not o.lstrip("+~").startswith("hydra")])
    ensure_store(OmegaConf.to_object(cfg.tracking))


@dataclass(frozen=True)
class Plan:
    """The cells of one call: those it can run and those it will run."""

    cells: list[Pair]  # the cells asked for whose method is in this checkout
    paths: dict[Pair, Path]  # each cell's run folder
    todo: list[Pair]  # the cells to run (without --rerun: the unfinished ones)


def plan_cells(args) -> Plan:
    """The cells `--methods` / `--objects` ask for, less the methods not in this checkout, and
    which of them to run; prints what is left out and why."""
    cells = needed_cells(methods=args.methods, objects=args.objects)
    unavailable = sorted({m for m, _ in cells if not method_available(m)})
    if unavailable:
        print(f"[reproduce] not in this checkout (their cells stay missing): {', '.join(unavailable)}", flush=True)
    cells = [c for c in cells if c[0] not in unavailable]
    paths = {c: Path(args.output_dir) / run_dir_name(c[1], args.preset, c[0], args.seed) for c in cells}
    finished = [c for c in cells if (paths[c] / "metrics.json").is_file()]
    todo = cells if args.rerun else [c for c in cells if c not in finished]
    if finished and not args.rerun:
        print(
            f"[reproduce] {len(finished)}/{len(cells)} cells finished before, skipped (--rerun redoes them)", flush=True
        )
    return Plan(cells, paths, todo)


def generate_sequences(objects: Sequence[str], data_dir: Path, common: list[str], overrides: list[str], log_path, env):
    """Step 2: the objects' sequences, one after another; (the command, whether it succeeded)."""
    gen = [sys.executable, "experiments/generate.py", "-m", *common, f"synth.object={','.join(objects)}", *overrides]
    print(
        f"[reproduce] sequences: {', '.join(objects)} into {data_dir} (complete ones skipped; log {log_path})",
        flush=True,
    )
    if run_logged(gen, log_path, env) != 0:
        print(f"[reproduce] generation failed:\n{_tail(log_path)}", file=sys.stderr, flush=True)
        return shlex.join(gen), False
    return shlex.join(gen), True


def run_multirun(
    methods: tuple[str, ...], objs: tuple[str, ...], plan: Plan, done: int, args, reconstruct: list[str], log_path, env
) -> tuple[int, bool]:
    """Step 3 for one sweep `method=<methods> synth.object=<objs>` (`reconstruct`: its command);
    (the cells finished so far, whether the multirun succeeded)."""
    cluster = args.launcher in ("submitit_slurm", "slurm")
    batch = [(m, o) for m in methods for o in objs]
    print(
        f"[reproduce] multirun: {len(batch)} cells (method={','.join(methods)} x synth.object={','.join(objs)}), "
        f"launcher {args.launcher}, "
        + ("one job per cell" if cluster else f"{args.jobs} jobs x {threads_per_run(args)} threads"),
        flush=True,
    )
    with Progress(batch, plan.paths, len(plan.cells), done) as progress:
        rc = run_logged(reconstruct, log_path, env)
    if rc != 0:
        left = ", ".join(f"{m} on {o}" for m, o in progress.pending) or "none"
        print(
            f"[reproduce] the multirun exited with {rc}; unfinished cells: {left}. Its log ends:\n{_tail(log_path)}",
            file=sys.stderr,
            flush=True,
        )
    return progress.done, rc == 0


def threads_per_run(args) -> int:
    """Dr.Jit threads of each run: --threads, else the cores shared by --jobs (a cluster: 0, the job's CPUs)."""
    cluster = args.launcher in ("submitit_slurm", "slurm")
    return args.threads or (0 if cluster else max(1, (os.cpu_count() or 1) // max(1, args.jobs)))


def reproduce(args, overrides: list[str]) -> tuple[list[str], bool]:
    """Generate and run the unfinished cells; returns (the commands run, whether all succeeded)."""
    out_dir, data_dir = Path(args.output_dir), Path(args.data_dir)
    plan = plan_cells(args)
    done = len(plan.cells) - len(plan.todo)
    common = [f"preset={args.preset}", f"seed={args.seed}", f"data_dir={data_dir}", f"recon.output_dir={out_dir}"]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))}
    log_path = out_dir / "multirun" / f"reproduce_{args.preset}.log"
    if not plan.todo:
        return [], True
    objects = sorted({o for _, o in plan.todo})
    command, ok = generate_sequences(objects, data_dir, common, overrides, log_path, env)
    commands = [command]
    if not ok:
        return commands, False
    prepare_store(common + overrides)
    launcher = launcher_overrides(args.launcher, args.jobs, threads_per_run(args))
    for methods, objs in plan_multiruns(plan.todo):
        cmd = [
            sys.executable,
            "experiments/reconstruct.py",
            "-m",
            *common,
            f"method={','.join(methods)}",
            f"synth.object={','.join(objs)}",
            *launcher,
            *overrides,
        ]
        commands.append(shlex.join(cmd))
        done, succeeded = run_multirun(methods, objs, plan, done, args, cmd, log_path, env)
        ok = ok and succeeded
    return commands, ok
