"""What a finished reconstruction's simulation gets wrong: which model extension the data ask for.

    python experiments/diagnose.py preset=small diagnose.run=outputs/torus_small_s0
    python experiments/diagnose.py preset=tiny diagnose.run=outputs/torus_tiny_s0 diagnose.sequence=/tmp/twin

Fits every candidate of diagnose.candidates (air drag, gravity's magnitude, the ground plane's
height) from the run's identified physics on half the views and judges it on the other half
(sgdr/discrepancy/, docs/discrepancy.md), then the residual diagnostics of the base fit. Writes
<run>/diagnose/diagnosis.json, residuals.json and residual_*.png, and adds the 'Model discrepancy'
section to <run>/report/report.html; the last line printed is one JSON object with "cause",
"candidates" and the residuals' headline numbers.
"""

from __future__ import annotations

import json
import logging
import sys
from pathlib import Path

import hydra
from omegaconf import DictConfig, OmegaConf

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import sgdr.backend  # noqa: E402
import sgdr.config  # noqa: E402
from sgdr.cli import user_errors
from sgdr.config import validate
from sgdr.discrepancy.run import run_diagnosis

sgdr.config.register()


@hydra.main(config_path="../conf", config_name="config", version_base="1.3")
def main(cfg: DictConfig) -> None:
    """A bad value or a missing run folder ends with one line `error: ...` (exit 2)."""

    with user_errors(FileNotFoundError):
        diagnose(cfg)


def diagnose(cfg: DictConfig) -> None:
    sgdr.backend.init(cfg.backend, cfg.threads or None)

    logging.getLogger("sgdr").setLevel(logging.INFO)
    c = OmegaConf.to_object(cfg)
    validate(c)
    record = run_diagnosis(c)
    print(f"diagnosis: {record['file']}")
    summary = {
        "cause": record["cause"],
        "candidates": {
            n: {k: v[k] for k in ("value", "interval", "held_out_loss", "gain", "time_gain", "future_gain", "decision")}
            for n, v in record["candidates"].items()
        },
        "judge": record["judge"],
        "base_held_out_loss": record["base"]["d_held_out"],
        "base_refit": None
        if record.get("rebase") is None
        else {
            "values": {n: st["values"] for n, st in record["rebase"]["steps"].items() if st["kept"]},
            "held_out_gain": record["rebase"]["held_out_gain"],
            "time_gain": record["rebase"]["time_gain"],
            "future_gain": record["rebase"]["future_gain"],
        },
        "v0_refit": record["v0_refit"],
        "residuals": record.get("residuals"),
        "seconds": round(record["seconds"], 1),
    }
    print(json.dumps(summary))


if __name__ == "__main__":
    main()
