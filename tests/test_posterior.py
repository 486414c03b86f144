"""The posterior (issue 14): the silhouette likelihood, the convergence verdict, and a tiny
posterior end to end on a twin whose truth is in the model class.

The end-to-end test builds a tiny run once (as tests/test_pipeline_e2e.py does), renders a twin
of its asset with a known stiffness shift, and samples 4 short ensembles over (log10 k shift,
friction): far too short to converge, so the report must say 'Not converged' first, while the
diagnostics are all computed and the twin's true shift lies inside the 5-95% interval.
"""

import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from omegaconf import OmegaConf

from sgdr.config import compose, validate
from sgdr.posterior.sample import diagnose, headline

TRUE_SHIFT = 0.2


def _post_cfg(*overrides):
    return OmegaConf.to_object(compose(["preset=tiny", *overrides])).posterior


def _ar1_chains(n_ens, n_steps, n_walk, dim, rho, seed=0, offsets=None):
    """Independent AR(1) chains [E, steps, W, D] with stationary N(offset, 1) and lag-1 correlation rho."""
    rng = np.random.default_rng(seed)
    x = np.zeros((n_ens, n_steps, n_walk, dim))
    x[:, 0] = rng.standard_normal((n_ens, n_walk, dim))
    for t in range(1, n_steps):
        x[:, t] = rho * x[:, t - 1] + math.sqrt(1 - rho**2) * rng.standard_normal((n_ens, n_walk, dim))
    if offsets is not None:
        x += np.asarray(offsets, float)[:, None, None, None]
    return x


def test_verdict_converged_on_well_mixed_chains():
    cfg = _post_cfg()
    chains = _ar1_chains(4, 2000, 8, 2, rho=0.5)  # τ = (1 + ρ) / (1 - ρ) = 3
    d = diagnose(chains, ["a", "b"], cfg, np.full((4, 8), 0.35))
    assert d["converged"], d["failed"]
    assert all(2.0 < t < 4.5 for row in d["tau"] for t in row), d["tau"]
    assert d["burn_in"] == math.ceil(2 * d["tau_max"]) and d["thin"] >= 1
    assert all(r < 1.01 for r in d["rhat"].values()) and all(e > 400 for e in d["ess_bulk"].values())
    assert abs(d["median"]["a"]) < 0.1 and d["q05"]["a"] == pytest.approx(-1.645, abs=0.15)
    assert headline(d).startswith("Converged")


def test_verdict_names_each_failed_criterion():
    cfg = _post_cfg()
    # ensembles stuck in different places: R-hat across ensembles catches what no single one shows
    apart = _ar1_chains(4, 2000, 8, 1, rho=0.5, offsets=[0.0, 0.0, 0.0, 3.0])
    d = diagnose(apart, ["a"], cfg, np.full((4, 8), 0.35))
    assert not d["converged"] and d["rhat"]["a"] > 1.1
    assert any("R-hat" in f for f in d["failed"])
    assert headline(d).startswith("Not converged")
    # short chains: < 50 τ, and a bad acceptance fraction in one ensemble
    short = _ar1_chains(4, 60, 8, 1, rho=0.8)
    acc = np.full((4, 8), 0.35)
    acc[2] = 0.02
    d = diagnose(short, ["a"], cfg, acc)
    assert any("τ long" in f for f in d["failed"]), d["failed"]
    assert any("acceptance" in f and "ensemble 3" in f for f in d["failed"]), d["failed"]
    # a walker that never moved
    stuck = _ar1_chains(4, 2000, 8, 1, rho=0.5)
    stuck[1, :, 3, 0] = 0.7
    d = diagnose(stuck, ["a"], cfg, np.full((4, 8), 0.35))
    assert any("never moved" in f and "ensemble 2" in f for f in d["failed"]), d["failed"]


def test_longer_chains_lengthens_until_the_chains_converge_and_only_when_length_helps():
    """The surrogate's chains are lengthened while only τ, ESS or R-hat fail: each call asks for more
    steps, the AR(1) chains converge at the asked length before the cap, and a failure that length
    does not mend (a bad acceptance fraction) or the cap ends it."""
    from sgdr.posterior.sample import longer_chains

    cfg = _post_cfg()
    acc = np.full((4, 8), 0.35)
    n, lengths = 200, []
    while True:
        d = diagnose(_ar1_chains(4, n, 8, 2, rho=0.95, seed=len(lengths)), ["a", "b"], cfg, acc)  # τ = 39
        steps = longer_chains(d, cfg, cap=40000)
        if steps is None:
            break
        assert steps >= 1.5 * n and steps <= 40000
        lengths.append(n := steps)
    assert d["converged"], (lengths, d["failed"])
    assert 50 * 39 * 0.8 < lengths[-1] < 40000 and len(lengths) <= 4, lengths
    short = _ar1_chains(4, 200, 8, 1, rho=0.95)
    d = diagnose(short, ["a"], cfg, acc)  # τ estimated short on short chains: the first ask is short too
    assert longer_chains(d, cfg, cap=40000) == math.ceil(1.2 * 50 * d["tau_max"]) > 300
    assert longer_chains(diagnose(short, ["a"], cfg, acc), cfg, cap=250) == 250
    assert longer_chains(diagnose(short, ["a"], cfg, acc), cfg, cap=200) is None
    bad = acc.copy()
    bad[1] = 0.02
    assert longer_chains(diagnose(short, ["a"], cfg, bad), cfg, cap=40000) is None


def test_de_moves_sample_a_correlated_gaussian_and_converge():
    """posterior.moves=de on a known target inside a box prior: the verdict's criteria hold and the
    5-95% interval is the Gaussian's."""
    from sgdr.posterior.sample import Problem, run_ensembles

    cov = np.array([[1.0, 0.9], [0.9, 1.0]])
    prec = np.linalg.inv(cov)
    problem = Problem(["a", "b"], np.array([-8.0, -8.0]), np.array([8.0, 8.0]), np.array([0.5, -0.5]))

    def log_prob(thetas):
        lp = -0.5 * np.einsum("sd,de,se->s", thetas, prec, thetas)
        return np.where(problem.inside(thetas), lp, -np.inf)

    chains, _, acc = run_ensembles(log_prob, problem, 12, 1500, 4, init_ball=0.1, seed=3, move="de")
    d = diagnose(chains, problem.names, _post_cfg(), acc)
    assert d["converged"], d["failed"]
    for n in problem.names:
        assert d["q05"][n] == pytest.approx(-1.645, abs=0.2) and d["q95"][n] == pytest.approx(1.645, abs=0.2)


def _two_modes(problem, weight=0.3):
    """log density of weight N((-3, -3), 0.3^2 I) + (1 - weight) N((3, 3), 0.3^2 I), -inf outside the box."""
    from scipy.special import logsumexp

    def log_prob(thetas):
        a = np.log(weight) - 0.5 * np.sum(((thetas + 3.0) / 0.3) ** 2, axis=1)
        b = np.log(1 - weight) - 0.5 * np.sum(((thetas - 3.0) / 0.3) ** 2, axis=1)
        return np.where(problem.inside(thetas), logsumexp(np.stack([a, b]), axis=0), -np.inf)

    return log_prob


def test_independence_proposals_cross_between_modes_with_their_weights():
    """posterior.surrogate.independence on two modes 20 standard deviations apart: DE alone crosses
    rarely (most of its between-mode proposals land in the gap), its ensembles disagree on the
    modes' weights and the verdict says so; after a pilot, the mixture's independence proposals
    carry walkers across, every ensemble holds the true weights (0.3 / 0.7) and the criteria hold."""
    from sgdr.posterior.sample import Problem, run_ensembles

    problem = Problem(["a", "b"], np.array([-8.0, -8.0]), np.array([8.0, 8.0]), np.array([0.0, 0.0]))
    log_prob = _two_modes(problem)

    def start(n, rng):  # half the walkers in each mode: the weights must be found, not given
        centres = np.where(np.arange(n)[:, None] % 2 == 0, -3.0, 3.0)
        return centres + 0.3 * rng.standard_normal((n, 2))

    kw = {"n_walkers": 12, "n_steps": 1500, "n_ensembles": 4, "init_ball": 0.1, "seed": 1, "move": "de", "start": start}
    chains, _, acc = run_ensembles(log_prob, problem, **kw, independence=0.5, pilot_steps=500)
    low_mode = (chains[:, 750:, :, 0] < 0).mean(axis=(1, 2))
    assert np.all(np.abs(low_mode - 0.3) < 0.08), low_mode
    d = diagnose(chains, problem.names, _post_cfg(), acc)
    assert d["converged"], d["failed"]
    assert np.all(acc.mean(axis=1) > 0.2), acc.mean(axis=1)

    chains, _, acc = run_ensembles(log_prob, problem, **kw)
    d = diagnose(chains, problem.names, _post_cfg(), acc)
    assert not d["converged"], low_mode
    assert np.ptp((chains[:, 750:, :, 0] < 0).mean(axis=(1, 2))) > 2 * np.ptp(low_mode)


def test_mixture_move_is_an_exact_independence_sampler():
    """MixtureMove's Metropolis-Hastings ratio: when the target is the (inflated) mixture itself every
    proposal is accepted; its density integrates to 1 over a grid."""
    import emcee
    from sklearn.mixture import GaussianMixture

    from sgdr.posterior.sample import MixtureMove, fit_mixture

    rng = np.random.default_rng(0)
    pilot = np.concatenate([rng.normal(-2, 0.5, (400, 2)), rng.normal([2, 1], [0.3, 0.8], (600, 2))])
    mixture = fit_mixture(pilot, seed=0)
    assert isinstance(mixture, GaussianMixture) and mixture.n_components == 2
    move = MixtureMove(mixture, inflate=1.5)
    g = np.linspace(-8, 8, 321)
    xx, yy = np.meshgrid(g, g)
    mass = np.exp(move.log_density(np.column_stack([xx.ravel(), yy.ravel()]))).sum() * (g[1] - g[0]) ** 2
    assert mass == pytest.approx(1.0, abs=1e-3)
    sampler = emcee.EnsembleSampler(8, 2, move.log_density, vectorize=True, moves=move.move)
    sampler.run_mcmc(move.draw(8, np.random.RandomState(1)), 200)
    assert np.all(sampler.acceptance_fraction > 0.999)


def test_the_defensive_component_lets_walkers_leave_a_mode_the_mixture_missed():
    """A mixture fitted on one mode only (the pilot never saw the other, 5% of the mass): a walker
    started in the missed mode never leaves it under the mixture's independence proposals (their
    density there is ~0), and with the defensive wide component it leaves, and the chains hold the
    missed mode at about its weight."""
    import emcee

    from sgdr.posterior.sample import MixtureMove, fit_mixture

    def target(x):
        a = -0.5 * np.sum((x - np.array([-3.0, 0.0])) ** 2, axis=1) / 0.25
        b = -0.5 * np.sum((x - np.array([3.0, 0.0])) ** 2, axis=1) / 0.25
        return np.logaddexp(np.log(0.95) + a, np.log(0.05) + b)

    rng = np.random.default_rng(0)
    mixture = fit_mixture(rng.normal([-3.0, 0.0], 0.5, (2000, 2)), seed=0)
    p0 = np.vstack([rng.normal([-3.0, 0.0], 0.5, (7, 2)), [[3.0, 0.0]]])
    for defensive, check in ((None, "stuck"), ((0.1, np.zeros(2), 16.0 * np.eye(2)), "mixes")):
        move = MixtureMove(mixture, inflate=1.5, defensive=defensive)
        sampler = emcee.EnsembleSampler(8, 2, target, vectorize=True, moves=move.move)
        sampler.random_state = np.random.RandomState(3).get_state()
        sampler.run_mcmc(p0, 6000)
        high = sampler.get_chain()[..., 0] > 0  # [steps, walkers]
        if check == "stuck":
            assert high[:, -1].all() and not high[:, :-1].any()
        else:
            assert not high[-3000:, -1].all()
            assert high[1000:].mean() == pytest.approx(0.05, abs=0.025)


def test_logit_space_samples_the_box_prior_itself():
    """posterior.space=logit on a flat likelihood: the chains (returned in θ) are the uniform prior,
    which needs the Jacobian (without it the walkers drift to the edges)."""
    from sgdr.posterior.sample import LogitSpace, Problem, run_ensembles

    problem = Problem(["a", "b"], np.array([0.0, -2.0]), np.array([1.0, 2.0]), np.array([0.0, 1.0]))
    flat = lambda thetas: np.where(problem.inside(np.atleast_2d(thetas)), 0.0, -np.inf)  # noqa: E731
    chains, lps, acc = run_ensembles(flat, problem, 12, 1500, 4, init_ball=0.05, seed=5, move="de", space="logit")
    assert np.all(problem.inside(chains.reshape(-1, 2))) and np.all(lps == 0.0)
    d = diagnose(chains, problem.names, _post_cfg(), acc)
    assert d["converged"], d["failed"]
    assert d["q05"]["a"] == pytest.approx(0.05, abs=0.03) and d["q95"]["a"] == pytest.approx(0.95, abs=0.03)
    assert d["q05"]["b"] == pytest.approx(-1.8, abs=0.12) and d["median"]["b"] == pytest.approx(0.0, abs=0.12)
    space = LogitSpace(problem)
    theta = np.array([[0.3, -1.0], [0.9, 1.5]])
    np.testing.assert_allclose(space.to_theta(space.to_z(theta)), theta)


def test_an_upscaled_camera_sees_the_same_view_finer():
    from sgdr.cameras import Camera
    from sgdr.observe.images import downscaled, upscaled

    cam = Camera.look_at([2.0, 0.5, 1.0], [0.0, 0.0, 0.3], [0, 0, 1], 40.0, 32, 24, "v")
    big = upscaled(cam, 3)
    assert (big.width, big.height) == (96, 72) and big.name == "v"
    pts = np.array([[0.0, 0.0, 0.3], [0.1, -0.2, 0.5]])
    uv, z = cam.project(pts)
    uv3, z3 = big.project(pts)
    np.testing.assert_allclose(uv3, 3 * uv, atol=1e-9)  # pixel coordinates scale, depth does not
    np.testing.assert_allclose(z3, z)
    np.testing.assert_allclose(downscaled(big, 3).K, cam.K)
    with pytest.raises(ValueError, match="image_scale"):
        upscaled(cam, 0)


def test_silhouette_discrepancy_on_a_synthetic_view():
    """Points filling a square silhouette score ~0; points shifted right score the outside term
    (their squared distance to the square) plus the uncovered strip; a cluster in one corner
    scores 0 outside and a large coverage term."""
    from scipy.ndimage import distance_transform_edt

    from sgdr.cameras import Camera
    from sgdr.observe.silhouette import Observation, discrepancy

    cam = Camera.look_at([0, 0, 5.0], [0, 0, 0], [0, 1, 0], 40.0, 64, 64)
    # the silhouette: the projection of the square [-0.5, 0.5]^2 at z = 0
    xy = np.stack(np.meshgrid(np.linspace(-0.5, 0.5, 41), np.linspace(-0.5, 0.5, 41)), -1).reshape(-1, 2)
    square = np.concatenate([xy, np.zeros((xy.shape[0], 1))], axis=1)
    uv, _ = cam.project(square)
    u0, v0 = np.floor(uv.min(0)).astype(int)
    u1, v1 = np.ceil(uv.max(0)).astype(int)
    mask = np.zeros((64, 64), bool)
    mask[v0:v1, u0:u1] = True
    rr, cc = np.nonzero(mask)
    obs = Observation(
        [cam], np.array([1]), distance_transform_edt(~mask)[None, None], [[np.stack([cc + 0.5, rr + 0.5], 1)]]
    )
    px_per_unit = (u1 - u0) / 1.0
    shift = np.array([0.3, 0.0, 0.0])
    corner = square[(square[:, 0] < -0.4) & (square[:, 1] < -0.4)]
    d = discrepancy(obs, np.stack([square, square + shift, np.resize(corner, square.shape)])[:, None])
    assert d.shape == (3, 1, 1)
    assert d[0, 0, 0] < 1.0  # filled: within the pixel grid's quantisation
    s_px = 0.3 * px_per_unit
    # a third of the points lie outside by up to s_px: mean d² ≈ (1/3)(s²/3) = s²/9; the strip of
    # width s_px left uncovered: mean over the square of d² ≈ (0.3)(s²/3) = s²/10
    assert d[1, 0, 0] == pytest.approx(s_px**2 / 9 + s_px**2 / 10, rel=0.25)
    assert d[2, 0, 0] > d[1, 0, 0] and d[2, 0, 0] > 20 * d[0, 0, 0]


def test_config_rules_name_the_key():
    from sgdr.checks import ConfigError

    with pytest.raises(ConfigError, match=r"posterior\.priors\.friction"):
        validate(OmegaConf.to_object(compose(["preset=tiny", "posterior.priors.friction=[0.5,0.2]"])))
    with pytest.raises(ConfigError, match=r"posterior\.n_walkers"):
        validate(OmegaConf.to_object(compose(["preset=tiny", "posterior.n_walkers=6"])))  # 4 parameters need > 8
    with pytest.raises(ConfigError, match=r"posterior\.parameters"):
        validate(OmegaConf.to_object(compose(["preset=tiny", "posterior.parameters=[stiffness]"])))
    with pytest.raises(ConfigError, match=r"posterior\.surrogate\.edge_points.*0 \(no edge probes\) or >= 2"):
        validate(OmegaConf.to_object(compose(["preset=tiny", "posterior.surrogate.edge_points=1"])))


# ---------------------------------------------------------------------------- on a tiny run


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    """(overrides, run folder, twin folder): a tiny reconstruction and a twin of its asset."""
    import sgdr.backend
    from sgdr.pipeline.run import run_pipeline
    from sgdr.synth.twin import twin_sequence

    root = tmp_path_factory.mktemp("posterior")
    overrides = [
        "preset=tiny",
        f"data_dir={root / 'data'}",
        f"recon.output_dir={root / 'outputs'}",
        f"tracking.uri=sqlite:///{root / 'mlflow.db'}",
    ]
    cfg = OmegaConf.to_object(compose(overrides))
    sgdr.backend.init(cfg.backend, cfg.threads or None)
    out = run_pipeline(cfg, progress=False)
    twin = twin_sequence(out.run_dir / "asset", root / "twin", {"log10_k_shift": TRUE_SHIFT})
    return overrides, out.run_dir, Path(twin)


slow = pytest.mark.slow  # a tiny reconstruction and rollouts


@slow
def test_likelihood_prefers_the_twins_truth(tiny):
    from sgdr.asset.store import load_asset
    from sgdr.data import load_sequence
    from sgdr.observe.silhouette import CentreMap, discrepancy, observation
    from sgdr.physics import Ground
    from sgdr.posterior.likelihood import SilhouetteLikelihood
    from sgdr.posterior.rollouts import loop_rollout

    _, run_dir, twin = tiny
    asset = load_asset(run_dir / "asset")
    seq = load_sequence(twin)
    model, _ = asset.build()
    ground = Ground(asset.ground_point, asset.ground_normal)
    obs = observation(seq, range(len(seq.cameras)), np.arange(1, asset.n_fit), 64)
    shifts = np.array([TRUE_SHIFT, TRUE_SHIFT - 1.0, 1.0])
    pos, stable = loop_rollout(
        model,
        asset.values,
        {"log10_k_shift": shifts},
        ground,
        asset.n_fit,
        1 / asset.fps,
        asset.n_substeps,
        asset.physics,
    )
    assert stable.all()
    # the truth is in the model class: the rollout contract + NumPy binding reproduce the twin's centres
    full = CentreMap(asset, 0)(pos[0])
    for f in range(asset.n_fit):
        np.testing.assert_allclose(full[f], seq.gt_particles(f), atol=1e-5)
    d = discrepancy(obs, CentreMap(asset, 128)(pos[:, obs.frames]))
    lik = SilhouetteLikelihood.at_map(obs, d[0], 0.5, 1.0)
    ll = lik.log_likelihood(d)
    assert ll[0] > ll[1] and ll[0] > ll[2], ll
    assert ll[0] == pytest.approx(-lik.n_terms / 2, rel=1e-9)  # σ² from this residual: log L = -n/2
    # an unstable rollout is -inf, not an error
    assert lik.log_likelihood(np.full((1, *d.shape[1:]), np.nan))[0] == -np.inf


@slow
def test_unstable_sample_is_flagged(tiny):
    from sgdr.asset.store import load_asset
    from sgdr.physics import Ground
    from sgdr.posterior.rollouts import loop_rollout

    _, run_dir, _ = tiny
    asset = load_asset(run_dir / "asset")
    model, _ = asset.build()
    physics = replace(asset.physics, retry_on_nan=False)  # no retries: 10^4 x stiffer is unstable at n_t
    pos, stable = loop_rollout(
        model, asset.values, {"log10_k_shift": np.array([0.0, 4.0])}, Ground(asset.ground_point, asset.ground_normal),
        3, 1 / asset.fps, asset.n_substeps, physics,
    )  # fmt: skip
    assert stable.tolist() == [True, False]
    assert np.isfinite(pos[0]).all() and np.isnan(pos[1]).all()


@slow
def test_tiny_posterior_on_a_twin(tiny):
    from sgdr.posterior.run import run_posterior

    overrides, run_dir, twin = tiny
    cfg = OmegaConf.to_object(
        compose(
            [
                *overrides,
                f"posterior.run={run_dir}",
                f"posterior.sequence={twin}",
                "posterior.likelihood=silhouette",
                "posterior.sampler=emcee",
                "posterior.parameters=[log10_k_shift,friction]",
                "posterior.n_walkers=6",
                "posterior.n_steps=24",
                "posterior.init_ball=0.2",
                "posterior.n_predictive=4",
            ]
        )
    )
    validate(cfg)
    record = run_posterior(cfg)
    out = run_dir / "posterior"

    def refuse(name):
        raise ValueError(f"{name} is not JSON")

    on_disk = json.loads((out / "posterior.json").read_text(), parse_constant=refuse)
    assert on_disk["headline"] == record["headline"]
    d = on_disk["diagnostics"]
    names = ["log10_k_shift", "friction"]
    assert d["names"] == names and d["n_ensembles"] == 4
    assert all(t is not None and t > 0 for row in d["tau"] for t in row), d["tau"]
    for n in names:
        assert np.isfinite(d["rhat"][n]) and d["rhat"][n] > 0.9
        assert np.isfinite(d["ess_bulk"][n]) and d["ess_bulk"][n] > 0 and np.isfinite(d["ess_tail"][n])
    assert all(0 < a < 1 for a in d["acceptance"])
    # 24 steps cannot be 50 τ: the verdict says so first, in the json and in the report
    assert not on_disk["converged"] and on_disk["headline"].startswith("Not converged")
    # the twin's truth: the shift given, the friction the asset's own
    assert on_disk["truth"]["log10_k_shift"] == pytest.approx(TRUE_SHIFT)
    assert d["q05"]["log10_k_shift"] <= TRUE_SHIFT <= d["q95"]["log10_k_shift"], (d["q05"], d["q95"])
    assert on_disk["truth_inside_5_95"]["log10_k_shift"] is True
    # the posterior predictive over fit and future frames, with the twin's truth
    pred = on_disk["predictive"]
    assert pred["frames"] == 12 and len(pred["com_height"]["q05"]) == 12
    assert len(pred["truth_com_height"]) == 12 and len(pred["median_cd_per_frame"]) == 12
    assert all(np.isfinite(pred["median_cd_per_frame"]))
    # the point estimate and the physics-free "still" prediction, scored the same way
    assert len(pred["map_cd_per_frame"]) == 12 and len(pred["still_cd_per_future_frame"]) == 12 - 8
    assert pred["map_cd_per_frame"][0] == pytest.approx(pred["median_cd_per_frame"][0], rel=1e-6)  # the rest state
    assert pred["median_future_cd"] < pred["still_future_cd"], (pred["median_future_cd"], pred["still_future_cd"])
    assert 0.0 <= pred["com_height_disp_truth_inside_future"] <= 1.0
    with np.load(out / "samples.npz") as z:
        assert z["chains"].shape == (4, 24, 6, 2) and z["kept"].shape[1] == 2
    for name in ("corner.png", "traces.png", "predictive.png", "ensemble.mp4"):
        assert (out / name).stat().st_size > 1000, name
    page = (run_dir / "report" / "report.html").read_text()
    section = page[page.index('<section id="posterior">') :]
    assert section.index("Not converged") < section.index("<table>")
    assert "5%" in section and "R-hat" in section and "uniform" in section and "<video" in section
    assert on_disk["sampler"] == {"kind": "emcee", "moves": "de", "space": "logit", "rollout": "batched",
                                  "surrogate": None, "design_search": None}  # fmt: skip
    assert "differential-evolution moves" in section
    # logged into the run's MLflow run
    from mlflow.tracking import MlflowClient

    state = json.loads((run_dir / "mlflow_run.json").read_text())
    assert record["mlflow_run_id"] == state["run_id"]
    run = MlflowClient(tracking_uri=state["tracking_uri"]).get_run(state["run_id"])
    assert run.data.metrics["posterior_converged"] == 0.0
    assert "posterior_rhat_log10_k_shift" in run.data.metrics


@slow
def test_tiny_rendered_posterior_converges_on_a_twin(tiny):
    """The default: the rendered likelihood sampled through the surrogate, started from the run's
    global-stage population. On a twin (truth inside the model class) it converges, the true
    stiffness shift lies in the 90% interval, the profile of log L peaks nearer the truth than the
    identified value, and the report says how the surrogate was checked."""
    from sgdr.posterior.run import run_posterior

    overrides, run_dir, twin = tiny
    out = run_dir / "posterior_rendered"
    cfg = OmegaConf.to_object(
        compose(
            [
                *overrides,
                f"posterior.run={run_dir}",
                f"posterior.sequence={twin}",
                f"posterior.out_dir={out}",
                "posterior.parameters=[log10_k_shift,friction]",
                "posterior.n_predictive=4",
                "posterior.surrogate.edge_points=5",
                "posterior.discrepancy_offset=true",
            ]
        )  # fmt: skip
    )
    validate(cfg)
    assert cfg.posterior.likelihood == "rendered" and cfg.posterior.sampler == "surrogate"
    record = run_posterior(cfg)
    sur = record["sampler"]["surrogate"]
    assert sur["validated"] and sur["rounds"][-1]["inside_95"] >= cfg.posterior.surrogate.inside_min
    from sgdr.posterior.run import PROFILE_SHIFTS

    # every rendered rollout once: the design (the MAP first) and the checks, the stiffness profile
    # (its 0 is the MAP)
    assert record["cost"]["rollouts"] == sur["n_distinct_evaluations"] + len(PROFILE_SHIFTS) - 1
    assert sur["n_distinct_evaluations"] <= sur["n_true_evaluations"]
    assert record["converged"], record["failed"]
    d = record["diagnostics"]
    assert d["q05"]["log10_k_shift"] <= TRUE_SHIFT <= d["q95"]["log10_k_shift"], (d["q05"], d["q95"])
    lk = record["likelihood"]
    assert lk["kind"] == "rendered" and lk["n_views"] == len(json.loads((twin / "sequence.json").read_text())["views"])
    # the scale's reference is the best-fitting design point: on a twin of other parameters, not the
    # identified ones, and nearer the truth
    assert not lk["reference_is_map"]
    # the twin is not the run's sequence: its design came from a global search on the twin's images
    found = record["sampler"]["design_search"]
    assert found is not None and found["n_evaluations"] > 0, found
    kept = json.loads((out / "design_search.json").read_text())  # kept for a rerun on this twin
    assert kept["search"]["best_loss"] == pytest.approx(found["best_loss"])
    # the reference (the best-fitting design point) is the search's: measured 0.24 for the truth's 0.2
    assert abs(lk["reference"]["log10_k_shift"] - TRUE_SHIFT) < 0.12, lk["reference"]
    assert abs(lk["reference"]["log10_k_shift"] - TRUE_SHIFT) < abs(TRUE_SHIFT), lk["reference"]
    assert np.mean(lk["reference_loss_per_frame"]) < np.mean(lk["map_loss_per_frame"])
    prof = lk["profile_log10_k_shift"]
    assert prof["+0.25"] > prof["+0"] and prof["+0.25"] > prof["-0.5"]  # the truth (+0.2) is nearer +0.25
    assert np.all(np.diff(lk["discrepancy_per_frame"]) >= -1e-12)
    ball = record["predictive"]["com_ball"]
    assert len(ball["radius"]) == record["predictive"]["frames"] and ball["truth_inside_future"] is not None
    # posterior.discrepancy_offset: the ball moved by the silhouettes' offset, held after the fit frames
    assert len(ball["offsets"]) == record["predictive"]["n_fit"] and len(ball["offset"]) == 3
    assert ball["sigma_fit"] == [ball["sigma_fit"][0]] * len(ball["sigma_fit"])  # their scatter, every fit frame
    page = (run_dir / "report" / "report.html").read_text()
    assert "held over the future" in page
    assert "Gaussian-process surrogate" in page and "95% interval" in page
    # the edge probes ran once the check passed, and the last round found every edge below the best
    last = sur["rounds"][-1]
    assert last["edges"] > 0 and last["open_edges"] == 0 and "just beyond the 90% intervals" in page
    # the likelihood's profile through the twin's truth (evaluation.studies.likelihood_profile): its
    # loss is lowest there, the twin being the model's own images
    from evaluation.studies.likelihood_profile import centre_of, parse_steps, profile

    names = record["names"]
    centre = centre_of(record, "truth", names, "posterior.json")
    assert centre[names.index("log10_k_shift")] == pytest.approx(TRUE_SHIFT)
    prof = profile(cfg, centre, names, parse_steps("log10_k_shift:-0.2,0.2"))
    moved = [m["loss"] for m in prof["moved"]["log10_k_shift"]]
    assert prof["centre_loss"] < min(moved), prof
    assert np.mean(prof["centre_per_frame"]) == pytest.approx(prof["centre_loss"])  # per fit frame, views averaged
    # the posterior's own log L, rebuilt from its record: the reference scores -n_vf / (2T) (its
    # misfit is the scale; less negative only where the loss floor lifts the scale above it)
    from evaluation.studies.likelihood_profile import log_likelihood_at

    at = log_likelihood_at(cfg, record, ["truth", "likelihood.reference"], "posterior.json")
    n_vf = at["n_view_frames"]
    ref_ll = at["at"]["likelihood.reference"]["log_likelihood"]
    assert -1.02 * n_vf / (2 * record["likelihood"]["temperature"]) <= ref_ll < 0
    assert at["at"]["truth"]["loss"] == pytest.approx(prof["centre_loss"], rel=1e-4)  # the same render
    assert len(prof["moved"]["log10_k_shift"][0]["per_frame"]) == len(prof["centre_per_frame"])
    # on the line from the reference to the truth: its ends are the two points above
    from evaluation.studies.likelihood_profile import log_likelihood_on_line, parse_line

    ends, fractions = parse_line("likelihood.reference:truth", "0,0.5,1")
    line = log_likelihood_on_line(cfg, record, ends, fractions, "posterior.json")
    assert [p["fraction"] for p in line["points"]] == [0.0, 0.5, 1.0]
    assert line["points"][0]["log_likelihood"] == pytest.approx(ref_ll, rel=1e-4)
    assert line["points"][-1]["loss"] == pytest.approx(at["at"]["truth"]["loss"], rel=1e-4)
    with pytest.raises(SystemExit, match="two sections"):
        parse_line("truth", None)
    with pytest.raises(SystemExit, match="not sampled"):
        profile(cfg, centre, names, parse_steps("kappa:0.1"))
    with pytest.raises(SystemExit, match="centre=map.nothing"):
        centre_of(record, "map.nothing", names, "posterior.json")


@slow
def test_the_contact_landscape_and_the_search_score_a_twins_truth(tiny, tmp_path, capsys):
    """evaluation.studies.contact_landscape: friction x restitution on a grid at the twin's level and
    κ, both windows, a heat map beside the JSON; the twin's own images make the truth (its friction
    and restitution the asset's) score below every grid point. search_twin's `truth_losses` scores
    the same truth with the same scorer. A run's own sequence is refused."""
    from evaluation.studies import contact_landscape
    from evaluation.studies.search_twin import truth_losses
    from sgdr.posterior.likelihood import RenderedImages
    from sgdr.posterior.run import design_search_config
    from sgdr.run_folder import run_asset_and_sequence

    overrides, run_dir, twin = tiny
    argv = [*overrides, f"posterior.run={run_dir}", f"posterior.sequence={twin}"]
    out = tmp_path / "contact.json"
    contact_landscape.main([*argv, "+points=2", f"+out={out}"])
    got = json.loads(out.read_text())
    assert np.shape(got["whole"]) == (2, 2) and np.shape(got["first"]) == (2, 2) and got["grid"] == [0.25, 0.75]
    assert got["truth"]["log10_k_shift"] == pytest.approx(TRUE_SHIFT)
    assert got["truth_whole"] < np.min(got["whole"]) and got["truth_first"] <= np.min(got["first"]) + 1e-9
    assert out.with_suffix(".png").stat().st_size > 1000
    assert json.loads(capsys.readouterr().out.strip().splitlines()[-1])["out"] == str(out)
    cfg = OmegaConf.to_object(compose(argv))
    _, asset, _, seq = run_asset_and_sequence(run_dir, str(twin), cfg.scene_file, "posterior")
    sc = design_search_config(cfg)
    images = RenderedImages(asset, seq, None, cfg.render, cfg.recon.lambda_dssim, sc.image_scale, sc.images_per_call)
    found = {"best_loss": 1.0, "stages": [{"frames": 2, "best_loss": 1.0}]}
    scored = truth_losses(cfg, asset, seq, images, found)
    assert scored["loss"] == pytest.approx(got["truth_whole"], rel=1e-5) and scored["gap"] == 1.0 - scored["loss"]
    assert scored["stages"][0]["frames"] == 2 and scored["stages"][0]["loss"] < 1.0
    _, _, _, own = run_asset_and_sequence(run_dir, "", cfg.scene_file, "posterior")
    assert truth_losses(cfg, asset, own, images, found) == {}
    with pytest.raises(SystemExit, match="not a twin"):
        contact_landscape.twin_values(own, asset)


@slow
def test_batched_rollout_retries_samples_past_the_stability_bound(tiny):
    """The batched program does not retry; a sample stiffer than the asset's n_t allows is re-run
    by the loop (doubled substeps), so a stiff sample is not silently cut off the posterior."""
    from sgdr.asset.store import load_asset
    from sgdr.physics import Ground
    from sgdr.posterior.rollouts import ROLLOUTS

    _, run_dir, _ = tiny
    asset = load_asset(run_dir / "asset")
    model, _ = asset.build()
    ground = Ground(asset.ground_point, asset.ground_normal)
    args = (ground, 3, 1 / asset.fps, asset.n_substeps, asset.physics)
    samples = {"log10_k_shift": np.array([0.0, 1.5])}  # 10^1.5 x stiffer: beyond n_t's bound, within max_substeps
    pos_b, stable_b = ROLLOUTS["batched"](model, asset.values, samples, *args)
    pos_l, stable_l = ROLLOUTS["loop"](model, asset.values, samples, *args)
    assert stable_l.tolist() == [True, True] and stable_b.tolist() == [True, True]
    np.testing.assert_allclose(pos_b, pos_l, atol=1e-4)


@slow
def test_the_point_predictions_silhouette_offsets_follow_the_twin(tiny):
    """posterior.discrepancy_offset's measurement on a twin (the model's own images, stiffness
    shifted): the offsets of the identified asset's rendered silhouettes from the twin's follow
    where the twin's centre of mass stands relative to the prediction's (its particles are the
    Gaussian centres), and vanish against the asset's own images."""
    from sgdr.asset.predict import physical_params, predict
    from sgdr.asset.store import load_asset
    from sgdr.data import load_sequence
    from sgdr.physics import Ground
    from sgdr.posterior.run import point_offsets

    overrides, run_dir, twin = tiny
    cfg = OmegaConf.to_object(compose(list(overrides)))
    asset = load_asset(run_dir / "asset")
    seq = load_sequence(twin)
    d = point_offsets(cfg, asset, seq)
    n_fit = min(asset.n_fit, seq.n_fit)
    assert d.shape == (n_fit, 3) and np.isfinite(d).all() and np.allclose(d[0], 0.0)
    model, binding = asset.build()
    pred = predict(model, physical_params(model, asset.physics, asset.values), binding, asset.gaussians,
                   Ground(asset.ground_point, asset.ground_normal), n_fit, asset.fps, int(asset.n_substeps),
                   asset.physics, seq.cameras, cfg.render, render_views=False)  # fmt: skip
    truth = np.stack([seq.gt_particles(f).mean(axis=0) for f in range(n_fit)])
    oracle = (truth - truth[0]) - (pred.centres.mean(axis=1) - pred.centres[0].mean(axis=0))
    size = float(np.ptp(asset.anchors, axis=0).max())
    assert np.abs(oracle).max() > 0.02 * size  # the shift moves the twin visibly
    # measured: 0.0016 off an oracle of up to 0.016 (4% of the size)
    assert np.abs(d - oracle).max() < 0.25 * np.abs(oracle).max(), (d, oracle)
    from sgdr.synth.twin import twin_sequence

    own = load_sequence(twin_sequence(run_dir / "asset", twin.parent / "twin_own", {"log10_k_shift": 0.0}))
    d0 = point_offsets(cfg, asset, own)
    assert np.abs(d0).max() < 0.01 * size, d0
