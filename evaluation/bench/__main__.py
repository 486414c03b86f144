"""Benchmark runner: `python -m evaluation.bench [NAME ...]` (or `make bench BENCH=NAME`).

Each benchmark is a module `evaluation/bench/<name>.py` with `run() -> dict`; the runner prints
one JSON object per benchmark on its own line (`{"bench": name, ...}`) and nothing else on
stdout (progress goes to stderr). Benchmarks warm up, separate compile time from kernel time,
report medians and compare against a reference measured in the same run.
"""

from __future__ import annotations

import importlib
import json
import pkgutil
import sys
import traceback
from pathlib import Path

HERE = Path(__file__).resolve().parent


def available() -> list[str]:
    """The benchmarks: every module of this package but the runner (`__main__`)."""
    return sorted(m.name for m in pkgutil.iter_modules([str(HERE)]) if not m.name.startswith("_"))


def main(argv: list[str]) -> int:
    if any(a in ("-h", "--help") for a in argv):
        print(f"{__doc__}\navailable: {available()}", file=sys.stderr)
        return 0
    names = [a for a in argv if a] or available()
    unknown = [n for n in names if n not in available()]
    if unknown:
        print(f"unknown benchmark(s) {unknown}; available: {available()}", file=sys.stderr)
        return 2
    status = 0
    for name in names:
        module = importlib.import_module(f"evaluation.bench.{name}")  # chosen by name on the command line
        try:
            result = module.run()
        except Exception as exc:  # report and keep going with the other benchmarks
            traceback.print_exc()
            result = {"error": f"{type(exc).__name__}: {exc}"}
            status = 1
        print(json.dumps({"bench": name, **result}), flush=True)
    return status


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
