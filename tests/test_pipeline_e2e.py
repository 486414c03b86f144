"""The whole pipeline on the tiny preset: generate -> reconstruct -> predict -> evaluate.

Asserts what issue 6 asks of CI: the dynamic loss decreases (the deterministic all-view loss
of a rollout from frame 0, before vs after training) and the fitted model beats the
physics-free baseline on future frames; plus the run's files, stage skipping on a rerun and
the redo of a corrupted stage (with everything downstream of it).
"""

import json

import numpy as np
import pytest
from omegaconf import OmegaConf

from sgdr.config import compose
from sgdr.recon.pipeline import STAGES, run_pipeline


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    root = tmp_path_factory.mktemp("e2e")
    cfg = OmegaConf.to_object(
        compose(
            [
                "preset=tiny",
                f"data_dir={root / 'data'}",
                f"recon.output_dir={root / 'outputs'}",
                f"tracking.uri=sqlite:///{root / 'mlflow.db'}",
            ]
        )
    )
    return cfg, run_pipeline(cfg, progress=False)


def test_dynamic_loss_decreases_and_beats_the_baseline(tiny_run):
    _, out = tiny_run
    m = out.metrics
    assert m["dynamic_eval_loss_final"] < m["dynamic_eval_loss_initial"]
    assert m["future_cd"] < m["baseline_future_cd"], (m["future_cd"], m["baseline_future_cd_by_variant"])
    for key in ("fit_psnr", "fit_ssim", "fit_cd", "fit_emd", "future_psnr", "future_ssim", "future_emd"):
        assert np.isfinite(m[key]), key


def test_run_folder_holds_the_record(tiny_run):
    _, out = tiny_run
    d = out.run_dir
    metrics = json.loads((d / "metrics.json").read_text())
    assert metrics["future_cd"] == out.metrics["future_cd"]
    assert (d / "config.yaml").exists()
    for name in ("side_by_side.mp4", "future.mp4", "losses.png", "stiffness.png", "ply/centres_000.ply", "ply/anchors_000.ply"):
        assert (d / "report" / name).stat().st_size > 0, name
    assert (d / "asset" / "asset.json").exists()


def test_rerun_skips_and_corruption_is_redone(tiny_run):
    cfg, out = tiny_run
    again = run_pipeline(cfg, progress=False)
    assert set(again.metrics["stages_skipped"]) == set(STAGES)
    assert again.metrics["future_cd"] == out.metrics["future_cd"]
    params = out.run_dir / "dynamics" / "params.npz"
    params.write_bytes(params.read_bytes()[:-10])  # truncated: a partial write
    redo = run_pipeline(cfg, progress=False)
    skipped = set(redo.metrics["stages_skipped"])
    assert {"static", "anchors", "refine", "velocity"} <= skipped
    assert "dynamics" not in skipped
    assert redo.metrics["future_cd"] == pytest.approx(out.metrics["future_cd"], rel=1e-3)
