"""Reconstruct a sequence, predict its future, evaluate and report.

    python experiments/reconstruct.py                          # = make demo: the torus, small preset
    python experiments/reconstruct.py sequence=/path/my_banana  # your own sequence
    python experiments/reconstruct.py preset=tiny synth.object=apple recon.force=true

Uses `sequence=` when given, else `<data_dir>/<synth.object>` (generated at the preset when
missing). Every config value and every image is checked first (errors name the key or the
file). Outputs go to `<recon.output_dir>/<sequence>_<preset>_s<seed>/` (stages, report,
asset, config.yaml, metrics.json, reconstruct.log), never into a folder holding another
sequence, and to one MLflow run per run folder in the store (`tracking.uri`, see
sgdr.tracking). A rerun skips verified completed stages, resumes an interrupted one and
continues the same MLflow run. The last line printed is one JSON object with the headline scores.
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
from sgdr.tracking import resolve_uri

sgdr.config.register()

HEADLINE = (
    "fit_psnr",
    "fit_ssim",
    "fit_cd",
    "future_cd",
    "baseline_future_cd",
    "future_emd",
    "future_psnr",
    "future_ssim",
    "minutes",
)


@hydra.main(config_path="../conf", config_name="config", version_base="1.3")
def main(cfg: DictConfig) -> None:
    with user_errors():
        sgdr.backend.init(cfg.backend, cfg.threads or None)
        from sgdr.pipeline.run import run_pipeline

        logging.getLogger("sgdr").setLevel(logging.INFO)
        out = run_pipeline(OmegaConf.to_object(cfg), progress=True)
    report = out.run_dir / "report"
    print(f"report:       {report / 'report.html'} (open in a browser: verdict, warnings, curves, videos)")
    print(f"run folder:   {out.run_dir}")
    print(f"metrics:      {out.run_dir / 'metrics.json'}")
    videos = [p for p in (report / "side_by_side.mp4", report / "future.mp4") if p.is_file()]
    if videos:
        print(f"videos:       {', '.join(map(str, videos))} (ground truth | prediction)")
    plots = sorted(report.glob("*.png"))
    if plots:
        print(f"plots:        {', '.join(map(str, plots))}")
    if (report / "ply").is_dir():
        print(f"PLYs:         {report / 'ply'}/centres_*.ply, anchors_*.ply")
    if (out.run_dir / "asset" / "asset.json").is_file():
        print(f"asset:        {out.run_dir / 'asset'} (python experiments/simulate.py recon.simulate.asset=...)")
    elif (out.run_dir / "asset").is_dir():
        print(
            f"asset:        {out.run_dir / 'asset'} (the {out.metrics.get('model')} model's; simulate.py takes spring-mass assets)"
        )
    store = resolve_uri(cfg.tracking.uri)  # a relative SQLite path is the repository root's
    print(f"MLflow store: {store} (mlflow ui --backend-store-uri {store})")
    print(
        json.dumps(
            {
                "sequence": out.metrics["sequence_name"],
                "run": str(out.run_dir),
                **{k: out.metrics.get(k) for k in HEADLINE},
            }
        )
    )


if __name__ == "__main__":
    main()
