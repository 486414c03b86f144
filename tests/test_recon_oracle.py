"""The oracle fit (`evaluation.studies.oracle`) on tracks the spring-mass simulator made itself: it must
find the stiffness that made them and predict their future better than any physics-free
continuation (a model fitted to its own class has no excuse)."""

import numpy as np
import pytest
from omegaconf import OmegaConf

from evaluation.studies.config import CHECKS, OracleConfig, StudyConfig, validate
from evaluation.studies.oracle import fit_tracks, offset_scan, score_tracks, tracked_anchor_index
from sgdr.asset.predict import physical_params
from sgdr.checks import ConfigError
from sgdr.identify.config import ReconConfig
from sgdr.physics import Ground, PhysicsConfig, SimState, build_spring_model, rollout


def _twin_tracks(cfg, n_frames=10, fps=24.0):
    rng = np.random.default_rng(3)
    u = rng.uniform(-1, 1, (400, 3))
    x_rest = 0.1 * u[np.linalg.norm(u, axis=1) < 1][:48] + [
        0.5,
        0.5,
        0.24,
    ]  # a ball of radius 0.1, 4 cm above the ground
    model = build_spring_model(x_rest, 8, cfg)
    truth = {
        "log10_k": 2.6,
        "kappa": 0.0,
        "friction": 0.4,
        "restitution": 0.3,
        "v0": (0.4, 0.0, 0.0),
        "gravity": (0.0, 0.0, -9.8),
    }
    params = physical_params(model, cfg, truth)
    ground = Ground([0.0, 0.0, 0.1], [0.0, 0.0, 1.0])
    states = rollout(
        model, params, SimState.at_rest(model, params.v0), ground, n_frames, 1 / fps, cfg, grad_mode="truncated"
    )
    return np.stack([s.x.numpy().T for s in states]).astype(np.float64), ground, truth


def test_oracle_recovers_the_stiffness_of_its_own_twin():
    cfg = PhysicsConfig(contact="coulomb", n_substeps=60, n_c=4, friction_init=0.4, restitution_init=0.3)
    tracks, ground, truth = _twin_tracks(cfg)
    recon = ReconConfig(lr_log10_k=0.05, lr_kappa=0.0, lr_friction=0.0, lr_restitution=0.0)
    values, losses, simulated = fit_tracks(
        tracks, ground, truth["gravity"], truth["v0"], 24.0, 7, cfg, 8, iterations=25, recon_cfg=recon, log10_k_init=2.3
    )
    # measured 1.6e-4 -> 1.2e-5 before the soft-vector exponent matched the official code, 1.8e-4 ->
    # 1.8e-5 after it (the twin itself changed); the stiffness check below is the one that matters
    assert losses[-1] < 0.15 * losses[0]
    assert abs(np.mean(values["log10_k"]) - truth["log10_k"]) < 0.1
    error, cd, base_cd, base_error = score_tracks(simulated, tracks, 7, 24.0, truth["gravity"], ground)
    assert error.shape == (10,) and set(base_cd) == {"still", "constant_velocity", "ballistic"}
    # measured: 0.027 vs 0.048 (held still). Per-anchor k spread 0.18 around the truth: the
    # mean is identified, the field only loosely (a 4 cm drop excites little of it)
    assert np.mean(error[7:]) < 0.75 * min(np.mean(v) for v in base_error.values())
    # the offset scan's zero offset is the fitted model's own rollout; a large shift fits worse
    rows, ensemble = offset_scan(
        tracks, ground, truth["gravity"], truth["v0"], 24.0, 7, cfg, 8, values, [0.0, 0.4], ensemble_tol=1.25
    )
    assert abs(rows[0]["future_track_error"] - np.mean(error[7:])) < 1e-6
    assert rows[1]["fit_track_error"] > 1.25 * rows[0]["fit_track_error"] and ensemble["offsets"] == [0.0]
    assert abs(ensemble["future_track_error"] - rows[0]["future_track_error"]) < 1e-6


def test_tracked_anchors_are_particles():
    rng = np.random.default_rng(0)
    p = rng.uniform(0, 1, (500, 3))
    idx = tracked_anchor_index(p, 32, seed=0)
    assert idx.shape == (32,) and len(set(idx.tolist())) == 32


def test_the_oracle_config_is_checked_like_sgdrs():
    """The study's schema (sgdr's plus `oracle`): every oracle field but the bools has a check,
    sgdr's checks still apply, and a bad value fails naming its key."""
    fields = {n for n, v in vars(OracleConfig()).items() if not isinstance(v, bool)}
    assert set(CHECKS) == fields
    validate(StudyConfig())
    bad = OmegaConf.to_object(OmegaConf.merge(OmegaConf.structured(StudyConfig), {"oracle": {"iterations": 0}}))
    with pytest.raises(ConfigError, match="oracle.iterations=0"):
        validate(bad)
    bad.oracle.iterations, bad.anchors.n_k = 1, 0
    with pytest.raises(ConfigError, match="anchors.n_k"):
        validate(bad)
