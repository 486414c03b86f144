"""The forecast of several runs of one sequence (sgdr.posterior.ensemble, forecast.ensemble_ball)."""

import json

import numpy as np
import pytest

from sgdr.posterior.forecast import ball_radius, calibrate_growth, coverage, ensemble_ball, mixture_radius


def _case(offset: float, n_draws: int = 8, t: int = 20, n_fit: int = 10, seed: int = 0) -> dict:
    """A run whose draws stand `offset` away along x after the fit frames, tightly; the truth at 0."""
    rng = np.random.default_rng(seed)
    draws = rng.normal(0, 0.002, (n_draws, t, 3))
    draws[:, n_fit:, 0] += offset
    return {"draws": draws, "centre": np.median(draws, axis=0), "truth": np.zeros((t, 3)),
            "sigma_fit": np.full(n_fit, 0.001), "fps": 24.0, "size": 0.5}  # fmt: skip


def test_two_runs_on_either_side_of_the_truth_cover_it_together_and_neither_alone():
    a, b = _case(+0.05, seed=1), _case(-0.05, seed=2)
    assert coverage(a, 0.0) == 0.0 and coverage(b, 0.0) == 0.0
    ens = ensemble_ball([a, b])
    assert ens["truth_inside_future"] == 1.0 and ens["member_centres"].shape == (2, 20, 3)
    assert np.allclose(ens["radius"][10:], 0.05, atol=0.006)  # the mixture reaches both runs
    assert coverage({"members": [a, b]}, 0.0) == 1.0
    # the ensemble's own calibration: γ = 0 suffices, as it does not for either run alone
    assert calibrate_growth([{"members": [a, b]}]) == 0.0 and calibrate_growth([a]) > 0.0


def test_every_run_weighs_the_same_whatever_its_number_of_draws():
    """A run with 2 draws against one with 40: its predictive still holds half the mixture, so the
    90% radius reaches it (with weights by draws it would be the 5% tail, inside the 90% ball)."""
    few, many = _case(+0.05, n_draws=2, seed=3), _case(0.0, n_draws=40, seed=4)
    centre = np.zeros((20, 3))
    members = [(few["draws"], np.full(20, 0.001)), (many["draws"], np.full(20, 0.001))]
    r = mixture_radius(members, centre, 0.9)
    assert np.all(r[10:] > 0.045)
    pooled = np.concatenate([few["draws"], many["draws"]])
    assert np.all(ball_radius(pooled, centre, np.full(20, 0.001), 0.9)[10:] < 0.01)


def test_one_member_is_the_runs_own_ball():
    """`ball_radius` is the one-member mixture: the same numbers as before the ensembles (seeded;
    compared with a tolerance, not bit for bit)."""
    c = _case(0.02, seed=5)
    sigma = np.linspace(0.001, 0.01, 20)
    rng = np.random.default_rng(0)
    noise = rng.standard_normal((8, 64, 20, 3)) * sigma[None, None, :, None]
    old = np.quantile(np.linalg.norm(c["draws"][:, None] + noise - c["centre"][None, None], axis=-1).reshape(-1, 20),
                      0.9, axis=0)  # fmt: skip
    np.testing.assert_allclose(ball_radius(c["draws"], c["centre"], sigma, 0.9), old, rtol=1e-9, atol=1e-12)


def _run(root, name, digest, case=None):
    run = root / name
    (run / "posterior").mkdir(parents=True)
    (run / "RUN.json").write_text(json.dumps({"sequence": "data/x", "digest": digest}))
    if case is not None:
        ball = {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in case.items()}
        record = {"converged": digest == "d1", "predictive": {"com_ball": ball}}
        (run / "posterior" / "posterior.json").write_text(json.dumps(record))
    return run


def test_the_ensemble_combines_finished_posteriors_of_one_sequence(tmp_path):
    from omegaconf import OmegaConf

    from sgdr.config import compose
    from sgdr.posterior.ensemble import run_ensemble

    a = _run(tmp_path, "a", "d1", _case(+0.05, seed=1))
    b = _run(tmp_path, "b", "d1", _case(-0.05, seed=2))
    cfg = OmegaConf.to_object(compose(["preset=tiny", f"posterior.run={a}", f"posterior.ensemble=[{b}]"]))
    rec = run_ensemble(cfg)
    assert rec["runs"] == [str(a), str(b)] and rec["truth_inside_future"] == 1.0
    assert rec["converged"] == [True, True] and "2 of their posteriors converged" in rec["headline"]
    out = a / "posterior_ensemble"
    written = json.loads((out / "ensemble.json").read_text())
    assert written["truth_inside_future"] == 1.0 and len(written["radius"]) == 20
    assert (out / "ensemble.png").stat().st_size > 0 and "Ensemble of 2 runs" in rec["headline"]
    # a run without its posterior: the error names the file and the command that makes it
    c = _run(tmp_path, "c", "d1")
    cfg.posterior.ensemble = [str(c)]
    with pytest.raises(FileNotFoundError, match="experiments/posterior.py posterior.run="):
        run_ensemble(cfg)
    # a run of another sequence: refused before any posterior is read
    d = _run(tmp_path, "d", "d2", _case(0.0))
    cfg.posterior.ensemble = [str(d)]
    with pytest.raises(ValueError, match="another sequence"):
        run_ensemble(cfg)
