"""Sampling the posterior with emcee, and deciding whether the samples can be trusted.

The sampled vector θ is small (`posterior.parameters`, default: log10_k_shift, κ, μ, e): a global
shift of the identified log10 k field and the scalar physics parameters, under uniform box priors
(`posterior.priors`). `log_probability` evaluates a whole ensemble at once
(`emcee.EnsembleSampler(vectorize=True)`): every walker inside the prior becomes one sample of
the `rollout_fn(samples) -> (positions [S, T, N_A, 3], stable [S])` contract (the batched rollout
or `sgdr.posterior.rollouts.loop_rollout`), its centres are compared with the silhouettes
(`sgdr.posterior.likelihood`); outside the prior or unstable is log p = -inf.

Independent ensembles. `run_ensembles` runs `posterior.n_ensembles` (>= 4 asked by the issue)
ensembles, each with its own seed and its own walkers started in a small ball around the MAP
(the run's identified parameters, shift 0), clipped into the prior. The walkers move with
`posterior.moves` (default: differential evolution) in `posterior.space` (default: logit, each
parameter mapped from its prior box onto the real line, `LogitSpace`); docs/posterior.md gives
the measurements behind both defaults.

Convergence (`diagnose`), every criterion required, its failures listed:
  1. τ: the integrated autocorrelation time of every parameter in every ensemble
     (`emcee.autocorr.integrated_time(..., quiet=True)`, averaged over the walkers as emcee
     does), finite, and every chain at least `posterior.tau_factor` (50) x max τ long; every
     walker accepted at least one move (a walker that never moved has no τ and is stuck);
  2. R-hat <= `posterior.rhat_max` and 3. bulk and tail ESS >= `posterior.ess_min`, with ArviZ
     (rank-normalised split R-hat, Vehtari et al. 2021) ACROSS the ensembles: chain = ensemble.
     The walkers of one ensemble are not independent chains (the ensemble moves couple them), so
     R-hat across walkers is not valid. Each ensemble's draws are its post-burn-in, thinned
     states, collapsed over the walkers in two orders: for R-hat step-major (the walkers of one
     step, then the next step), so the split halves compare early with late steps and a drift
     shows; for ESS walker-major (one walker's steps, then the next walker's), so the
     autocorrelation ArviZ estimates along the draws is each walker's own over time (step-major
     would put independent-looking neighbouring walkers side by side and overstate the ESS);
  4. the mean acceptance fraction of every ensemble in [acceptance_min, acceptance_max]
     (the DE and stretch moves' healthy range is about 0.2-0.5).
Burn-in = 2 max τ steps and thinning = max(1, min τ / 2) (emcee's guidance), both from the
measured τ; when τ is unusable (not finite, or burn-in beyond half the chain) half the chain is
burnt and nothing thinned, and the run is not converged.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np
from scipy.special import expit, logit

from sgdr.observe.silhouette import discrepancy

# The independence proposals' defensive component: this share of them come from one wide Gaussian
# (the pooled pilot's mean, its covariance scaled by DEFENSIVE_SCALE^2), so that no region a walker
# can reach has a vanishing proposal density. Without it a walker that wandered in the pilot into a
# small mode the mixture left out stays there (the independence ratio q(x)/q(x') is tiny) and the
# bulk ESS falls to the number of walkers (cream s0 at small: 45; docs/posterior.md).
DEFENSIVE_SHARE = 0.1
DEFENSIVE_SCALE = 2.0


@dataclass
class Problem:
    """The sampled parameters, their priors and the MAP they start from."""

    names: list  # [D]
    low: np.ndarray  # [D]
    high: np.ndarray  # [D]
    map_theta: np.ndarray  # [D]

    @staticmethod
    def from_config(asset, post_cfg) -> Problem:
        """The MAP of each parameter from the asset: shift 0, identified κ, μ, e, physics.zeta0.
        A MAP outside its prior raises ValueError naming posterior.priors.<name>."""
        identified = {
            "log10_k_shift": 0.0,
            "kappa": float(asset.values["kappa"]),
            "friction": float(asset.values["friction"]),
            "restitution": float(asset.values["restitution"]),
            "zeta0": float(asset.values.get("zeta0", asset.physics.zeta0)),
        }
        names = list(post_cfg.parameters)
        low = np.array([float(getattr(post_cfg.priors, n)[0]) for n in names])
        high = np.array([float(getattr(post_cfg.priors, n)[1]) for n in names])
        theta = np.array([identified[n] for n in names])
        for n, lo, hi, t in zip(names, low, high, theta):
            if not lo <= t <= hi:
                raise ValueError(
                    f"posterior.priors.{n}={[lo, hi]} excludes the run's identified value {t:.4g}: widen the prior"
                )
        return Problem(names, low, high, theta)

    def inside(self, thetas: np.ndarray) -> np.ndarray:
        return np.all((thetas >= self.low) & (thetas <= self.high), axis=1)

    def samples(self, thetas: np.ndarray) -> dict:
        """The rollout contract's per-sample dict from θ [S, D]."""
        return {n: np.asarray(thetas[:, j], float) for j, n in enumerate(self.names)}


class LogProbability:
    """log p(θ) for a batch of walkers θ [W, D] -> [W] (uniform prior + silhouette likelihood).

    rollout_fn(samples) -> (positions [S, T_fit, N_A, 3], stable [S]); centre_map: anchor
    positions -> centres; frames: the observation's frame indices into the rollout."""

    def __init__(self, problem: Problem, rollout_fn, centre_map, likelihood):
        self.problem, self.rollout_fn, self.centre_map, self.likelihood = problem, rollout_fn, centre_map, likelihood
        self._discrepancy = discrepancy
        self.calls = 0  # rollouts run (the cost)
        self.unstable = 0

    def discrepancies(self, thetas: np.ndarray) -> np.ndarray:
        """D [S, V, F] of θ [S, D] (NaN for an unstable rollout)."""
        positions, stable = self.rollout_fn(self.problem.samples(thetas))
        self.calls += len(thetas)
        self.unstable += int(np.sum(~np.asarray(stable)))
        frames = self.likelihood.obs.frames
        centres = self.centre_map(positions[:, frames])
        d = self._discrepancy(self.likelihood.obs, np.nan_to_num(centres, nan=0.0))
        d[~np.asarray(stable, bool)] = np.nan
        return d

    def __call__(self, thetas: np.ndarray) -> np.ndarray:
        thetas = np.atleast_2d(np.asarray(thetas, float))
        out = np.full(thetas.shape[0], -np.inf)
        ok = self.problem.inside(thetas)
        if ok.any():
            out[ok] = self.likelihood.log_likelihood(self.discrepancies(thetas[ok]))
        return out


def initial_walkers(problem: Problem, n_walkers: int, init_ball: float, rng) -> np.ndarray:
    """[W, D]: MAP + init_ball x prior width x N(0, 1), clipped 1e-3 of the width inside the prior
    (a MAP on a prior edge, e.g. restitution 0, would otherwise put half the walkers outside)."""
    width = problem.high - problem.low
    p0 = problem.map_theta + init_ball * width * rng.standard_normal((n_walkers, len(problem.names)))
    return np.clip(p0, problem.low + 1e-3 * width, problem.high - 1e-3 * width)


def moves(name: str):
    """emcee's proposal for `posterior.moves`: None (emcee's stretch move) or the DE move."""
    import emcee

    if name == "stretch":
        return None
    if name == "de":
        # differential evolution alone (ter Braak 2006): it updates half the ensemble per call,
        # always the same batch width, which the frozen rollouts replay; emcee's snooker variant
        # splits the ensemble in four (widths alternating 3 and 2 at 10 walkers), which made them
        # record again on every call
        return emcee.moves.DEMove()
    raise ValueError(f"posterior.moves={name!r}: expected 'stretch' or 'de'")


def fit_mixture(z: np.ndarray, seed: int, max_components: int = 8):
    """The Gaussian mixture (full covariances; 1 to `max_components` components, the lowest BIC) of
    pilot draws z [N, D] in the space the walkers move in. At most 8000 draws, evenly strided."""
    from sklearn.mixture import GaussianMixture

    z = np.asarray(z, float)
    z = z[np.all(np.isfinite(z), axis=1)]
    z = z[:: max(1, len(z) // 8000)]
    best, best_bic = None, np.inf
    for k in range(1, min(int(max_components), max(1, len(z) // (4 * z.shape[1] + 4))) + 1):
        gm = GaussianMixture(k, covariance_type="full", reg_covar=1e-4, random_state=int(seed)).fit(z)
        bic = gm.bic(z)
        if bic < best_bic:
            best, best_bic = gm, bic
    return best


class MixtureMove:
    """Independence proposals from a fixed Gaussian mixture (`fit_mixture` of a pilot run, its
    covariances inflated by `inflate`^2 so that its tails reach beyond the pilot's): every walker
    proposes a draw of the mixture, accepted with the independence sampler's Metropolis-Hastings
    ratio p(x') q(x) / (p(x) q(x')). The mixture stays fixed while the chains run, so they keep
    their target. `defensive` = (share, mean, covariance): one more component, this share of the
    proposals, wide enough to reach every mode (`DEFENSIVE_SHARE`). Why: the rendered posteriors
    of the small objects are often multimodal (the cream's stiffness shift has three modes,
    correlated 0.96 with κ); differential evolution
    there proposes mostly between modes and accepts 8-15%, with τ of 100-1300 steps, where a
    proposal that knows the modes jumps between them in one step (docs/posterior.md)."""

    def __init__(self, mixture, inflate: float = 1.5, defensive: tuple | None = None):
        import emcee

        weights = np.asarray(mixture.weights_, float)
        means = np.asarray(mixture.means_, float)
        covs = np.asarray(mixture.covariances_, float) * float(inflate) ** 2
        if defensive is not None:
            share, mean, cov = defensive
            weights = np.append(weights * (1.0 - float(share)), float(share))
            means = np.vstack([means, np.asarray(mean, float)[None]])
            covs = np.concatenate([covs, np.asarray(cov, float)[None]])
        self.weights = weights / weights.sum()
        self.means = means
        self.chol = np.linalg.cholesky(covs)
        self.move = emcee.moves.MHMove(self._propose)

    def log_density(self, x: np.ndarray) -> np.ndarray:
        from scipy.special import logsumexp

        x = np.atleast_2d(x)
        d = x.shape[1]
        terms = []
        for w, mu, chol in zip(self.weights, self.means, self.chol, strict=True):
            r = np.linalg.solve(chol, (x - mu).T).T
            terms.append(
                np.log(w) - 0.5 * np.sum(r**2, axis=1) - np.sum(np.log(np.diag(chol))) - 0.5 * d * np.log(2 * np.pi)
            )
        return logsumexp(np.stack(terms), axis=0)

    def draw(self, n: int, random) -> np.ndarray:
        comp = random.choice(len(self.weights), size=int(n), p=self.weights)
        return self.means[comp] + np.einsum("nij,nj->ni", self.chol[comp], random.randn(int(n), self.means.shape[1]))

    def _propose(self, x0: np.ndarray, random):
        q = self.draw(len(x0), random)
        return q, self.log_density(x0) - self.log_density(q)


class LogitSpace:
    """The box prior's interior mapped onto R^D: z = logit((θ - low) / (high - low)). A uniform
    prior in θ is the logistic density in z (the Jacobian), smooth and without walls, which
    the ensemble moves cross far faster than a box whose edges reject every proposal beyond them
    (Stan maps bounded parameters the same way). Chains are returned in θ."""

    def __init__(self, problem: Problem):
        self.low, self.width = problem.low, problem.high - problem.low

    def to_theta(self, z: np.ndarray) -> np.ndarray:
        return self.low + self.width * expit(z)

    def to_z(self, theta: np.ndarray) -> np.ndarray:
        return logit((np.asarray(theta, float) - self.low) / self.width)

    def log_jacobian(self, z: np.ndarray) -> np.ndarray:
        """log |dθ/dz| summed over the parameters, [S]."""
        z = np.atleast_2d(z)
        return np.sum(np.log(self.width) - np.logaddexp(0.0, z) - np.logaddexp(0.0, -z), axis=1)

    def log_prob(self, log_prob):
        return lambda z: log_prob(self.to_theta(np.atleast_2d(z))) + self.log_jacobian(z)


def run_ensembles(
    log_prob,
    problem: Problem,
    n_walkers,
    n_steps,
    n_ensembles,
    init_ball,
    seed=0,
    progress=False,
    move="stretch",
    space="box",
    start=None,
    independence=0.0,
    pilot_steps=0,
):
    """(chains [E, steps, W, D], log_probs [E, steps, W], acceptance [E, W]) from `n_ensembles`
    independent emcee ensembles, seeds seed, seed+1, ...; move: `posterior.moves`; space:
    `posterior.space` ("box": θ itself; "logit": `LogitSpace`, chains and log p returned in θ);
    start: (n_walkers, rng) -> [W, D] initial walkers in θ (e.g. the surrogate's `design_start`),
    default `initial_walkers` around the MAP.

    independence > 0 (for cheap targets such as the surrogate: `posterior.surrogate.independence`):
    every ensemble first runs `pilot_steps` with `move` alone; a Gaussian mixture is fitted to the
    second halves of all pilots (`fit_mixture`, plus the defensive wide component) and each
    ensemble then goes on from its pilot's last state for `n_steps` with `move` and, this share of
    the steps, the mixture's independence proposals (`MixtureMove`). Only those `n_steps` are
    returned."""
    import emcee

    if space not in ("box", "logit"):
        raise ValueError(f"posterior.space={space!r}: expected 'box' or 'logit'")
    if not 0.0 <= float(independence) < 1.0:
        raise ValueError(f"posterior.surrogate.independence={independence!r}: expected a share in [0, 1)")
    if float(independence) > 0 and int(pilot_steps) < 2:
        raise ValueError(f"posterior.surrogate.pilot_steps={pilot_steps!r}: independence proposals need a pilot run")
    mapped = LogitSpace(problem) if space == "logit" else None
    target = mapped.log_prob(log_prob) if mapped else log_prob

    starts = []
    for e in range(int(n_ensembles)):
        rng = np.random.default_rng(int(seed) * 1000 + e)
        p0 = (
            initial_walkers(problem, int(n_walkers), float(init_ball), rng)
            if start is None
            else start(int(n_walkers), rng)
        )
        starts.append(mapped.to_z(p0) if mapped else p0)
    step_moves = moves(move)
    if float(independence) > 0:
        pilots = []
        for e, p0 in enumerate(starts):
            sampler = emcee.EnsembleSampler(
                int(n_walkers), len(problem.names), target, vectorize=True, moves=moves(move)
            )
            sampler.random_state = np.random.RandomState(int(seed) * 1000 + 500 + e).get_state()
            sampler.run_mcmc(p0, int(pilot_steps))
            pilots.append(sampler.get_chain())
            starts[e] = sampler.get_chain()[-1]
        pooled = np.concatenate([c[c.shape[0] // 2 :].reshape(-1, c.shape[-1]) for c in pilots])
        wide = (
            DEFENSIVE_SHARE,
            pooled.mean(axis=0),
            np.cov(pooled.T) * DEFENSIVE_SCALE**2 + 1e-4 * np.eye(pooled.shape[1]),
        )
        mixture = MixtureMove(fit_mixture(pooled, seed), defensive=wide)
        base = step_moves if step_moves is not None else emcee.moves.StretchMove()
        step_moves = [(base, 1.0 - float(independence)), (mixture.move, float(independence))]

    chains, lps, acc = [], [], []
    for e, p0 in enumerate(starts):
        sampler = emcee.EnsembleSampler(int(n_walkers), len(problem.names), target, vectorize=True, moves=step_moves)
        sampler.random_state = np.random.RandomState(int(seed) * 1000 + e).get_state()
        if progress:
            from tqdm import tqdm

            bar = tqdm(total=int(n_steps), desc=f"ensemble {e + 1}/{n_ensembles}", unit="step", leave=False)
            for _ in sampler.sample(p0, iterations=int(n_steps)):
                bar.update(1)
            bar.close()
        else:
            sampler.run_mcmc(p0, int(n_steps))
        chain, lp = sampler.get_chain(), sampler.get_log_prob()
        if mapped:
            lp = lp - mapped.log_jacobian(chain.reshape(-1, chain.shape[-1])).reshape(lp.shape)
            chain = mapped.to_theta(chain)
        chains.append(chain)
        lps.append(lp)
        acc.append(sampler.acceptance_fraction)
    return np.stack(chains), np.stack(lps), np.stack(acc)


def _finite_or_none(x):
    x = float(x)
    return x if math.isfinite(x) else None


def diagnose(chains: np.ndarray, names: list, post_cfg, acceptance: np.ndarray) -> dict:
    """The convergence diagnostics and verdict of chains [E, steps, W, D] (module docstring).

    Returns a JSON-ready dict: tau [E][D], tau_max, burn_in, thin, chain_over_tau, rhat, ess_bulk,
    ess_tail (per name), acceptance [E], the pooled kept samples' median / q05 / q95 per name,
    n_kept, converged, failed (one sentence per failed criterion), failed_criteria (their names:
    stuck, tau_unknown, tau, rhat, ess, acceptance)."""
    import arviz as az
    import emcee

    n_ens, n_steps, n_walk, dim = chains.shape
    tau = np.full((n_ens, dim), np.nan)
    stuck = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # quiet=True still warns; the criterion below says it
        for e in range(n_ens):
            for j in range(dim):
                # walkers whose chain never changed have no autocorrelation (0/0); emcee's
                # walker average would turn one of them into a NaN τ
                moved = np.ptp(chains[e, :, :, j], axis=0) > 0
                if moved.any():
                    tau[e, j] = emcee.autocorr.integrated_time(chains[e][:, moved, j : j + 1], quiet=True)[0]
                if moved.sum() < n_walk:
                    stuck.append(f"ensemble {e + 1} {names[j]}: {n_walk - int(moved.sum())} of {n_walk}")
    failed, kinds = [], []  # one sentence per failed criterion, and its name (`failed_criteria`)
    tau_ok = bool(np.all(np.isfinite(tau)) and np.all(tau > 0))
    tau_max = float(np.max(tau)) if tau_ok else float("nan")
    if tau_ok:
        burn, thin = int(math.ceil(2 * tau_max)), max(1, int(0.5 * float(np.min(tau))))
    if not tau_ok or burn > n_steps // 2:
        burn, thin = n_steps // 2, 1
    if stuck:
        failed.append("walkers that never moved (no accepted step): " + ", ".join(stuck))
        kinds.append("stuck")
    if not tau_ok:
        failed.append("the autocorrelation time τ could not be estimated for every parameter and ensemble")
        kinds.append("tau_unknown")
    elif n_steps < post_cfg.tau_factor * tau_max:
        failed.append(
            f"chains of {n_steps} steps are {n_steps / tau_max:.1f} τ long (max τ = {tau_max:.1f} steps), "
            f"need >= {post_cfg.tau_factor:g} τ (posterior.n_steps >= {math.ceil(post_cfg.tau_factor * tau_max)})"
        )
        kinds.append("tau")
    kept = chains[:, burn::thin]  # [E, K, W, D]
    draws = kept.reshape(n_ens, -1, dim)  # step-major: the walkers of one step, then the next step
    by_walker = kept.transpose(0, 2, 1, 3).reshape(n_ens, -1, dim)  # walker-major: one walker's steps, then the next
    step_major = az.from_dict(posterior={n: draws[..., j] for j, n in enumerate(names)})
    walker_major = az.from_dict(posterior={n: by_walker[..., j] for j, n in enumerate(names)})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rhat = az.rhat(step_major, method="rank")
        ess_bulk = az.ess(walker_major, method="bulk")
        ess_tail = az.ess(walker_major, method="tail")
    rhat = {n: float(rhat[n].values) for n in names}
    ess_bulk = {n: float(ess_bulk[n].values) for n in names}
    ess_tail = {n: float(ess_tail[n].values) for n in names}
    bad_r = [f"{n} {rhat[n]:.3f}" for n in names if not rhat[n] <= post_cfg.rhat_max]
    if bad_r:
        failed.append(f"R-hat above {post_cfg.rhat_max:g} across the ensembles: {', '.join(bad_r)}")
        kinds.append("rhat")
    bad_e = [
        f"{n} {min(ess_bulk[n], ess_tail[n]):.0f}"
        for n in names
        if not min(ess_bulk[n], ess_tail[n]) >= post_cfg.ess_min
    ]
    if bad_e:
        failed.append(f"ESS (bulk or tail) below {post_cfg.ess_min:g}: {', '.join(bad_e)}")
        kinds.append("ess")
    acc = np.asarray(acceptance, float).mean(axis=1)  # [E]
    bad_a = [
        f"ensemble {e + 1} {a:.2f}"
        for e, a in enumerate(acc)
        if not post_cfg.acceptance_min <= a <= post_cfg.acceptance_max
    ]
    if bad_a:
        failed.append(
            f"acceptance fraction outside [{post_cfg.acceptance_min:g}, {post_cfg.acceptance_max:g}]: {', '.join(bad_a)}"
        )
        kinds.append("acceptance")
    pooled = draws.reshape(-1, dim)
    q05, q50, q95 = np.percentile(pooled, [5, 50, 95], axis=0)
    return {
        "names": list(names),
        "n_ensembles": int(n_ens),
        "n_walkers": int(n_walk),
        "n_steps": int(n_steps),
        "tau": [[_finite_or_none(t) for t in row] for row in tau],
        "tau_max": _finite_or_none(tau_max),
        "chain_over_tau": _finite_or_none(n_steps / tau_max) if tau_ok else None,
        "burn_in": int(burn),
        "thin": int(thin),
        "n_kept": int(pooled.shape[0]),
        "rhat": {n: _finite_or_none(v) for n, v in rhat.items()},
        "ess_bulk": {n: _finite_or_none(v) for n, v in ess_bulk.items()},
        "ess_tail": {n: _finite_or_none(v) for n, v in ess_tail.items()},
        "acceptance": [float(a) for a in acc],
        "median": {n: float(q50[j]) for j, n in enumerate(names)},
        "q05": {n: float(q05[j]) for j, n in enumerate(names)},
        "q95": {n: float(q95[j]) for j, n in enumerate(names)},
        "converged": not failed,
        "failed": failed,
        "failed_criteria": kinds,
    }


def longer_chains(diag: dict, post_cfg, cap: int) -> int | None:
    """How many steps chains need that `diag` found too short, or None when length cannot help (a
    criterion other than τ, R-hat and ESS failed, τ could not be estimated, the chains already
    reach `cap`, or nothing failed). The τ criterion asks for 1.2 x tau_factor x τ; an ESS short of
    ess_min for its ratio (ESS grows with the length) x 1.2; an R-hat alone for twice the length;
    at least 1.5 x the length (τ estimated on short chains is itself short), at most `cap`."""
    n = int(diag["n_steps"])
    if diag["converged"] or n >= int(cap) or diag["tau_max"] is None:
        return None
    if not set(diag["failed_criteria"]) <= {"tau", "rhat", "ess"}:
        return None
    need = 1.5 * n
    if n < post_cfg.tau_factor * diag["tau_max"]:
        need = max(need, 1.2 * post_cfg.tau_factor * diag["tau_max"])
    ess = [min(diag["ess_bulk"][k] or 0.0, diag["ess_tail"][k] or 0.0) for k in diag["names"]]
    if min(ess) < post_cfg.ess_min:
        need = max(need, 1.2 * n * post_cfg.ess_min / max(min(ess), 1.0))
    if any(r is None or r > post_cfg.rhat_max for r in diag["rhat"].values()):
        need = max(need, 2.0 * n)
    return int(min(math.ceil(need), int(cap)))


def kept_samples(chains: np.ndarray, diag: dict) -> np.ndarray:
    """[N, D] the pooled post-burn-in, thinned samples `diag` summarised."""
    return chains[:, diag["burn_in"] :: diag["thin"]].reshape(-1, chains.shape[-1])


def headline(diag: dict) -> str:
    """The first line of the report section: 'Not converged: ...' when any criterion failed."""
    if diag["failed"]:
        return "Not converged: " + "; ".join(diag["failed"]) + ". The intervals below are not a posterior to rely on."
    return (
        f"Converged: {diag['n_ensembles']} ensembles of {diag['n_walkers']} walkers, chains "
        f"{diag['chain_over_tau']:.0f} τ long, R-hat <= {max(v for v in diag['rhat'].values()):.3f}, "
        f"ESS >= {min(min(diag['ess_bulk'].values()), min(diag['ess_tail'].values())):.0f}."
    )
