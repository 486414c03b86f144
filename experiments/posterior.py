"""The posterior of a finished reconstruction's physics: how far to trust the identified asset.

    python experiments/posterior.py preset=small posterior.run=outputs/torus_small_s0
    python experiments/posterior.py preset=tiny posterior.run=outputs/torus_tiny_s0 posterior.sequence=/tmp/twin
    python experiments/posterior.py preset=small posterior.run=outputs/torus_small_s0 \
        'posterior.ensemble=[outputs/torus_small_s1,outputs/torus_small_s2]'   # finished posteriors combined

emcee ensembles over a global log10 k shift, κ, μ, e (posterior.parameters) under the uniform
priors of conf/posterior/default.yaml, with the silhouette likelihood of the fit frames
(sgdr/posterior/likelihood.py); the sizes come from the preset. Writes <run>/posterior/
(posterior.json, samples.npz, corner.png, traces.png, predictive.png), adds the 'Posterior'
section to <run>/report/report.html (its first line says 'Not converged' when a criterion
failed) and logs the files and diagnostics into the run's MLflow run. docs/posterior.md says
what everything means. The last line printed is one JSON object.
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
from sgdr.posterior.run import run_posterior

sgdr.config.register()


@hydra.main(config_path="../conf", config_name="config", version_base="1.3")
def main(cfg: DictConfig) -> None:
    """A bad value or a missing run folder ends with one line `error: ...` (exit 2)."""

    with user_errors(FileNotFoundError):
        posterior(cfg)


def posterior(cfg: DictConfig) -> None:
    sgdr.backend.init(cfg.backend, cfg.threads or None)

    logging.getLogger("sgdr").setLevel(logging.INFO)
    logging.getLogger("emcee").setLevel(logging.ERROR)  # its short-chain warning is our verdict's job
    c = OmegaConf.to_object(cfg)
    validate(c)
    if c.posterior.ensemble:  # combine finished posteriors of several runs (sgdr/posterior/ensemble.py)
        from sgdr.posterior.ensemble import run_ensemble

        rec = run_ensemble(c)
        print(rec["headline"])
        print(json.dumps({k: rec[k] for k in ("out_dir", "runs", "truth_inside_fit", "truth_inside_future")}))
        return
    record = run_posterior(c, progress=True)
    d = record["diagnostics"]
    print(record["headline"])
    if record.get("report"):
        print(f"report: {record['report']}")
    summary = {
        "posterior": str(Path(c.posterior.out_dir or Path(c.posterior.run) / "posterior")),
        "converged": record["converged"],
        "tau_max": d["tau_max"],
        "rhat_max": max((v for v in d["rhat"].values() if v is not None), default=None),
        "median": d["median"],
        "q05": d["q05"],
        "q95": d["q95"],
        "truth_inside_5_95": record["truth_inside_5_95"],
        "seconds": record["cost"]["seconds"],
    }
    print(json.dumps(summary))


if __name__ == "__main__":
    main()
