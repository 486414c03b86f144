"""The design search's loss over friction x restitution on a twin, at the truth's level and κ: where
the truth's basin lies in the contact's two parameters, and whether a sweep of one at a time can
reach it (docs/posterior.md, "The SBC's misses in friction and restitution").

    python -m evaluation.studies.contact_landscape posterior.run=outputs/torus_small_s0 preset=small threads=1 \\
        posterior.sequence=outputs/sbc_d4s/case_033/twin +points=16 +out=outputs/sbc_d4s/case_033/contact.json

Scores an n x n grid ((i + 1/2) / n of [0, 1] each) with the search's scorer (the design search's
images and scale, `design_search_config`) on the first `+frames` fit frames (default: half the
window, as the design search's first window) and on the whole window, and the truth itself on both.
Writes the JSON (`+out`) and a heat map of each window's loss above the truth's beside it (.png);
prints the truth's losses and the seconds.
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
from sgdr.posterior.likelihood import RenderedImages
from sgdr.posterior.run import asset_level, design_search_config
from sgdr.run_folder import run_asset_and_sequence


def grid_values(truth: dict, level: float, grid: np.ndarray) -> dict:
    """The scorer's candidates: friction (rows) x restitution (columns) on `grid`, the level and κ
    the truth's."""
    mu, e = np.meshgrid(grid, grid, indexing="ij")
    n = mu.size
    return {
        "log10_k": np.full(n, level + float(truth["log10_k_shift"])),
        "kappa": np.full(n, float(truth["kappa"])),
        "friction": mu.ravel(),
        "restitution": e.ravel(),
    }


def twin_values(seq, asset) -> dict:
    """The twin's truth of the shift, κ, friction and restitution; those its gt leaves out are the
    asset's own (a shift of 0). Refuses a sequence that is not a twin."""
    gt = seq.gt_params() or {}
    if not gt.get("twin"):
        raise SystemExit(f"error: {seq.root}: not a twin (its gt/params.json holds no truth)")
    own = {k: float(np.mean(asset.values[k])) for k in ("kappa", "friction", "restitution") if k in asset.values}
    truth = {"log10_k_shift": 0.0, **own, **{k: float(v) for k, v in (gt.get("truth") or {}).items()}}
    missing = [k for k in ("kappa", "friction", "restitution") if k not in truth]
    if missing:
        raise SystemExit(f"error: {seq.root}: the asset has no {missing}; the contact landscape needs them")
    return truth


def plot(out: dict, path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 4.2))
    for ax, key in zip(axes, ("first", "whole")):
        above = np.asarray(out[key]) - out[f"truth_{key}"]
        im = ax.imshow(above, origin="lower", extent=[0, 1, 0, 1], cmap="viridis", aspect="auto")
        ax.plot(out["truth"]["restitution"], out["truth"]["friction"], "r+", ms=14, mew=2)
        ax.set_xlabel("restitution")
        ax.set_ylabel("friction")
        ax.set_title(f"{key} window: loss above the truth's (+)")
        fig.colorbar(im, ax=ax)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def main(argv: list[str]) -> None:
    extra, argv = split_extra(argv)
    with user_errors():
        cfg = OmegaConf.to_object(compose(argv))
        validate(cfg)
        pc = cfg.posterior
        if not pc.sequence:
            raise SystemExit("error: posterior.sequence=<a twin sequence folder> is needed")
        n = int(extra.get("points", 16))
        if n < 2:
            raise SystemExit(f"error: +points={n}: need at least 2 per parameter")
        sgdr.backend.init(cfg.backend, cfg.threads or None)
        _, asset, _, seq = run_asset_and_sequence(Path(pc.run), pc.sequence, cfg.scene_file, "posterior")
        truth = twin_values(seq, asset)
        sc = design_search_config(cfg)
        images = RenderedImages(asset, seq, None, cfg.render, cfg.recon.lambda_dssim, sc.image_scale,
                                sc.images_per_call)  # fmt: skip
        frames = int(extra.get("frames", max(1, round(0.5 * images.scorer.n_fit_frames))))
        grid = (np.arange(n) + 0.5) / n
        level = asset_level(asset)
        t0 = time.time()
        values = grid_values(truth, level, grid)
        at_truth = {**grid_values(truth, level, np.zeros(1)), "friction": np.array([truth["friction"]]),
                    "restitution": np.array([truth["restitution"]])}  # fmt: skip
        out = {
            "truth": truth,
            "grid": grid.tolist(),
            "frames_first": frames,
            "first": images.scorer(values, frames=frames).reshape(n, n).tolist(),
            "whole": images.scorer(values).reshape(n, n).tolist(),
            "truth_first": float(images.scorer(at_truth, frames=frames)[0]),
            "truth_whole": float(images.scorer(at_truth)[0]),
        }
        out["seconds"] = time.time() - t0
        path = Path(extra.get("out", Path(pc.sequence).parent / "contact_landscape.json"))
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(out))
        plot(out, path.with_suffix(".png"))
        keys = ("truth", "truth_first", "truth_whole", "seconds")
        print(json.dumps({**{k: out[k] for k in keys}, "out": str(path)}))


if __name__ == "__main__":
    main(sys.argv[1:])
