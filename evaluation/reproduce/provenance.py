"""How the tables were made: this checkout's commit, the machine, the command, and the commit of
each run behind a cell (a run made on another commit than the tables is named in them)."""

from __future__ import annotations

import contextlib
import datetime as _dt
import os
import platform
import shlex
import subprocess
from collections.abc import Sequence
from pathlib import Path

from evaluation import ROOT
from evaluation.reproduce.cells import Results


def git_commit(root: Path = ROOT) -> tuple[str, bool | None]:
    """(HEAD's sha or "unknown", whether tracked files are modified)."""
    try:
        head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True, check=True)
        dirty = subprocess.run(["git", "status", "--porcelain", "-uno"], cwd=root, capture_output=True, text=True)
        return head.stdout.strip(), bool(dirty.stdout.strip())
    except (OSError, subprocess.SubprocessError):
        return "unknown", None


def machine() -> dict:
    cpu = platform.processor() or platform.machine()
    with contextlib.suppress(OSError):  # no /proc/cpuinfo (not Linux): the platform's name stays
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    return {"host": platform.node(), "cpu": cpu, "cores": os.cpu_count(), "system": platform.platform()}


def tables_record(argv: Sequence[str], args, commands: list[str], minutes: float) -> dict:
    """The record of one `python -m evaluation.reproduce` call (`tables.json`'s top level):
    commit, machine, date, the command and the multiruns it started, the runs' settings."""
    commit, dirty = git_commit()
    return {
        "commit": commit,
        "dirty": dirty,
        "date": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "machine": machine(),
        "command": shlex.join(["python", "-m", "evaluation.reproduce", *argv]),
        "multirun_commands": commands,
        "preset": args.preset,
        "seed": args.seed,
        "output_dir": str(args.output_dir),
        "minutes": minutes,
    }


def provenance_lines(meta: dict) -> list[str]:
    """The record as the tables' first lines."""
    machine = meta.get("machine", {})
    return [
        f"commit {meta.get('commit')}{' (uncommitted changes)' if meta.get('dirty') else ''}, {meta.get('date')}",
        f"machine: {machine.get('cpu')}, {machine.get('cores')} cores, {machine.get('system')}",
        f"command: {meta.get('command')}",
        f"preset {meta.get('preset')}, seed {meta.get('seed')}, runs in {meta.get('output_dir')}",
    ]


def stale_runs(res: Results) -> list[str]:
    """The runs made on another commit than the tables' (`<run folder> (<its commit>)`)."""
    head = res.meta.get("commit")
    return sorted(
        f"{r.path.name} ({r.commit[:10] if r.commit else 'unknown'})"
        for r in res.runs.values()
        if r.metrics is not None and head and r.commit != head
    )
