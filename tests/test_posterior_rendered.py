"""The posterior's rendered likelihood, its surrogate sampler and the forecast's discrepancy ball
(issue 36): each on a case whose answer is known without the pipeline."""

import json

import numpy as np
import pytest

from sgdr.posterior.forecast import ball_radius, calibrate_growth, coverage, fit_misfit, inside, sigma_over_time
from sgdr.posterior.likelihood import RenderedLikelihood
from sgdr.posterior.sample import Problem, run_ensembles
from sgdr.posterior.surrogate import SurrogateConfig, design, psis_khat, sample_with_surrogate


def test_rendered_likelihood_splits_noise_from_a_growing_discrepancy():
    """The MAP's misfit per frame: the smallest is the noise, the rest a non-decreasing
    discrepancy; the MAP scores about -n_vf / 2 and 10% more loss everywhere costs ~ n_vf x 0.05."""
    m = np.array([0.02, 0.021, 0.025, 0.024, 0.03, 0.04])  # per frame, with a dip at frame 3
    losses = np.repeat(m[:, None], 5, axis=1)  # [F, V]
    lik = RenderedLikelihood.at_map(losses, floor=1e-4, temperature=1.0)
    assert lik.noise == pytest.approx(0.02)
    assert np.all(np.diff(lik.discrepancy) >= -1e-12) and lik.discrepancy[0] == pytest.approx(0.0)
    assert lik.discrepancy[-1] == pytest.approx(0.02)
    n_vf = losses.size
    at_map = lik.log_likelihood(losses[None])[0]
    assert at_map == pytest.approx(-n_vf / 2, rel=0.05)
    worse = lik.log_likelihood(1.1 * losses[None])[0]
    assert at_map - worse == pytest.approx(0.05 * n_vf, rel=0.1)
    # later frames, where the model misses more, weigh less: the same extra loss costs less there
    early, late = losses.copy(), losses.copy()
    early[1] += 0.01
    late[-1] += 0.01
    assert lik.log_likelihood(late[None])[0] > lik.log_likelihood(early[None])[0]
    # an unstable sample (NaN losses) has zero probability; the temperature flattens
    assert lik.log_likelihood(np.full((1, *losses.shape), np.nan))[0] == -np.inf
    hot = RenderedLikelihood.at_map(losses, 1e-4, 2.0)
    assert hot.log_likelihood(losses[None])[0] == pytest.approx(at_map / 2)
    # a perfect fit: the floor keeps the scale finite
    assert RenderedLikelihood.at_map(np.zeros((3, 2)), 1e-4, 1.0).noise == pytest.approx(1e-4)


def _gaussian_problem():
    problem = Problem(["a", "b"], np.array([-1.0, 0.0]), np.array([1.0, 2.0]), np.array([0.1, 1.0]))
    mean, sd = np.array([0.2, 0.9]), np.array([0.08, 0.25])
    calls = []

    def log_like(thetas):
        thetas = np.atleast_2d(thetas)
        calls.append(len(thetas))
        return -0.5 * np.sum(((thetas - mean) / sd) ** 2, axis=1)

    return problem, mean, sd, log_like, calls


def test_the_surrogate_posterior_matches_a_known_gaussian_with_few_true_evaluations():
    problem, mean, sd, log_like, calls = _gaussian_problem()
    sc = SurrogateConfig(n_initial=0, n_sobol=32, n_validate=32, max_rounds=4, chain_steps=1500, clip=60.0)
    start = design(problem, np.zeros((0, 2)), sc.n_initial, sc.n_sobol, seed=0)
    assert start.shape == (33, 2) and np.allclose(start[0], problem.map_theta)

    def chains_of(lp, start):
        return run_ensembles(lp, problem, 10, sc.chain_steps, 4, 0.05, seed=0, move="de", space="logit", start=start)

    chains, _, acc, record = sample_with_surrogate(log_like, problem, start, sc, chains_of, seed=0)
    assert record.validated and record.rounds[-1]["inside_95"] >= 0.9 and record.rounds[-1]["khat"] <= 0.7
    assert sum(calls) == record.log_like.size <= 33 + 4 * 32  # the true likelihood only at the design and checks
    pooled = chains[:, chains.shape[1] // 2 :].reshape(-1, 2)
    assert np.allclose(pooled.mean(axis=0), mean, atol=0.3 * sd)
    assert np.allclose(pooled.std(axis=0), sd, rtol=0.25)
    assert 0.15 < acc.mean() < 0.75


def test_the_check_fails_a_surrogate_that_does_not_stand_for_the_likelihood():
    """One round, on a design far from a narrow peak: the surrogate's interval does not hold the
    truth at its draws, and the record says it is not validated."""
    problem, _, _, _, _ = _gaussian_problem()

    def narrow(thetas):
        thetas = np.atleast_2d(thetas)
        return -0.5 * np.sum(((thetas - np.array([0.9, 1.9])) / 0.01) ** 2, axis=1)

    sc = SurrogateConfig(n_initial=0, n_sobol=8, n_validate=24, max_rounds=1, chain_steps=300)
    start = design(problem, np.zeros((0, 2)), 0, 8, seed=1)

    def chains_of(lp, start):
        return run_ensembles(lp, problem, 10, sc.chain_steps, 4, 0.05, seed=0, move="de", space="logit", start=start)

    *_, record = sample_with_surrogate(narrow, problem, start, sc, chains_of, seed=0)
    assert not record.validated and record.rounds[0]["inside_95"] < 0.9
    assert psis_khat(np.zeros(10)) < 0.7  # equal weights: a perfect surrogate


def test_walkers_start_where_the_evaluations_are_highest_not_at_the_map():
    """A narrow peak far from the MAP on a plateau, in four parameters (a twin's likelihood seen
    from the asset's MAP): walkers started around the MAP wander the plateau; started from the
    evaluations (`design_start`) they sample the peak."""
    from sgdr.posterior.surrogate import design_start

    problem = Problem(list("abcd"), np.zeros(4), np.ones(4), np.full(4, 0.2))
    peak, sd = np.array([0.7, 0.6, 0.75, 0.65]), np.array([0.005, 0.01, 0.008, 0.02])

    def needle(thetas):
        thetas = np.atleast_2d(thetas)
        return np.maximum(-0.5 * np.sum(((thetas - peak) / sd) ** 2, axis=1), -60.0)

    rng = np.random.default_rng(0)
    evaluated = np.concatenate([design(problem, np.zeros((0, 4)), 0, 16, seed=0), peak + sd * rng.normal(size=(16, 4))])
    start = design_start(evaluated, needle(evaluated), problem, within=10.0)
    assert np.all(start.spread < 2 * sd) and np.all(start.spread >= 1e-3)
    p0 = start(40, np.random.default_rng(1))
    assert np.all(np.abs(p0 - peak) < 6 * sd)
    runs = {}
    for name, s in (("design", start), ("map", None)):
        chains, _, _ = run_ensembles(needle, problem, 16, 800, 2, 0.05, seed=0, move="de", space="logit", start=s)
        runs[name] = chains[:, 400:].reshape(-1, 4)
    assert np.allclose(runs["design"].mean(axis=0), peak, atol=0.5 * sd)
    assert np.allclose(runs["design"].std(axis=0), sd, rtol=0.4)
    assert np.mean(np.all(np.abs(runs["map"] - peak) < 3 * sd, axis=1)) < 0.5  # lost on the plateau
    with pytest.raises(ValueError, match="no stable evaluation"):
        design_start(evaluated[:2], np.array([-np.inf, -np.inf]), problem, 10.0)


def test_the_design_keeps_candidates_inside_the_prior_best_first():
    problem = Problem(["a"], np.array([0.0]), np.array([1.0]), np.array([0.5]))
    cand = np.array([[0.3], [1.5], [0.7], [0.1]])
    d = design(problem, cand, n_initial=2, n_sobol=0, seed=0)
    assert d[:, 0].tolist() == [0.5, 0.3, 0.7]


def test_the_design_counts_candidates_that_coincide_once():
    """A search over more parameters than the posterior samples gives candidates that coincide
    once projected (a sweep over a parameter the posterior keeps fixed): each enters once, the
    MAP among them too, and n_initial counts distinct ones."""
    problem = Problem(["a", "b"], np.array([0.0, 0.0]), np.array([1.0, 1.0]), np.array([0.5, 0.5]))
    cand = np.array([[0.3, 0.2], [0.3, 0.2], [0.5, 0.5], [0.3, 0.2], [0.7, 0.1], [0.9, 0.9]])
    d = design(problem, cand, n_initial=2, n_sobol=0, seed=0)
    assert d.tolist() == [[0.5, 0.5], [0.3, 0.2], [0.7, 0.1]]


class _Cam:
    """An orthographic-looking pinhole camera on the x axis: pixel u along +y, v along -z."""

    def __init__(self, focal=300.0, depth=2.0, size=192):
        self.K = np.array([[focal, 0, size / 2], [0, focal, size / 2], [0, 0, 1.0]])
        self.depth, self.size = depth, size

    def project(self, points):
        p = np.asarray(points, float)
        z = self.depth - p[:, 0]
        uv = np.stack([p[:, 1] / z * self.K[0, 0] + self.K[0, 2], -p[:, 2] / z * self.K[1, 1] + self.K[1, 2]], 1)
        return uv, z


class _Seq:
    """Silhouettes of a disc of points moving by `shift(f)` along y, seen by one `_Cam`."""

    def __init__(self, cam, shift, n_frames):
        self.cameras, self.shift, self.n_frames = [cam], shift, n_frames
        rng = np.random.default_rng(0)
        self.points = rng.uniform(-0.1, 0.1, (20000, 3))

    def image(self, v, f):
        img = np.zeros((self.cameras[0].size, self.cameras[0].size, 4))
        uv, _ = self.cameras[0].project(self.points + [0, self.shift(f), 0])
        ij = np.clip(np.floor(uv).astype(int), 0, self.cameras[0].size - 1)
        img[ij[:, 1], ij[:, 0], 3] = 1.0
        return img


def test_the_fit_misfit_reads_a_lagging_prediction_off_the_silhouettes():
    """The observed object moves 0.01 per frame along y; the prediction stands still: the misfit at
    frame f is 0.01 f scene units in the one axis the view sees, / sqrt(2) per axis."""
    cam = _Cam()
    seq = _Seq(cam, lambda f: 0.01 * f, 6)
    predicted = np.repeat(seq.points[None], 6, axis=0)  # [T, P, 3], not moving
    sigma = fit_misfit(seq, predicted, 6)
    assert sigma[0] == pytest.approx(0.0, abs=1e-9)
    assert np.allclose(sigma, 0.01 * np.arange(6) / np.sqrt(2), atol=0.002)
    # a prediction that moves with the object has (almost) no misfit
    moving = np.stack([seq.points + [0, 0.01 * f, 0] for f in range(6)])
    # (what is left: the silhouette's area centroid is not the mean of the projected points under
    # perspective, ~0.3 px here, 1 px = 0.0067 scene units)
    assert fit_misfit(seq, moving, 6).max() < 0.003


def test_the_ball_covers_what_its_level_says_and_the_growth_calibrates_to_it():
    """No parameter spread, σ constant: the 90% radius is the chi(3) 90% quantile (2.50 σ). Truths
    drifting away linearly need a growth > 0; the calibrated growth covers >= 90% and a smaller
    one does not."""
    t, n_fit = 30, 10
    draws = np.zeros((8, t, 3))
    sigma = np.full(t, 0.01)
    r = ball_radius(draws, np.zeros((t, 3)), sigma, 0.9, n_noise=4000, seed=0)
    assert np.allclose(r, 2.50 * 0.01, rtol=0.03)
    rng = np.random.default_rng(3)
    cases = []
    for k in range(6):
        speed = rng.uniform(0.02, 0.06)  # sizes per second, unknown to the forecast
        h = np.maximum(np.arange(t) - n_fit + 1, 0) / 24.0
        truth = np.zeros((t, 3))
        truth[:, k % 3] = speed * h * 0.5 + rng.normal(0, 0.002, t)
        cases.append({"draws": draws, "centre": np.zeros((t, 3)), "truth": truth, "sigma_fit": np.full(n_fit, 0.002),
                      "fps": 24.0, "size": 0.5})  # fmt: skip
    assert np.mean([coverage(c, 0.0) for c in cases]) < 0.5
    g = calibrate_growth(cases, 0.9)
    assert g > 0
    n = [t - n_fit] * len(cases)
    assert np.average([coverage(c, g) for c in cases], weights=n) >= 0.9
    assert np.average([coverage(c, 0.7 * g) for c in cases], weights=n) < 0.9
    s = sigma_over_time(np.full(n_fit, 0.002), t, 24.0, 0.5, g)
    assert np.allclose(s[:n_fit], 0.002) and np.all(np.diff(s[n_fit - 1 :]) >= 0)
    assert inside(np.zeros((2, 3)), np.zeros((2, 3)), np.zeros(2)).all()


def test_a_rough_likelihood_is_sampled_smoothed_and_the_roughness_is_measured():
    """A Gaussian plus deterministic ripples of ~3 nats (as the rendered loss's substep-scale
    roughness): the surrogate fits the ripples as noise, stands for the smoothed likelihood at its
    draws, and its posterior is the smooth one's."""
    problem, mean, sd, _, _ = _gaussian_problem()

    def rough(thetas):
        thetas = np.atleast_2d(thetas)
        smooth = -0.5 * np.sum(((thetas - mean) / sd) ** 2, axis=1)
        return smooth + 3.0 * np.sin(180 * thetas[:, 0]) * np.cos(150 * thetas[:, 1])

    sc = SurrogateConfig(n_initial=0, n_sobol=48, n_validate=32, max_rounds=5, chain_steps=1500)
    start = design(problem, np.zeros((0, 2)), 0, sc.n_sobol, seed=0)

    def chains_of(lp, start):
        return run_ensembles(lp, problem, 10, sc.chain_steps, 4, 0.05, seed=0, move="de", space="logit", start=start)

    chains, _, _, record = sample_with_surrogate(rough, problem, start, sc, chains_of, seed=0)
    assert record.validated
    assert 0.7 < record.rounds[-1]["roughness_nats"] < 4.0  # the ripples' RMS is 1.5 nats
    pooled = chains[:, chains.shape[1] // 2 :].reshape(-1, 2)
    assert np.allclose(pooled.mean(axis=0), mean, atol=0.75 * sd)  # the ripples move it a little


def test_only_a_sequence_other_than_the_runs_own_is_searched_anew(tmp_path):
    """The design's candidates: the run's own population for its own sequence (RUN.json), a new
    global search for any other (a twin); a folder that is no run is never its own."""
    from sgdr.posterior.run import _own_sequence

    run, seq, twin = tmp_path / "run", tmp_path / "data" / "torus", tmp_path / "twin"
    for d in (run, seq, twin):
        d.mkdir(parents=True)
    (run / "RUN.json").write_text(json.dumps({"sequence": str(tmp_path / "data" / ".." / "data" / "torus")}))
    assert _own_sequence(run, seq)
    assert not _own_sequence(run, twin)
    assert not _own_sequence(tmp_path / "no_run", seq)


@pytest.mark.parametrize("seed", range(5))
def test_the_gp_finds_the_rough_optimum_from_any_seed(seed):
    """Deterministic ripples of ~3 nats on a Gaussian, 96 Sobol evaluations: whatever the restarts'
    seed, the fit keeps the rough optimum (a nugget of about the ripples' RMS, 1.5 nats), not an
    interpolation of the ripples (a nugget at its bound). A guard: this case does not trap the
    smooth start alone; the small torus's evaluations did (surrogate.py)."""
    from scipy.stats import qmc

    from sgdr.posterior.surrogate import GPSurrogate

    problem, mean, sd, _, _ = _gaussian_problem()
    u = qmc.Sobol(2, scramble=True, seed=1).random(96)
    thetas = problem.low + u * (problem.high - problem.low)
    smooth = -0.5 * np.sum(((thetas - mean) / sd) ** 2, axis=1)
    ll = smooth + 3.0 * np.sin(180 * thetas[:, 0]) * np.cos(150 * thetas[:, 1])
    gp = GPSurrogate(problem.low, problem.high, 60.0, seed).fit(thetas, ll)
    assert 0.7 < gp.roughness < 4.0, gp.gp.kernel_


def _ridge_problem(ripples: float = 0.0):
    """A long ridge along a (sd 0.2) that is thin across (sd 0.01) and leans, b = 0.5 + 0.5 (a - 0.5),
    with deterministic ripples of `ripples` nats (the rendered loss's roughness)."""
    problem = Problem(["a", "b"], np.array([0.0, 0.0]), np.array([1.0, 1.0]), np.array([0.5, 0.5]))

    def log_like(thetas):
        a, b = np.atleast_2d(thetas).T
        ridge = -0.5 * ((a - 0.5) / 0.2) ** 2 - 0.5 * ((b - 0.5 - 0.5 * (a - 0.5)) / 0.01) ** 2
        return ridge + ripples * np.sin(180 * a) * np.cos(150 * b)

    return problem, log_like


def test_edges_sit_one_interval_width_beyond_each_side_inside_the_prior_on_the_draws_regression():
    from sgdr.posterior.surrogate import edge_starts

    problem = Problem(["a", "b"], np.array([0.0, 0.0]), np.array([1.0, 1.0]), np.array([0.5, 0.5]))
    rng = np.random.default_rng(0)
    a = rng.normal(0.5, 0.05, 4000)
    pool = np.column_stack([a, (0.015 + 0.1 * (a - 0.5) + rng.normal(0, 0.005, a.size)).clip(0, 1)])
    params, points, axes = edge_starts(pool, problem)
    q05, q95 = np.quantile(pool, [0.05, 0.95], axis=0)
    assert params == [0, 0, 1]  # b's lower side: the prior's bound is nearer than half the distance
    assert points[0, 0] == pytest.approx(q05[0] - (q95[0] - q05[0]))
    assert points[1, 0] == pytest.approx(q95[0] + (q95[0] - q05[0]))
    # b follows the draws' leaning (0.1 per unit of a) to the edge; its axis there is b's sd given a
    assert points[1, 1] == pytest.approx(0.015 + 0.1 * (points[1, 0] - 0.5), abs=0.002)
    assert abs(axes[1][1, 0]) == pytest.approx(0.005, rel=0.1) and axes[1][0, 0] == 0.0
    assert points[2, 1] == pytest.approx(q95[1] + (q95[1] - q05[1]))


def test_edge_probes_find_a_leaning_ridge_and_stay_low_around_a_posterior_that_reaches_far_enough():
    from sgdr.posterior.surrogate import probe_edges

    problem, log_like = _ridge_problem()
    rng = np.random.default_rng(1)
    # too narrow along the ridge (a sd 0.03 instead of 0.2): the ridge goes on past its edges in a
    a = rng.normal(0.5, 0.03, 4000)
    narrow = np.column_stack([a, 0.5 + 0.5 * (a - 0.5) + rng.normal(0, 0.01, a.size)])
    probes, ll, edge_ll = probe_edges(log_like, narrow, problem, 9)
    assert probes.shape == (ll.size, 2) and np.allclose(ll, log_like(probes))
    q = np.quantile(a, [0.05, 0.95])
    ridge_there = -0.5 * ((q + np.array([-1, 1]) * np.ptp(q) - 0.5) / 0.2) ** 2
    assert np.all(edge_ll[:2] > ridge_there - 1.0) and np.all(edge_ll[:2] > -3.0)  # found where the ridge passes
    # the exact posterior (a correlated Gaussian): every edge's profile 3.3 sd out, ~5.4 nats down
    cov = np.array([[0.2**2, 0.5 * 0.2**2], [0.5 * 0.2**2, 0.25 * 0.2**2 + 0.01**2]])
    exact = rng.multivariate_normal([0.5, 0.5], cov, 4000)
    exact = exact[np.all((exact > 0) & (exact < 1), axis=1)]
    _, _, edge_ll = probe_edges(log_like, exact, problem, 9)
    assert edge_ll.size > 0 and np.all(edge_ll < -3.0), edge_ll


def test_edge_probes_carry_the_surrogate_along_a_ridge_its_first_design_did_not_reach():
    """The first design covers a rough ridge only near its middle: the check alone passes there and
    the posterior stays about as narrow as the design; with edge probes the first round finds the
    ridge going on, and the next round's 90% interval of a is far wider (the truth's [0.17, 0.83],
    the prior's bound at 2.5 sd)."""
    problem, log_like = _ridge_problem(ripples=2.0)
    a = np.linspace(0.44, 0.56, 9)
    on = np.column_stack([a, 0.5 + 0.5 * (a - 0.5)])
    sobol = design(problem, np.zeros((0, 2)), 0, 16, seed=0)[1:]
    start = np.vstack([on, on + [0, 0.02], on - [0, 0.02], on + [0, 0.05], on - [0, 0.05], sobol])

    def chains_of(lp, walkers):
        return run_ensembles(lp, problem, 10, 1500, 4, 0.05, seed=0, move="de", space="logit", start=walkers)

    runs = {}
    for edges in (0, 9):
        sc = SurrogateConfig(n_initial=0, n_sobol=0, n_validate=32, max_rounds=6, chain_steps=1500, edge_points=edges)
        chains, _, _, record = sample_with_surrogate(log_like, problem, start, sc, chains_of, seed=0)
        pooled = chains[:, chains.shape[1] // 2 :].reshape(-1, 2)
        runs[edges] = (record, np.quantile(pooled[:, 0], [0.05, 0.95]))
    (plain, span0), (probed, span9) = runs[0], runs[9]
    assert plain.validated and np.ptp(span0) < 0.3, span0
    assert probed.rounds[0]["open_edges"] > 0 and probed.rounds[-1]["open_edges"] == 0 and probed.validated
    assert np.ptp(span9) > 0.4 and span9[0] < 0.33 and span9[1] > 0.67, span9


def _splat(cam, points, size):
    """An alpha image [size, size] of `points` seen by `cam` (one pixel per point)."""
    img = np.zeros((size, size))
    uv, _ = cam.project(points)
    ij = np.clip(np.floor(uv * size / cam.width).astype(int), 0, size - 1)
    img[ij[:, 1], ij[:, 0]] = 1.0
    return img


def test_the_silhouette_offsets_triangulate_where_the_object_stands_from_the_images():
    """Three views of a blob; the observed blob drifts away from the predicted one by a known 3D
    vector that grows over the frames: the offsets recover it (relative to frame 0) from the
    silhouettes alone, at the predicted images' own (lower) resolution too, and the end offset
    and the scatter about it come out of `offset_discrepancy`."""
    from sgdr.cameras import Camera
    from sgdr.posterior.forecast import offset_discrepancy, silhouette_offsets

    cams = [Camera.look_at(eye, [0, 0, 0], [0, 0, 1], 40.0, 256, 256) for eye in ([3, 0, 1], [0, 3, 1], [-2, -2, 2])]
    rng = np.random.default_rng(1)
    blob = rng.normal(0, 0.08, (20000, 3))
    drift = np.array([0.02, -0.01, 0.015])  # per frame
    n = 6

    class Seq:
        cameras = cams

        def image(self, v, f):
            img = np.zeros((256, 256, 4))
            img[..., 3] = _splat(cams[v], blob + f * drift, 256)
            return img

    predicted = np.stack([[_splat(c, blob, 128) for c in cams] for _ in range(n)])  # [F, V, 128, 128]
    coms = np.zeros((n, 3))
    d = silhouette_offsets(Seq(), predicted, coms)
    assert d.shape == (n, 3) and np.allclose(d[0], 0.0)
    assert np.allclose(d, np.arange(n)[:, None] * drift, atol=0.006)
    end, sigma = offset_discrepancy(d)
    assert np.allclose(end, (n - 1) * drift, atol=0.006)
    assert 0.0 < sigma < 0.02  # the last third's scatter about the end: the drift of one frame

    # a view whose observed silhouette leaves the image does not count: the other two still give it
    class Cut(Seq):
        def image(self, v, f):
            img = super().image(v, f)
            if v == 2:
                img[:, :60, 3] = 1.0  # a slab over the border: that view's centroid is not the object's
            return img

    assert np.allclose(silhouette_offsets(Cut(), predicted, coms), d, atol=0.006)
    # one view is not enough for a 3D offset: NaN, and no offset from nothing
    d1 = silhouette_offsets(Seq(), predicted[:, :1], coms)
    assert np.isnan(d1).all()
    end1, sigma1 = offset_discrepancy(d1)
    assert np.all(end1 == 0.0) and sigma1 == 0.0


def test_a_climb_walks_up_a_leaning_ridge_from_the_best_evaluation_and_stays_in_the_prior():
    """The design lies along the thin leaning ridge of `_ridge_problem` up to 1.5 sd below its top
    (a = 0.5; 1.125 nats): the climb reaches the top within its budget; a budget under one
    generation climbs nothing."""
    from sgdr.posterior.surrogate import CLIMB_POPSIZE, climb

    problem, log_like = _ridge_problem()
    a = np.linspace(0.02, 0.2, 7)
    start = np.vstack([np.column_stack([a, 0.5 + 0.5 * (a - 0.5)]), [[0.9, 0.1]]])
    ll = log_like(start)
    thetas, lls = climb(log_like, start, ll, problem, 96, 10.0, seed=0)
    assert len(lls) <= 96 and len(lls) % CLIMB_POPSIZE == 0 and np.allclose(lls, log_like(thetas))
    assert np.all((thetas >= problem.low) & (thetas <= problem.high))
    assert ll.max() < -1.0 and lls.max() > -0.1, (ll.max(), lls.max())
    none_t, none_l = climb(log_like, start, ll, problem, CLIMB_POPSIZE - 1, 10.0, seed=0)
    assert none_t.shape == (0, 2) and none_l.size == 0


def test_the_surrogate_rounds_record_their_climb():
    problem, log_like = _ridge_problem()
    start = design(problem, np.zeros((0, 2)), 0, 16, seed=0)

    def chains_of(lp, walkers):
        return run_ensembles(lp, problem, 10, 400, 2, 0.05, seed=0, move="de", space="logit", start=walkers)

    sc = SurrogateConfig(n_initial=0, n_sobol=0, n_validate=16, max_rounds=1, chain_steps=400, climb=16,
                         independence=0.0)  # fmt: skip
    _, _, _, record = sample_with_surrogate(log_like, problem, start, sc, chains_of, seed=0)
    first = record.rounds[0]
    assert first["climb_evaluations"] == 16 and first["climb_gain_nats"] >= 0.0
    assert len(record.log_like) == len(start) + 16 + 16  # the design, the climb, the check's draws
