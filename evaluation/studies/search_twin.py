"""The identification's global search on a sequence the run did not see (e.g. an SBC twin), alone:
what the posterior's design starts from (`sgdr.posterior.run.search_sequence`), without the
sampler after it.

    python -m evaluation.studies.search_twin posterior.run=outputs/torus_small_s0 preset=small threads=1 \\
        posterior.sequence=outputs/calibration_small/case_000/twin posterior.surrogate.design_search.line_points=0

Its settings are the posterior's design search's (`design_search_config`: recon.search.* with
posterior.surrogate.design_search.* in place). Prints one JSON object: the search's best values
and loss (on the whole fit window), its evaluations, the earlier stages of the frame schedule,
and the seconds it took (docs/posterior.md, "SBC at small"). On a twin (its gt holds the truth) it
also scores the truth with the search's own scorer: its loss on the whole fit window and on each
earlier stage's window, and the search's gap to it (`truth`). `+save=<file>` keeps the search's
whole record (every candidate and loss) there.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np
from omegaconf import OmegaConf

import sgdr.backend
from evaluation.studies.config import split_extra
from sgdr.cli import user_errors
from sgdr.config import compose, validate
from sgdr.identify.global_search import REGION_START
from sgdr.posterior.likelihood import RenderedImages
from sgdr.posterior.run import SEARCHED_AS, asset_level, design_search_config, design_search_space, search_sequence
from sgdr.run_folder import run_asset_and_sequence


def truth_losses(cfg, asset, seq, images: RenderedImages, found: dict) -> dict:
    """The twin's truth scored as the search scored its candidates (`images.scorer`, the search's
    box and level): its loss on the whole fit window and on each earlier stage's window, and the
    search's best minus it on each (a positive gap: the search ended above the truth); {} when the
    sequence is not a twin."""
    gt = seq.gt_params() or {}
    truth = gt.get("truth") or {}
    if not gt.get("twin") or not truth:
        return {}
    _, space = design_search_space(cfg, asset)
    level = asset_level(asset)
    values = {}
    for name in space.names:
        theta = next((k for k, v in SEARCHED_AS.items() if v == name), None)
        if theta in truth:
            values[name] = float(truth[theta]) + (level if name == "log10_k" else 0.0)
        else:
            values[name] = REGION_START.get(name, float(np.mean(asset.values.get(name, 0.0))))
    batch = {n: np.array([v]) for n, v in values.items()}
    whole = float(images.scorer(batch)[0])
    out = {"values": values, "loss": whole, "gap": found["best_loss"] - whole, "stages": []}
    for stage in found.get("stages", []):
        loss = float(images.scorer(batch, frames=int(stage["frames"]))[0])
        out["stages"].append({"frames": stage["frames"], "loss": loss, "gap": stage["best_loss"] - loss})
    return out


def main(argv: list[str]) -> None:
    extra, argv = split_extra(argv)
    with user_errors():
        cfg = OmegaConf.to_object(compose(argv))
        validate(cfg)
        pc = cfg.posterior
        if not pc.sequence:
            raise SystemExit("error: posterior.sequence=<a sequence folder> is needed (the run's own has its search)")
        sgdr.backend.init(cfg.backend, cfg.threads or None)
        _, asset, _, seq = run_asset_and_sequence(Path(pc.run), pc.sequence, cfg.scene_file, "posterior")
        sc = design_search_config(cfg)
        images = RenderedImages(asset, seq, None, cfg.render, cfg.recon.lambda_dssim, sc.image_scale,
                                sc.images_per_call)  # fmt: skip
        t0 = time.time()
        found = search_sequence(cfg, asset, seq, images)
        seconds = time.time() - t0
        if "save" in extra:
            Path(extra["save"]).parent.mkdir(parents=True, exist_ok=True)
            Path(extra["save"]).write_text(json.dumps(found))
        keys = ("names", "best", "best_loss", "n_evaluations", "stages")
        truth = truth_losses(cfg, asset, seq, images, found)
        print(json.dumps({**{k: found[k] for k in keys}, "seconds": seconds, "truth": truth}))


if __name__ == "__main__":
    main(sys.argv[1:])
