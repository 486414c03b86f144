"""Diagnosis benchmark: `python -m evaluation.bench diagnose` (or `make bench BENCH=diagnose`).

What one discrepancy diagnosis (issue 15, `experiments/diagnose.py`) costs against the
reconstruction it diagnoses, measured in the same run on the same machine. The built-in torus
sequence at the preset (`SGDR_BENCH_PRESET`, default `tiny`; `small` takes about 15 minutes)
is generated first (not timed), reconstructed by the pipeline (`run_pipeline`: every stage,
prediction, evaluation and report), and diagnosed with the default candidate list on its own
sequence (`run_diagnosis`: the base refit, every candidate, the residual diagnostics and the
report section). Reported: both wall times, their ratio `diagnose_over_reconstruct` (the
machine-independent figure: how many reconstructions one diagnosis costs), and the issue's
absolute budget for the preset (2 min at tiny, 10 min at small on the 2-core development
machine) with `within_budget`, which only means something on that machine. The Dr.Jit kernel
cache (~/.drjit) is left as it is: a first run on a fresh machine includes compilation in both
times.
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
from pathlib import Path

# Imported at the top, unlike the other benchmarks: this one composes the config (which imports
# Dr.Jit) to learn the backend before it can choose it.
import drjit as dr
from omegaconf import OmegaConf

import sgdr.backend as backend
from sgdr.config import compose
from sgdr.discrepancy.run import run_diagnosis
from sgdr.pipeline.run import run_pipeline
from sgdr.run_folder import ensure_sequence

BUDGET_S = {"tiny": 120.0, "small": 600.0}  # the budget for one diagnosis, per preset


def run() -> dict:
    preset = os.environ.get("SGDR_BENCH_PRESET", "tiny")
    log = lambda msg: print(f"[bench diagnose] {msg}", file=sys.stderr, flush=True)  # noqa: E731
    with tempfile.TemporaryDirectory(prefix="sgdr_bench_diagnose_") as tmp:
        root = Path(tmp)
        overrides = [
            f"preset={preset}",
            f"data_dir={root / 'data'}",
            f"recon.output_dir={root / 'outputs'}",
            "tracking.enabled=false",
        ]
        cfg = OmegaConf.to_object(compose(overrides))
        backend.init(cfg.backend, cfg.threads or None)
        log(f"generating the {preset} torus sequence (not timed)")
        ensure_sequence(cfg)
        log("reconstructing")
        t0 = time.perf_counter()
        out = run_pipeline(cfg, progress=False)
        t_recon = time.perf_counter() - t0
        log(f"reconstruction {t_recon:.1f} s; diagnosing")
        dcfg = OmegaConf.to_object(
            compose([*overrides, f"diagnose.run={out.run_dir}", f"diagnose.out_dir={root / 'diagnose'}"])
        )
        t0 = time.perf_counter()
        record = run_diagnosis(dcfg)
        t_diag = time.perf_counter() - t0
        log(f"diagnosis {t_diag:.1f} s, cause {record['cause']}")
    budget = BUDGET_S.get(preset)
    return {
        "preset": preset,
        "diagnose_s": t_diag,
        "reconstruct_s": t_recon,
        "diagnose_over_reconstruct": t_diag / t_recon,
        "budget_s": budget,
        "within_budget": None if budget is None else bool(t_diag <= budget),
        "candidates": sorted(record["candidates"]),
        "cause": record["cause"],
        "threads": dr.thread_count(),
        "backend": cfg.backend,
    }
