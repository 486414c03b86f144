"""The tables' output formats, each a function of the collected `Results`: Markdown
(`tables.md`), one long-format CSV per table (`table<n>.csv`), JSON (`tables.json`: the record,
every cell with its run folder and the run's own commit, every run) and one self-contained HTML
page (`tables.html`); `write_tables` writes all four. A cell reads `ours (paper)`; a cell without
a number names its reason in a footnote.
"""

from __future__ import annotations

import csv
import json
from collections.abc import Sequence
from pathlib import Path

from evaluation.reproduce.cells import Cell, Results
from evaluation.reproduce.provenance import provenance_lines, stale_runs
from evaluation.reproduce.tables import METHOD_LABELS, TABLES, UNITS, Metric, TableSpec
from sgdr.report.html import STYLE, Section, esc, paragraph
from sgdr.report.html import table as html_table


def fmt_value(fmt: str, value: float | None, missing: str = "") -> str:
    """`value` formatted with `fmt` (e.g. "{:.2f}"), or `missing` for None."""
    return missing if value is None else fmt.format(value)


def markdown_table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> list[str]:
    """The lines of one Markdown table."""
    lines = ["| " + " | ".join(header) + " |", "|" + " --- |" * len(header)]
    return lines + ["| " + " | ".join(r) + " |" for r in rows]


class _Notes:
    """Footnotes of one table: each distinct reason once, cells refer to it by number."""

    def __init__(self):
        self.reasons: dict[str, int] = {}

    def ref(self, reason: str) -> int:
        return self.reasons.setdefault(reason, len(self.reasons) + 1)


def _cell_text(cell: Cell, metric: Metric, notes: _Notes, paper: bool = True) -> str:
    if cell.status == "ok":
        ours = fmt_value(metric.fmt, cell.value)
    else:
        ours = f"{'missing' if cell.status == 'missing' else 'n/a'} [{notes.ref(cell.reason)}]"
    if paper:
        ours += f" ({fmt_value(metric.fmt, cell.paper) or '?'})"
    return ours


def table_grid(spec: TableSpec, cells: Sequence[Cell]) -> tuple[list[str], list[list[str]], dict[str, int]]:
    """(header, rows, footnotes) of one table in the paper's layout; a cell reads `ours (paper)`."""
    by = {(c.metric, c.method, c.obj): c for c in cells if c.table == spec.number}
    notes = _Notes()
    if spec.per_object:
        header = ["metric", "method", *spec.columns]
        rows = [
            [
                m.label,
                METHOD_LABELS.get(method, method),
                *(_cell_text(by[(m.key, method, o)], m, notes) for o in spec.columns),
            ]
            for m in spec.metrics
            for method in spec.methods
        ]
    else:
        (obj,) = spec.objects
        header = ["method", *(m.label for m in spec.metrics)]
        rows = [
            [METHOD_LABELS.get(method, method), *(_cell_text(by[(m.key, method, obj)], m, notes) for m in spec.metrics)]
            for method in spec.methods
        ]
    return header, rows, notes.reasons


def markdown(res: Results, tables: Sequence[TableSpec] = TABLES) -> str:
    lines = ["# The paper's Tables 1-3, reproduced by sgdr", ""]
    lines += [f"- {s}" for s in provenance_lines(res.meta)]
    stale = stale_runs(res)
    if stale:
        lines.append(f"- runs made on another commit than this one: {', '.join(stale)}")
    lines += ["", UNITS, "", f"**Ratio.** {res.ratio['sentence']}", "", f"**Direction.** {res.direction['sentence']}"]
    for spec in tables:
        header, rows, notes = table_grid(spec, res.cells)
        lines += ["", f"## Table {spec.number}: {spec.title}", ""]
        lines += markdown_table(header, rows)
        if notes or spec.notes:
            lines.append("")
        lines += [f"[{n}] {reason}  " for reason, n in notes.items()]
        lines += [f"Note: {n}" for n in spec.notes]
    return "\n".join(lines) + "\n"


CSV_FIELDS = ("metric", "method", "object", "ours", "paper", "status", "reason", "run", "run_commit")


def write_csv(path: Path, spec: TableSpec, cells: Sequence[Cell]) -> None:
    """One row per cell (the means included, object `mean`): machine-readable, long format."""
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(CSV_FIELDS)
        for c in cells:
            if c.table == spec.number:
                w.writerow((c.metric, c.method, c.obj, c.value, c.paper, c.status, c.reason, c.run, c.run_commit))


def as_json(res: Results, tables: Sequence[TableSpec] = TABLES) -> dict:
    return {
        **res.meta,
        "units": UNITS,
        "ratio": res.ratio,
        "direction": res.direction,
        "tables": [
            {
                "number": spec.number,
                "title": spec.title,
                "methods": list(spec.methods),
                "objects": list(spec.objects),
                "metrics": [m.key for m in spec.metrics],
                "notes": list(spec.notes),
                "cells": [
                    {
                        "metric": c.metric,
                        "method": c.method,
                        "object": c.obj,
                        "value": c.value,
                        "paper": c.paper,
                        "status": c.status,
                        "reason": c.reason or None,
                        "run": c.run,
                        "run_commit": c.run_commit,
                    }
                    for c in res.cells
                    if c.table == spec.number
                ],
            }
            for spec in tables
        ],
        "runs": {
            f"{method}/{obj}": {
                "run": str(r.path),
                "finished": r.metrics is not None,
                "reason": r.reason or None,
                "commit": r.commit,
                "minutes": r.minutes,
            }
            for (method, obj), r in sorted(res.runs.items())
        },
    }


def html_page(res: Results, tables: Sequence[TableSpec] = TABLES) -> str:
    """One self-contained page (inline style, no script, nothing fetched) of the three tables."""
    sections = []
    for spec in tables:
        header, rows, notes = table_grid(spec, res.cells)
        foot = "".join(paragraph(f"[{n}] {reason}") for reason, n in notes.items())
        foot += "".join(paragraph(f"Note: {n}") for n in spec.notes)
        sections.append(Section(f"Table {spec.number}: {spec.title}", html_table(header, rows) + foot))
    stale = stale_runs(res)
    intro = "".join(paragraph(s) for s in provenance_lines(res.meta))
    if stale:
        intro += paragraph(f"Runs made on another commit than this one: {', '.join(stale)}")
    intro += (
        paragraph(UNITS)
        + paragraph(f"Ratio. {res.ratio['sentence']}")
        + paragraph(f"Direction. {res.direction['sentence']}")
    )
    nav = "<nav>" + "".join(f'<a href="#{s.anchor}">{esc(s.title)}</a>' for s in sections) + "</nav>"
    body = "".join(f'<section id="{s.anchor}"><h2>{esc(s.title)}</h2>{s.body}</section>' for s in sections)
    title = "The paper's Tables 1-3, reproduced by sgdr"
    return (
        f'<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8"><title>{esc(title)}</title>'
        f"<style>{STYLE}</style></head><body><h1>{esc(title)}</h1>{intro}{nav}{body}</body></html>\n"
    )


def write_tables(res: Results, results_dir: Path, tables: Sequence[TableSpec] = TABLES) -> list[Path]:
    """tables.md, table<n>.csv, tables.json, tables.html in `results_dir`; returns the paths."""
    results_dir = Path(results_dir)
    results_dir.mkdir(parents=True, exist_ok=True)
    paths = [results_dir / "tables.md"]
    paths[0].write_text(markdown(res, tables))
    for spec in tables:
        paths.append(results_dir / f"table{spec.number}.csv")
        write_csv(paths[-1], spec, res.cells)
    paths.append(results_dir / "tables.json")
    paths[-1].write_text(json.dumps(as_json(res, tables), indent=2, allow_nan=False) + "\n")
    paths.append(results_dir / "tables.html")
    paths[-1].write_text(html_page(res, tables), encoding="utf-8")
    return paths
