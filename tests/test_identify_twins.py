"""Identification on twins (sgdr.synth.twin): sequences simulated by an asset's own
spring-mass model with a known truth, reconstructed by the whole pipeline at tiny.

The twin's stiffness field is the asset's + a known shift, so its level (mean log10 k_i) is
known. Reconstructing it re-fits everything from the twin's images (static Gaussians, anchors,
v0), so the reconstruction's model is not the twin's: the level is recovered up to what those
stages and the tiny search (6 x 3 candidates over 4 parameters) leave.
"""

from pathlib import Path

import numpy as np
import pytest
from omegaconf import OmegaConf

from sgdr.config import compose

# Measured (tiny torus asset, level 2.79; `recon.contact_margin=0`), identified - truth level for
# shifts -0.6 / -0.3 / +0.4: -0.115 / +0.044 / +0.096 decades; at +0.8 (level 3.59, near the
# search's stability cap 3.83) -0.35: a stiff tiny torus barely deforms at 32 px, so the test
# uses a soft twin, 0.8 decades below the start (physics.log10_k_init = 3.0).
SHIFT = -0.6
TOLERANCE = 0.2  # decades (a factor 1.6 in k): the measured errors above, plus room for another CPU's rounding


@pytest.fixture(scope="module")
def twin_run(tmp_path_factory):
    """(the asset's mean log10 k, the twin reconstruction's pipeline output)."""
    import sgdr.backend
    from sgdr.asset.store import load_asset
    from sgdr.pipeline.run import run_pipeline
    from sgdr.synth.twin import twin_sequence

    root = tmp_path_factory.mktemp("twins")
    overrides = [
        "preset=tiny",
        f"data_dir={root / 'data'}",
        f"recon.output_dir={root / 'outputs'}",
        f"tracking.uri=sqlite:///{root / 'mlflow.db'}",
        "recon.eval_emd=false",
        "recon.render_videos=false",
        "recon.write_plys=false",
    ]
    cfg = OmegaConf.to_object(compose(overrides))
    sgdr.backend.init(cfg.backend, cfg.threads or None)
    out = run_pipeline(cfg, progress=False)
    asset_level = float(np.mean(load_asset(out.run_dir / "asset").values["log10_k"]))
    twin = twin_sequence(out.run_dir / "asset", root / "twin", {"log10_k_shift": SHIFT})
    twin_cfg = OmegaConf.to_object(compose([*overrides, f"sequence={Path(twin)}", "recon.contact_margin=0"]))
    return asset_level, cfg.physics.log10_k_init, run_pipeline(twin_cfg, progress=False)


@pytest.mark.slow
def test_a_twins_stiffness_level_is_recovered_by_the_pipeline(twin_run):
    from sgdr.asset.store import load_asset

    asset_level, start, out = twin_run
    truth = asset_level + SHIFT
    found = load_asset(out.run_dir / "asset").values["log10_k"]
    assert abs(found.mean() - truth) < TOLERANCE, (found.mean(), truth)
    assert abs(found.mean() - truth) < 0.25 * abs(start - truth), (found.mean(), truth, start)
    assert out.metrics["dynamic_eval_loss_final"] <= out.metrics["dynamic_eval_loss_initial"]
