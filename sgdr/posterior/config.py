"""Typed config schema of the posterior (group key `posterior`, experiments/posterior.py).

The method (priors, likelihood, tempering, convergence criteria) is written out in
conf/posterior/default.yaml; the presets set only the sizes (walkers, steps, ensembles, views,
points), which change how much is computed, not what.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from sgdr.checks import Check, any_text, at_least, between, choice, list_of, non_negative, positive, vector
from sgdr.posterior.surrogate import SurrogateConfig

# the sampled parameters a posterior may include (sgdr.posterior.rollouts.SAMPLE_KEYS without v0)
PARAMETERS = ("log10_k_shift", "kappa", "friction", "restitution", "zeta0")


@dataclass
class PriorConfig:
    """Uniform (box) priors [low, high] of the sampled parameters. log10_k_shift is added to every
    anchor's identified log10 k_i; the others replace the identified value."""

    log10_k_shift: list = field(default_factory=lambda: [-1.0, 1.0])  # decades around the identified field
    kappa: list = field(default_factory=lambda: [-4.0, 4.0])  # soft vector κ (softplus(κ) is used)
    friction: list = field(default_factory=lambda: [0.0, 1.0])  # μ (coulomb: coefficient; project: factor)
    restitution: list = field(default_factory=lambda: [0.0, 1.0])  # e (acts only with physics.contact=coulomb)
    zeta0: list = field(default_factory=lambda: [0.0, 1.0])  # damping ζ0 (only when sampled)


@dataclass
class PosteriorConfig:
    run: str = "outputs/torus_small_s0"  # the finished run folder (holds asset/ and report/)
    sequence: str = ""  # the observed sequence ("" = the run's own, from its RUN.json); e.g. a twin
    out_dir: str = ""  # where posterior.json, samples.npz and plots go ("" = <run>/posterior)
    parameters: list = field(default_factory=lambda: ["log10_k_shift", "kappa", "friction", "restitution"])
    priors: PriorConfig = field(default_factory=PriorConfig)
    rollout: str = "batched"  # how the walkers' samples are simulated: "batched" (one program) | "loop" (reference)
    # likelihood (sgdr.posterior.likelihood): "rendered" (the identification's image loss of every view-frame,
    # RenderedLikelihood) | "silhouette" (projected centres against the silhouettes, SilhouetteLikelihood)
    likelihood: str = "rendered"
    image_scale: int = 0  # rendered: images downscaled by this (0 = the run's recon.search.image_scale, else 1)
    loss_floor: float = 1.0e-4  # rendered: the smallest per-image noise scale
    # how the posterior is sampled: "surrogate" (a GP of log L refined at the chains' draws and checked
    # there, sgdr.posterior.surrogate) | "emcee" (the ensembles on the likelihood itself)
    sampler: str = "surrogate"
    surrogate: SurrogateConfig = field(default_factory=SurrogateConfig)
    n_views: int = 0  # views used, evenly spaced (0 = all)
    frame_stride: int = 1  # every frame_stride-th fit frame (frame 0, the rest state, is never used)
    n_points: int = 256  # bound Gaussian centres projected per sample (seeded subset; 0 = all)
    n_mask_points: int = 128  # silhouette pixels per view and frame for the coverage term
    sigma_floor_px: float = 0.5  # noise scale floor, pixels (the pixel grid's quantisation)
    temperature: float = 1.0  # extra tempering on top of the per-view-frame normalisation (>= 1 flattens)
    # sampling (sgdr.posterior.sample)
    n_walkers: int = 16  # walkers per ensemble (>= 2 x parameters)
    n_steps: int = 400  # steps per ensemble
    n_ensembles: int = 4  # independent ensembles (R-hat and ESS across them)
    init_ball: float = 0.05  # walkers start MAP + init_ball x prior width x N(0, 1)
    # emcee's proposal (sgdr.posterior.sample.moves): "stretch" (Goodman & Weare, emcee's default) or
    # "de" (differential evolution, ter Braak 2006)
    moves: str = "de"
    # where the walkers move: "box" (θ, the prior's edges reject) or "logit" (each θ mapped from its
    # prior box onto the real line, sgdr.posterior.sample.LogitSpace)
    space: str = "logit"
    # convergence criteria
    tau_factor: float = 50.0  # chains must be >= tau_factor x the integrated autocorrelation time
    rhat_max: float = 1.01  # rank-normalised split R-hat across ensembles, every parameter
    ess_min: float = 400.0  # bulk and tail ESS across ensembles, every parameter
    acceptance_min: float = 0.15  # mean acceptance fraction of every ensemble in [min, max]
    acceptance_max: float = 0.75
    # posterior predictive
    n_predictive: int = 32  # posterior draws rolled out over every frame for the bands
    # the forecast's model discrepancy (sgdr.posterior.forecast): the misfit measured on the fit frames,
    # growing by discrepancy_growth object sizes per second after them; band_level: the predictive ball's level
    discrepancy_growth: float = 0.0
    # discrepancy_offset: the discrepancy's mean is the offset between the observed and the rendered
    # point prediction's silhouettes at the last fit frame (triangulated over the views), held over the
    # future, its noise their scatter about it; false: no mean, the noise the projected centres' misfit
    discrepancy_offset: bool = False
    band_level: float = 0.9
    # ensemble: finished posteriors of other runs of the same sequence (reconstructions at other seeds), combined
    # with posterior.run's into one predictive ball (sgdr.posterior.ensemble) instead of sampling;
    # ensemble_growth: its discrepancy growth (object sizes per second)
    ensemble: list = field(default_factory=list)
    ensemble_growth: float = 0.0


PRIOR_CHECKS = {name: vector(2) for name in PARAMETERS}
SURROGATE_CHECKS = {
    "n_initial": at_least(0),
    "n_sobol": at_least(0),
    "n_validate": at_least(8, "PSIS needs a few draws to fit its tail"),
    "max_rounds": at_least(1),
    "chain_steps": at_least(100),
    "clip": positive(),
    "inside_min": between(0.0, 1.0, lo_open=True),
    "search_other_sequence": choice((True, False)),
    "start_within": positive(),
    "edge_points": Check(lambda x: isinstance(x, int) and (x == 0 or x >= 2), "must be 0 (no edge probes) or >= 2"),
    "edge_within": positive(),
    "climb": Check(
        lambda x: isinstance(x, int) and (x == 0 or x >= 8), "must be 0 (no climb) or >= 8 (one generation)"
    ),
    "independence": between(0.0, 1.0, hi_open=True),
    "pilot_steps": at_least(2, "the mixture of the independence proposals is fitted to the pilot's second half"),
}

DESIGN_SEARCH_CHECKS = {
    "initial_samples": non_negative("0: CMA-ES starts at the asset's values"),
    "generations": at_least(1),
    "line_points": non_negative("0: no coordinate sweep"),
    "frame_schedule": list_of(between(0.0, 1.0, lo_open=True), min_len=1),
    "level": choice("sgdr.identify.global_search:LEVELS"),
    "starts": at_least(1),
    "contact_points": non_negative("0: no contact grid"),
    "start_distance": positive(),
}

CHECKS: dict[str, Check] = {
    "run": any_text("a finished run folder"),
    "sequence": any_text("an observed sequence folder; empty: the run's own"),
    "out_dir": any_text("the output folder; empty: <run>/posterior"),
    "parameters": list_of(choice(PARAMETERS), min_len=1),
    "rollout": choice("sgdr.posterior.rollouts:ROLLOUTS"),
    "likelihood": choice(("rendered", "silhouette")),
    "image_scale": at_least(0, "0: the run's recon.search.image_scale"),
    "loss_floor": positive(),
    "sampler": choice(("surrogate", "emcee")),
    "n_views": at_least(0, "0: all views"),
    "frame_stride": at_least(1),
    "n_points": at_least(0, "0: every centre"),
    "n_mask_points": at_least(1),
    "sigma_floor_px": positive(),
    "temperature": at_least(1.0, "1: no tempering beyond the per-view-frame normalisation"),
    "n_walkers": at_least(4),
    "n_steps": at_least(2),
    "n_ensembles": at_least(2, "R-hat needs several independent ensembles; the issue asks for >= 4"),
    "init_ball": between(0.0, 0.5, lo_open=True),
    "moves": choice(("stretch", "de")),
    "space": choice(("box", "logit")),
    "tau_factor": positive(),
    "rhat_max": at_least(1.0),
    "ess_min": positive(),
    "acceptance_min": between(0.0, 1.0),
    "acceptance_max": between(0.0, 1.0),
    "n_predictive": at_least(1),
    "discrepancy_growth": at_least(0.0, "object sizes per second; 0: the fit frames' misfit, not growing"),
    "band_level": between(0.0, 1.0, lo_open=True),
    "ensemble": list_of(any_text("a finished run folder with posterior/posterior.json")),
    "ensemble_growth": at_least(0.0, "object sizes per second"),
}


def rule_problem(c: PosteriorConfig) -> str | None:
    """Rules between the posterior's fields: each prior's low < high, the acceptance window
    non-empty, enough walkers for the sampled parameters (emcee's stretch move needs > 2 x dim)."""
    for name in PARAMETERS:
        lo, hi = getattr(c.priors, name)
        if not lo < hi:
            return f"posterior.priors.{name}={[lo, hi]}: the low end must be < the high end"
    if not c.acceptance_min < c.acceptance_max:
        return f"posterior.acceptance_min={c.acceptance_min} must be < posterior.acceptance_max={c.acceptance_max}"
    if c.n_walkers < 2 * len(c.parameters) + 1:
        return (
            f"posterior.n_walkers={c.n_walkers} must be > 2 x the {len(c.parameters)} sampled parameters "
            f"(posterior.parameters={list(c.parameters)})"
        )
    if len(set(c.parameters)) != len(c.parameters):
        return f"posterior.parameters={list(c.parameters)} names a parameter twice"
    return None
