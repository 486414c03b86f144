"""The tables' cells from the run folders: one run folder per (method, object) cell, its
metrics.json read into `Cell`s (ours beside the paper's), the means over the objects, and what
the tables say (the PAC-NeRF / Spring-Gaus ratio of mean future CD, Table 3's direction).

A cell is one run folder `<output_dir>/<object>_<preset>[_<method>]_s<seed>` (`run_dir_name`, the
rule of `sgdr.run_folder.default_run_name`). A missing run is a visible "missing" cell with its
reason, never a number; a score a method does not have (null in its metrics.json, e.g. a fit-only
method's future) shows the run's reason.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from evaluation import ROOT
from evaluation.reproduce.tables import HETERO, MEAN, PAPER_T1, PAPER_T3, TABLES, TableSpec

DEFAULT_METHOD = "spring_gaus"  # the run folder leaves its name out (sgdr.run_folder.DEFAULT_METHOD)


def run_dir_name(obj: str, preset: str, method: str, seed: int) -> str:
    """`<object>_<preset>[_<method>]_s<seed>` (sgdr.run_folder.default_run_name's rule)."""
    tag = "" if method == DEFAULT_METHOD else f"_{method}"
    return f"{obj}_{preset}{tag}_s{seed}"


def method_available(method: str, conf_dir: Path = ROOT / "conf") -> bool:
    return (Path(conf_dir) / "method" / f"{method}.yaml").is_file()


@dataclass(frozen=True)
class Run:
    """What a cell's run folder holds: its metrics (None when there are none) or why not."""

    method: str
    obj: str
    path: Path
    metrics: dict | None
    reason: str = ""  # why there are no metrics

    @property
    def commit(self) -> str | None:
        """The commit the run's metrics.json was written on (its provenance)."""
        return ((self.metrics or {}).get("provenance") or {}).get("git_commit")

    @property
    def minutes(self) -> float | None:
        return (self.metrics or {}).get("minutes")


def read_metrics(run_dir: Path) -> dict | None:
    """A run folder's metrics.json (written by `experiments/reconstruct.py`); None when it has
    none. A corrupt file raises `json.JSONDecodeError`."""
    metrics_file = Path(run_dir) / "metrics.json"
    return json.loads(metrics_file.read_text()) if metrics_file.is_file() else None


def read_run(output_dir: Path, method: str, obj: str, preset: str, seed: int, available: bool = True) -> Run:
    """The run folder of one (method, object) cell and its metrics.json, or the reason it has none."""
    path = Path(output_dir) / run_dir_name(obj, preset, method, seed)
    try:
        metrics = read_metrics(path)
    except json.JSONDecodeError as err:
        return Run(method, obj, path, None, f"unreadable metrics.json ({err})")
    if metrics is not None:
        return Run(method, obj, path, metrics)
    if not available:
        return Run(method, obj, path, None, f"method not in this checkout (no conf/method/{method}.yaml)")
    if path.is_dir():
        return Run(
            method, obj, path, None, f"unfinished or failed: no metrics.json in {path} (see its reconstruct.log)"
        )
    return Run(method, obj, path, None, f"not run (no {path})")


@dataclass(frozen=True)
class Cell:
    """One number of a table: ours (or why there is none) and the paper's."""

    table: int
    metric: str
    method: str
    obj: str  # an object or MEAN
    value: float | None
    paper: float | None
    status: str  # "ok", "missing" (no run / no metrics) or "null" (the run has no such score)
    reason: str = ""
    run: str | None = None  # the run folder (a mean: None)
    run_commit: str | None = None


def _score(run: Run, key: str) -> tuple[float | None, str, str]:
    """(value, status, reason) of one score of a run."""
    if run.metrics is None:
        return None, "missing", run.reason
    if key not in run.metrics:
        return None, "missing", f"{run.path.name}/metrics.json has no {key!r}"
    value = run.metrics[key]
    if value is None:
        why = (run.metrics.get("missing") or {}).get(key, "null in metrics.json, no reason given")
        return None, "null", why
    value = float(value)
    if not math.isfinite(value):  # metrics.json is strict JSON; guard against a hand-written one
        return None, "null", f"{value} in metrics.json"
    return value, "ok", ""


def table_cells(spec: TableSpec, runs: dict[tuple[str, str], Run]) -> list[Cell]:
    """Every cell of one table, the mean over the objects included (a mean exists only when every
    object has its number)."""
    cells = []
    for metric in spec.metrics:
        for method in spec.methods:
            paper = spec.paper.get((method, metric.key), {})
            values = []
            for obj in spec.objects:
                run = runs[(method, obj)]
                value, status, reason = _score(run, metric.key)
                values.append(value)
                cells.append(
                    Cell(
                        spec.number,
                        metric.key,
                        method,
                        obj,
                        value,
                        paper.get(obj),
                        status,
                        reason,
                        str(run.path),
                        run.commit,
                    )
                )
            if spec.per_object:
                have = [v for v in values if v is not None]
                if len(have) == len(values):
                    cells.append(
                        Cell(spec.number, metric.key, method, MEAN, sum(have) / len(have), paper.get(MEAN), "ok")
                    )
                else:
                    why = f"{len(values) - len(have)} of {len(values)} objects have no number"
                    cells.append(Cell(spec.number, metric.key, method, MEAN, None, paper.get(MEAN), "missing", why))
    return cells


# ------------------------------------------------------------------------------ what the tables say
def future_cd_ratio(cells: Sequence[Cell]) -> dict:
    """PAC-NeRF's mean future CD over Spring-Gaus's (Table 1), measured and the paper's."""
    mean = {c.method: c for c in cells if c.table == 1 and c.metric == "future_cd" and c.obj == MEAN}
    sg, pac = mean.get("spring_gaus"), mean.get("pacnerf")
    out = {
        "what": "PAC-NeRF mean future CD / Spring-Gaus mean future CD (Table 1)",
        "paper": PAPER_T1[("pacnerf", "future_cd")][MEAN] / PAPER_T1[("spring_gaus", "future_cd")][MEAN],
        "spring_gaus_mean_future_cd": sg.value if sg else None,
        "pacnerf_mean_future_cd": pac.value if pac else None,
        "measured": None,
    }
    if sg and pac and sg.value is not None and pac.value is not None and sg.value > 0:
        out["measured"] = pac.value / sg.value
        word = "lower" if out["measured"] > 1 else "higher"
        factor = out["measured"] if out["measured"] > 1 else 1 / out["measured"]
        out["sentence"] = (
            f"Measured: Spring-Gaus's mean future CD ({sg.value:.2f}) is {factor:.2f}x {word} than PAC-NeRF's "
            f"({pac.value:.2f}); the paper: 3.48x lower (5.16 against 17.94)."
        )
    else:
        missing = [c.method for c in (sg, pac) if c is not None and c.value is None]
        out["sentence"] = (
            f"Not measured: no mean future CD for {', '.join(missing) or 'either method'} "
            "(a mean needs all seven objects); the paper: Spring-Gaus 3.48x lower (5.16 against 17.94)."
        )
    return out


def table3_direction(cells: Sequence[Cell]) -> dict:
    """Which method has the lowest fit CD and the lowest future CD on torus_hetero (Table 3),
    measured (among the methods that have the number) and the paper's, with both orderings."""
    out = {}
    for key in ("fit_cd", "future_cd"):
        got = sorted((c.value, c.method) for c in cells if c.table == 3 and c.metric == key and c.value is not None)
        paper = sorted((v[HETERO], m) for (m, k), v in PAPER_T3.items() if k == key)
        absent = [c.method for c in cells if c.table == 3 and c.metric == key and c.value is None]
        out[key] = {
            "lowest": got[0][1] if got else None,
            "order": [m for _, m in got],
            "without_number": absent,
            "paper_lowest": paper[0][1],
            "paper_order": [m for _, m in paper],
        }
    parts = []
    for key, name in (("fit_cd", "fit CD"), ("future_cd", "future CD")):
        d = out[key]
        measured = " < ".join(d["order"]) if d["order"] else "no method has a number"
        extra = f" ({', '.join(d['without_number'])}: no number)" if d["without_number"] else ""
        parts.append(f"{name}: {measured}{extra}; paper: {' < '.join(d['paper_order'])}")
    out["sentence"] = "Table 3 on torus_hetero, lowest first. " + ". ".join(parts) + "."
    return out


@dataclass
class Results:
    """The tables' cells, what they say, and the record of how they were made."""

    cells: list[Cell]
    runs: dict[tuple[str, str], Run]
    ratio: dict
    direction: dict
    meta: dict = field(default_factory=dict)


def collect(
    output_dir: Path,
    preset: str,
    seed: int,
    tables: Sequence[TableSpec] = TABLES,
    conf_dir: Path = ROOT / "conf",
    meta: dict | None = None,
) -> Results:
    """Read every cell's run folder and build the tables."""
    runs = {}
    for spec in tables:
        for method in spec.methods:
            for obj in spec.objects:
                if (method, obj) not in runs:
                    runs[(method, obj)] = read_run(
                        output_dir, method, obj, preset, seed, method_available(method, conf_dir)
                    )
    cells = [c for spec in tables for c in table_cells(spec, runs)]
    return Results(cells, runs, future_cd_ratio(cells), table3_direction(cells), dict(meta or {}))
