"""Sampling a posterior whose every evaluation is a rendered rollout: a Gaussian-process surrogate,
refined where the chains go, and checked against the true likelihood at the chains' own draws.

Why. One rendered log-likelihood at the small preset costs ~0.7 s (a rollout of the fit frames and
190 renders); converged ensembles need ~10^5 evaluations, days on 2 cores. The landscape is
smooth enough between its basins for a surrogate (four parameters, one number each), so:

  1. design   the identification's global stage already scored a population (the run's
              dynamics.json `search`): its candidates inside the prior, best first (at most
              `n_initial`), plus `n_sobol` scrambled Sobol points over the prior box and the MAP,
              are evaluated with the true likelihood (batched);
  2. fit      a Gaussian process (scikit-learn; an anisotropic squared-exponential kernel plus a
              white-noise term, hyper-parameters by maximum marginal likelihood) to log L in the
              unit box u = (θ - low) / (high - low), with values more than `clip` nats below the
              best (and unstable rollouts) clipped there (the GP models the region that matters;
              its mean reverts to that floor away from the data, so unexplored corners are not
              mistaken for mass). The rendered log L is rough: along a global stiffness shift of
              the small torus it moves by 5-13 nats between steps of 0.02 decades (a contact
              shifts by a substep), so the white-noise term (the "roughness") is fitted, not
              fixed small, and the surrogate's mean is a smoothed log L;
  3. sample   emcee ensembles (`sgdr.posterior.sample.run_ensembles`, the same moves, space and
              convergence criteria as the direct sampler) on the surrogate's mean, `chain_steps`
              long: cheap, so the chains are many τ long; their walkers start from the true
              evaluations so far (`design_start`), not around the MAP: where the likelihood is;
              after a pilot, half their moves are independence proposals from a Gaussian
              mixture fitted to it (`independence`), which cross between a posterior's modes;
  4. check    `n_validate` draws of those chains are evaluated with the true likelihood; the
              surrogate stands for it when at least `inside_min` of them lie in its 95% predictive
              interval (mean ± 1.96 sd, the roughness included: the emulator check of Bastos &
              O'Hagan 2009). The RMS error, the mean error (a bias would show there) and the PSIS
              Pareto k̂ of the log ratios true - surrogate (ArviZ; > 0.7 means the rough true
              posterior is not reached by reweighting the smooth one) are recorded beside it.
              If it does not, the draws join the design and 2-4 repeat, at most `max_rounds` times.

What is sampled is therefore the posterior of the smoothed log-likelihood: wider than the rough
one where the roughness is large, which on data the model cannot fit exactly is the honest
direction. The chains of the round that passed the check are the posterior; the run is 'converged' only when
they meet the usual criteria AND the check passed (`failed` says which did not). Deterministic
for a given seed (the GP's optimiser restarts and the draws are seeded).
"""

from __future__ import annotations

import logging
import time
import warnings
from dataclasses import dataclass, field

import numpy as np

log = logging.getLogger(__name__)


@dataclass
class DesignSearchConfig:
    """posterior.surrogate.design_search.*: the global search on a sequence other than the run's own
    (a twin) is the identification's (recon.search.*) with these replaced (`design_search_config`).
    Its first look, its sweeps and its windows decide which basin of the rendered loss the design
    starts in, and so where the posterior sits: on ten noisy twins at small the 90% intervals held
    21 of 40 truths with a 32-point first look and no sweep, 30 with the small preset's 128 points
    and 8 sweep points (docs/posterior.md, "SBC at small")."""

    initial_samples: int = 128  # scrambled Sobol points over the search box scored first (recon.search.initial_samples)
    generations: int = 24  # CMA-ES generations, split over the windows (recon.search.generations)
    line_points: int = 8  # each parameter's coordinate sweep before each window's CMA-ES (recon.search.line_points)
    # the fit windows (shares of the fit frames) searched in turn (recon.search.frame_schedule)
    frame_schedule: list = field(default_factory=lambda: [0.5, 1.0])
    # the level's search coordinate (recon.search.level): "effective" moves κ at a fixed stiffness.
    # On the ten twins of the SBC's second draw the search's best came within a mean 5.6% of the
    # truth's loss against 11.2% with the level itself (docs/posterior.md, "The SBC's misses up close")
    level: str = "effective"
    # the whole window searched from this many distinct starts side by side (recon.search.starts), start_distance
    # apart in the unit box (recon.search.start_distance)
    starts: int = 1
    # friction x restitution together on this grid after each coordinate sweep (recon.search.contact_points):
    # on the SBC's cases 33 and 37 the search's gap to the truth's loss fell from 0.00123 and 0.00067 to
    # 0.00054 and 0.00049 (docs/posterior.md, "The SBC's misses in friction and restitution")
    contact_points: int = 12
    start_distance: float = 0.2


@dataclass
class SurrogateConfig:
    """posterior.surrogate.* (conf/posterior/default.yaml; sizes in the presets)."""

    n_initial: int = 96  # the global stage's best candidates inside the prior, evaluated first
    n_sobol: int = 32  # scrambled Sobol points over the prior box added to the design
    n_validate: int = 48  # draws of each round's chains evaluated with the true likelihood
    max_rounds: int = 6  # surrogate refits at most
    chain_steps: int = 3000  # steps of the ensembles on the surrogate (cheap)
    clip: float = 60.0  # nats below the best at which log L is clipped for the GP
    inside_min: float = 0.9  # share of the check draws whose true log L lies in the surrogate's 95% interval
    # a sequence other than the run's own (posterior.sequence, e.g. a twin) gets its own global search
    # (the identification's stage, recon.search.*) for the design's candidates: the run's population
    # describes the run's sequence only; False: the run's population for any sequence
    search_other_sequence: bool = True
    design_search: DesignSearchConfig = field(default_factory=DesignSearchConfig)
    # the walkers start from the true evaluations so far, drawn with weights exp(log L - max) and
    # spread by half the spread of those within `start_within` nats of the best (`design_start`)
    start_within: float = 10.0
    # edge probes (0: none): once the check passes, the likelihood's profile just beyond each side of
    # each parameter's 90% interval (`probe_edges`, this many points a line); a probe within
    # `edge_within` nats of the best evaluation means the posterior reaches further than the
    # surrogate knows (a ridge its chains never went along): the probes join the design and
    # another round follows
    edge_points: int = 0
    edge_within: float = 3.0
    # the chains on the surrogate: this share of their moves are independence proposals from a Gaussian
    # mixture fitted to a pilot of `pilot_steps` (sgdr.posterior.sample.MixtureMove; 0: `posterior.moves` alone)
    independence: float = 0.5
    pilot_steps: int = 2000
    # a climb (0: none): before each round's fit, a local CMA-ES on the true likelihood from the best
    # evaluation so far, this many evaluations (`climb`). On the SBC's third draw every truth the
    # intervals missed fitted better than any evaluation the sampler had made, most of them uphill
    # from the posterior's median along a ridge
    climb: int = 0


@dataclass
class SurrogateRecord:
    """What the surrogate did: every true evaluation and each round's check."""

    thetas: np.ndarray  # [N, D] every θ the true likelihood evaluated, in order
    log_like: np.ndarray  # [N]
    rounds: list = field(default_factory=list)  # per round: n_design, khat, rmse, max_abs, seconds
    validated: bool = False
    surrogate: GPSurrogate | None = None  # the last round's (the validated one when validated)
    start: object = None  # the last round's walker starter (`design_start`)

    def to_json(self) -> dict:
        best = int(np.argmax(self.log_like)) if self.log_like.size else -1
        return {
            "n_true_evaluations": int(self.log_like.size),
            # a θ met twice (an edge probe's line clipped onto the prior's bound) is rendered once
            "n_distinct_evaluations": int(len(np.unique(self.thetas, axis=0))) if self.thetas.size else 0,
            "rounds": self.rounds,
            "validated": bool(self.validated),
            "best_theta": self.thetas[best].tolist() if best >= 0 else None,
            "best_log_like": float(self.log_like[best]) if best >= 0 else None,
        }


class GPSurrogate:
    """log L(θ) ≈ floor + clip · GP(u) (module docstring, step 2)."""

    def __init__(self, low, high, clip: float, seed: int = 0):
        self.low, self.high = np.asarray(low, float), np.asarray(high, float)
        self.clip, self.seed = float(clip), int(seed)
        self.gp = None
        self.floor = 0.0

    def unit(self, thetas: np.ndarray) -> np.ndarray:
        return (np.atleast_2d(thetas) - self.low) / (self.high - self.low)

    def fit(self, thetas: np.ndarray, log_like: np.ndarray) -> GPSurrogate:
        from sklearn.gaussian_process import GaussianProcessRegressor
        from sklearn.gaussian_process.kernels import RBF, ConstantKernel, WhiteKernel

        y = np.asarray(log_like, float)
        ok = np.isfinite(y)
        if ok.sum() < 2:
            raise ValueError("posterior surrogate: fewer than 2 stable evaluations to fit")
        self.floor = float(y[ok].max()) - self.clip
        # an unstable rollout (-inf) sits at the floor: the GP learns that nothing is there
        target = (np.maximum(np.where(ok, y, self.floor), self.floor) - self.floor) / self.clip  # [0, 1]
        x = self.unit(thetas)
        d = x.shape[1]
        # the nugget: the rendered loss is rough at the scale of a few percent of a decade (a contact or
        # a bounce shifts by a substep), several nats; the GP treats that roughness as noise and its
        # mean is the smoothed log L (the noise level is fitted, up to (0.5 clip)^2)
        # The hyper-parameters' likelihood is multimodal: from a smooth start (nugget 1e-5) the optimiser
        # and its random restarts can all end interpolating the roughness (nugget at its bound, short
        # length scales) far below the rough optimum (measured on the small torus's 209 evaluations:
        # log marginal likelihood -19 at nugget 0 against 158 at 4.2 nats, seeds 0 and 4 of 5). So the
        # fit starts from a smooth and from a rough nugget and keeps the higher marginal likelihood.
        best = None
        for nugget in (1e-5, 1e-2):
            kernel = ConstantKernel(0.1, (1e-4, 10.0)) * RBF(np.full(d, 0.2), (1e-3, 20.0)) + WhiteKernel(
                nugget, (1e-10, 0.25)
            )
            gp = GaussianProcessRegressor(kernel, normalize_y=False, n_restarts_optimizer=3, random_state=self.seed)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # hyper-parameters at a bound: the fit still stands
                gp.fit(x, target)
            if best is None or gp.log_marginal_likelihood_value_ > best.log_marginal_likelihood_value_:
                best = gp
        self.gp = best
        return self

    def predict(self, thetas: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(mean [S], standard deviation [S]) of log L in nats, the roughness (nugget) included."""
        mean, sd = self.gp.predict(self.unit(thetas), return_std=True)
        return self.floor + self.clip * mean, self.clip * sd

    @property
    def roughness(self) -> float:
        """The fitted nugget's standard deviation, nats."""
        try:
            return float(self.clip * np.sqrt(self.gp.kernel_.k2.noise_level))
        except AttributeError:
            return float("nan")

    def __call__(self, thetas: np.ndarray) -> np.ndarray:
        """[S] surrogate log L; -inf outside the box."""
        thetas = np.atleast_2d(np.asarray(thetas, float))
        out = np.full(thetas.shape[0], -np.inf)
        inside = np.all((thetas >= self.low) & (thetas <= self.high), axis=1)
        if inside.any():
            out[inside] = self.floor + self.clip * self.gp.predict(self.unit(thetas[inside]))
        return out


def design(problem, candidates: np.ndarray, n_initial: int, n_sobol: int, seed: int) -> np.ndarray:
    """[N, D] the first design: the MAP, the given candidates inside the prior (best first, at most
    n_initial distinct ones, none equal to the MAP) and n_sobol scrambled Sobol points over the
    prior box. Candidates of a search over more parameters than the posterior samples coincide once
    projected (a sweep over κ at the best level and μ is one point in (shift, μ)): each counts once."""
    from scipy.stats import qmc

    parts = [problem.map_theta[None]]
    c = np.asarray(candidates, float).reshape(-1, len(problem.names))
    if c.size and n_initial > 0:
        c = c[problem.inside(c)]
        seen, keep = {np.asarray(problem.map_theta, float).tobytes()}, []
        for row in c:
            if row.tobytes() not in seen:
                seen.add(row.tobytes())
                keep.append(row)
        if keep:
            parts.append(np.stack(keep)[: int(n_initial)])
    if n_sobol > 0:
        u = qmc.Sobol(len(problem.names), scramble=True, seed=int(seed)).random(int(n_sobol))
        parts.append(problem.low + u * (problem.high - problem.low))
    return np.concatenate(parts)


def design_start(thetas: np.ndarray, log_like: np.ndarray, problem, within: float):
    """A walker starter (n_walkers, rng) -> [W, D] from the true evaluations so far: each walker an
    evaluated θ drawn with weight exp(log L - max) (the posterior restricted to what was evaluated),
    moved by N(0, (s/2)^2), s the per-parameter spread of the evaluations within `within` nats of the
    best (at least 1e-3 of the prior width), clipped inside the prior. So the walkers start where the
    likelihood is, at its scale: the MAP and a fixed share of the prior width (`posterior.init_ball`)
    put them on a plateau when the peak is narrow or lies elsewhere (a twin's: the asset's MAP is the
    run's fit, not the twin's), and on a plateau the ensemble never finds it."""
    thetas = np.asarray(thetas, float)
    ll = np.where(np.isfinite(log_like), np.asarray(log_like, float), -np.inf)
    if not np.isfinite(ll).any():
        raise ValueError("posterior surrogate: no stable evaluation to start the walkers from")
    w = np.exp(ll - ll.max())
    w /= w.sum()
    width = problem.high - problem.low
    top = thetas[ll >= ll.max() - float(within)]
    spread = np.maximum(0.5 * top.std(axis=0) if len(top) >= 2 else 0.0, 1e-3 * width)

    def start(n_walkers: int, rng) -> np.ndarray:
        p0 = thetas[rng.choice(len(thetas), size=int(n_walkers), p=w)]
        p0 = p0 + spread * rng.standard_normal(p0.shape)
        return np.clip(p0, problem.low + 1e-3 * width, problem.high - 1e-3 * width)

    start.spread = spread
    return start


EDGE_BEYOND = 1.0  # how far beyond each side of a 90% interval its edge probe sits, in interval widths
EDGE_SPREAD = 4.0  # an edge's lines: its start ± this many conditional sd along each principal axis


def edge_starts(pool: np.ndarray, problem) -> tuple[list[int], np.ndarray, list[np.ndarray]]:
    """The edges of the posterior draws `pool` [N, D]: per parameter j and side, θ_j `EDGE_BEYOND`
    widths of its 90% interval beyond the interval's end (inside the prior; a side whose move the
    prior's bound leaves shorter than half that gets none), the others at their mean given θ_j (the
    draws' linear regression on θ_j: a ridge that leans is followed, not left). Returns (each
    edge's parameter, [M, D] the starts, each edge's [D, D] axes: the other parameters' covariance
    given θ_j, as columns scaled to one sd, zero in row j). For a Gaussian posterior an edge lies
    3.3 sd out, 5.4 nats below its peak."""
    q05, q95 = np.quantile(pool, [0.05, 0.95], axis=0)
    mean, cov = pool.mean(axis=0), np.atleast_2d(np.cov(pool.T))
    d = pool.shape[1]
    params, points, axes = [], [], []
    for j in range(d):
        width = q95[j] - q05[j]
        if width <= 0 or cov[j, j] <= 0:
            continue
        others = [i for i in range(d) if i != j]
        slope = cov[others, j] / cov[j, j]
        given = cov[np.ix_(others, others)] - np.outer(slope, cov[j, others])
        w, v = np.linalg.eigh(given) if others else (np.zeros(0), np.zeros((0, 0)))
        scaled = np.zeros((d, len(others)))
        scaled[others] = v * np.sqrt(np.clip(w, 0.0, None))
        for end, side in ((q05[j], -1.0), (q95[j], 1.0)):
            value = float(np.clip(end + side * EDGE_BEYOND * width, problem.low[j], problem.high[j]))
            if abs(value - end) < 0.5 * EDGE_BEYOND * width:
                continue
            point = mean.copy()
            point[j] = value
            point[others] = mean[others] + slope * (value - mean[j])
            params.append(j)
            points.append(np.clip(point, problem.low, problem.high))
            axes.append(scaled)
    return params, np.array(points).reshape(-1, d), axes


def probe_edges(true_log_like, pool: np.ndarray, problem, n_points: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The likelihood's profile at each edge of the posterior draws `pool` (`edge_starts`): the
    edge's parameter held, lines of `n_points` through the edge's best so far along each principal
    axis of the other parameters' covariance given it (± `EDGE_SPREAD` sd, inside the prior), the
    best moving with each line: a coordinate sweep in the posterior's own whitened coordinates,
    fine where the ridge is thin. One batched call of `true_log_like` per axis for all edges.
    Returns (every probe [P, D], its log L [P], the best log L at each edge [M])."""
    params, best, axes = edge_starts(pool, problem)
    d = pool.shape[1]
    if not params:
        return np.zeros((0, d)), np.zeros(0), np.zeros(0)
    t = np.linspace(-EDGE_SPREAD, EDGE_SPREAD, int(n_points))
    best_ll = np.full(len(params), -np.inf)
    thetas, lls = [], []
    for k in range(d - 1):
        trial = np.concatenate([best[m][None] + t[:, None] * axes[m][:, k][None] for m in range(len(params))])
        trial = np.clip(trial, problem.low, problem.high)
        ll = np.asarray(true_log_like(trial), float)
        thetas.append(trial)
        lls.append(ll)
        rows = np.where(np.isfinite(ll), ll, -np.inf).reshape(len(params), t.size)  # one line per edge
        for m, row in enumerate(rows):
            i = int(np.argmax(row))
            if row[i] > best_ll[m]:
                best_ll[m], best[m] = row[i], trial[m * t.size + i]
    return np.concatenate(thetas), np.concatenate(lls), best_ll


CLIMB_POPSIZE = 8  # a climb's CMA-ES population: one batched call of the true likelihood a generation


def climb(true_log_like, thetas: np.ndarray, log_like: np.ndarray, problem, n_evaluations: int, within: float,
          seed: int) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """A local CMA-ES on the true log L from the best of the evaluations so far: in the prior's unit
    box, its step per parameter the spread of the evaluations within `within` nats of the best (at
    least 1% of the prior's width), `CLIMB_POPSIZE` a generation, `n_evaluations` at most. The
    surrogate's mean reverts to its floor away from its design, so a ridge that rises beyond the
    design's best holds no posterior mass until something evaluates it; the climb walks up it.
    Returns (every θ it evaluated [M, D], their log L [M]); -inf (unstable) counts as worst."""
    import cma

    ll = np.where(np.isfinite(log_like), np.asarray(log_like, float), -np.inf)
    if not np.isfinite(ll).any() or n_evaluations < CLIMB_POPSIZE:
        return np.zeros((0, len(problem.names))), np.zeros(0)
    width = problem.high - problem.low
    top = np.asarray(thetas, float)[ll >= ll.max() - float(within)]
    spread = np.maximum(top.std(axis=0) if len(top) >= 2 else 0.0, 1e-2 * width) / width
    u0 = (np.asarray(thetas, float)[int(np.argmax(ll))] - problem.low) / width
    opts = {"bounds": [0.0, 1.0], "popsize": CLIMB_POPSIZE, "seed": int(seed) + 1, "verbose": -9, "tolfun": 0.0,
            "tolx": 1e-9, "CMA_stds": (spread / spread.max()).tolist()}  # fmt: skip
    es = cma.CMAEvolutionStrategy(np.clip(u0, 0.0, 1.0).tolist(), float(spread.max()), opts)
    out_t, out_l = [], []
    while sum(len(t) for t in out_t) + CLIMB_POPSIZE <= int(n_evaluations) and not es.stop():
        u = np.clip(np.asarray(es.ask(), float), 0.0, 1.0)
        trial = problem.low + u * width
        lt = np.asarray(true_log_like(trial), float)
        es.tell(list(u), (-np.where(np.isfinite(lt), lt, -1e12)).tolist())
        out_t.append(trial)
        out_l.append(lt)
    return np.concatenate(out_t), np.concatenate(out_l)


def psis_khat(log_weights: np.ndarray) -> float:
    """ArviZ's Pareto k̂ of importance log-weights (inf when fewer than 2 are finite, 0 when all
    are equal). A draw whose true likelihood is -inf (an unstable rollout) carries weight 0 and
    no tail; the record counts such draws separately."""
    import arviz as az

    lw = np.asarray(log_weights, float)
    lw = lw[np.isfinite(lw)]
    if lw.size < 2:
        return float("inf")
    if np.ptp(lw) < 1e-9:  # equal weights: the surrogate is exact here, no tail to fit
        return 0.0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # ArviZ warns about k̂ itself; the caller reports it
        _, khat = az.psislw(lw - lw.max())
    return float(khat)


def sample_with_surrogate(true_log_like, problem, start: np.ndarray, sc: SurrogateConfig, run_chains, seed: int = 0,
                          progress: bool = False):  # fmt: skip
    """(chains [E, steps, W, D], log_probs, acceptance, SurrogateRecord) by the module docstring's
    steps. true_log_like(thetas [S, D]) -> [S] (batched, -inf where unstable); start: the first
    design (`design`); run_chains(log_prob, start) -> (chains, log_probs, acceptance), e.g.
    `run_ensembles` with the posterior's settings, its walkers from `start` (`design_start` of the
    true evaluations so far; kept in the record as `record.start`)."""
    rng = np.random.default_rng(int(seed))
    t0 = time.time()
    thetas = np.asarray(start, float)
    ll = np.asarray(true_log_like(thetas), float)
    record = SurrogateRecord(thetas, ll)
    log.info("posterior surrogate: design of %d evaluated in %.0f s (best log L %.2f)", len(ll), time.time() - t0,
             np.nanmax(np.where(np.isfinite(ll), ll, np.nan)))  # fmt: skip
    chains = log_probs = acceptance = None
    for r in range(int(sc.max_rounds)):
        t_round = time.time()
        climbed = {}
        if int(sc.climb) > 0:
            before = _best(record.log_like)
            up_t, up_l = climb(true_log_like, record.thetas, record.log_like, problem, int(sc.climb), sc.start_within,
                               seed + r)  # fmt: skip
            record.thetas = np.concatenate([record.thetas, up_t])
            record.log_like = np.concatenate([record.log_like, up_l])
            after = _best(record.log_like)
            climbed = {"climb_evaluations": int(up_l.size), "climb_gain_nats": after - before}
            log.info("posterior surrogate: round %d, climb of %d evaluations, best log L +%.2f nats", r + 1,
                     up_l.size, after - before)  # fmt: skip
        surrogate = GPSurrogate(problem.low, problem.high, sc.clip, seed + r).fit(record.thetas, record.log_like)
        record.start = design_start(record.thetas, record.log_like, problem, sc.start_within)
        chains, log_probs, acceptance = run_chains(surrogate, record.start)
        pool = chains[:, chains.shape[1] // 2 :].reshape(-1, chains.shape[-1])
        draws = pool[rng.choice(len(pool), size=min(int(sc.n_validate), len(pool)), replace=False)]
        truth = np.asarray(true_log_like(draws), float)
        approx, sd = surrogate.predict(draws)
        err = truth - approx
        khat = psis_khat(err)
        finite = np.isfinite(err)
        rmse = float(np.sqrt(np.mean(err[finite] ** 2))) if finite.any() else float("inf")
        covered = float(np.mean(np.where(finite, np.abs(err) <= 1.96 * sd, False)))
        record.rounds.append(
            {
                "round": r + 1,
                "n_design": int(len(record.log_like)),
                "inside_95": covered,
                "mean_error_nats": float(np.mean(err[finite])) if finite.any() else float("inf"),
                "roughness_nats": surrogate.roughness,
                "khat": khat,
                "rmse_nats": rmse,
                "max_abs_nats": float(np.max(np.abs(err[finite]))) if finite.any() else float("inf"),
                "unstable_draws": int((~np.isfinite(truth)).sum()),
                "lengthscales": _lengthscales(surrogate),
                "seconds": float(time.time() - t_round),
                **climbed,
            }
        )
        record.surrogate = surrogate
        record.thetas = np.concatenate([record.thetas, draws])
        record.log_like = np.concatenate([record.log_like, truth])
        log.info("posterior surrogate: round %d, design %d, %.0f%% of the draws inside the 95%% interval, rmse %.2f "
                 "nats, roughness %.2f nats, k-hat %.2f", r + 1, record.rounds[-1]["n_design"], 100 * covered, rmse,
                 surrogate.roughness, khat)  # fmt: skip
        if progress:
            print(f"posterior surrogate: round {r + 1}: {covered:.0%} inside, rmse {rmse:.2f} nats", flush=True)
        if covered >= sc.inside_min and int(sc.edge_points) > 0:
            # the check holds where the chains went; whether the likelihood goes on beyond their reach
            probes, probe_ll, edge_ll = probe_edges(true_log_like, pool, problem, int(sc.edge_points))
            top = _best(record.log_like)
            record.thetas = np.concatenate([record.thetas, probes])
            record.log_like = np.concatenate([record.log_like, probe_ll])
            open_edges = int(np.sum(edge_ll >= top - float(sc.edge_within)))
            record.rounds[-1].update(
                {"edges": int(edge_ll.size), "edge_probes": int(probe_ll.size), "open_edges": open_edges,
                 "edge_log_like_below_best": [float(top - v) for v in edge_ll], "seconds": float(time.time() - t_round)}
            )  # fmt: skip
            log.info("posterior surrogate: round %d, %d edges probed (%d rollouts), %d within %.1f nats of the best",
                     r + 1, edge_ll.size, probe_ll.size, open_edges, sc.edge_within)  # fmt: skip
            if open_edges:
                continue
        if covered >= sc.inside_min:
            record.validated = True
            break
    return chains, log_probs, acceptance, record


def _best(log_like: np.ndarray) -> float:
    """The highest finite log L (-inf when none is: every rollout unstable)."""
    return float(np.max(log_like[np.isfinite(log_like)], initial=-np.inf))


def _lengthscales(surrogate: GPSurrogate) -> list | None:
    """The fitted RBF length scales in unit-box coordinates (how far each parameter matters)."""
    try:
        return [float(v) for v in np.atleast_1d(surrogate.gp.kernel_.k1.k2.length_scale)]
    except AttributeError:
        return None
