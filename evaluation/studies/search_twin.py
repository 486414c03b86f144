"""The identification's global search on a sequence the run did not see (e.g. an SBC twin), alone:
what the posterior's design starts from (`sgdr.posterior.run.search_sequence`), without the
sampler after it.

    python -m evaluation.studies.search_twin posterior.run=outputs/torus_small_s0 preset=small threads=1 \\
        posterior.sequence=outputs/calibration_small/case_000/twin posterior.surrogate.design_search.line_points=0

Its settings are the posterior's design search's (`design_search_config`: recon.search.* with
posterior.surrogate.design_search.* in place). Prints one JSON object: the search's best values
and loss (on the whole fit window), its evaluations, the earlier stages of the frame schedule,
and the seconds it took (docs/posterior.md, "SBC at small").
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

from omegaconf import OmegaConf

import sgdr.backend
from sgdr.cli import user_errors
from sgdr.config import compose, validate
from sgdr.posterior.run import search_sequence
from sgdr.run_folder import run_asset_and_sequence


def main(argv: list[str]) -> None:
    with user_errors():
        cfg = OmegaConf.to_object(compose(argv))
        validate(cfg)
        pc = cfg.posterior
        if not pc.sequence:
            raise SystemExit("error: posterior.sequence=<a sequence folder> is needed (the run's own has its search)")
        sgdr.backend.init(cfg.backend, cfg.threads or None)
        _, asset, _, seq = run_asset_and_sequence(Path(pc.run), pc.sequence, cfg.scene_file, "posterior")
        t0 = time.time()
        found = search_sequence(cfg, asset, seq, None)
        keys = ("names", "best", "best_loss", "n_evaluations", "stages")
        print(json.dumps({**{k: found[k] for k in keys}, "seconds": time.time() - t0}))


if __name__ == "__main__":
    main(sys.argv[1:])
