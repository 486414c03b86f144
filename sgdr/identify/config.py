"""Typed config schema of the reconstruction pipeline (group key `recon`)."""

from __future__ import annotations

from dataclasses import dataclass, field

from sgdr.asset.config import SimulateConfig
from sgdr.checks import (
    Check,
    at_least,
    between,
    choice,
    finite,
    folder_name,
    list_of,
    non_empty_text,
    non_negative,
    positive,
    vector,
)

#                                   speed change, scene units / s (see sgdr.asset.momentum)


@dataclass
class SearchConfig:
    """The dynamic stage's global search (sgdr.identify.global_search): CMA-ES over the global
    parameters, each candidate scored by its open-loop rollout of all fit frames, rendered on all
    views at the prediction's n_t. The method sets what is searched, the preset how much."""

    parameters: list[str] = field(default_factory=list)  # searched: log10_k (one level), kappa, friction,
    #   restitution, region_contrast, region_theta, region_phi, region_offset (two regions of different
    #   stiffness split by a plane; sgdr.identify.global_search); those the physics lacks are skipped;
    #   empty = no search (start at physics.*_init, or the best of recon.log10_k_grid)
    log10_k_range: list[float] = field(default_factory=lambda: [1.5, 5.5])  # capped by the stability bound at n_t
    kappa_range: list[float] = field(default_factory=lambda: [-4.0, 4.0])
    friction_range: list[float] = field(default_factory=lambda: [0.0, 1.0])
    restitution_range: list[float] = field(default_factory=lambda: [0.0, 0.9])
    region_contrast_range: list[float] = field(default_factory=lambda: [-1.5, 1.5])  # decades between the two regions
    region_theta_range: list[float] = field(default_factory=lambda: [0.0, 3.1416])  # the plane's normal, polar angle
    region_phi_range: list[float] = field(
        default_factory=lambda: [0.0, 3.1416]
    )  # its azimuth (n and -n with -c are one split)
    region_offset_range: list[float] = field(
        default_factory=lambda: [-0.3, 0.3]
    )  # the plane's distance from the centre, sizes
    sigma0: float = 0.3  # CMA-ES's initial step, in units of each range
    popsize: int = 8  # candidates per generation (one batched rollout)
    generations: int = 10
    initial_samples: int = 0  # scrambled Sobol points over the whole box scored first; CMA-ES starts at their best
    #                           (0: CMA-ES starts at physics.*_init)
    image_scale: int = 1  # candidates are scored on images downscaled by this (k x k block means)
    # the search's stages: each scores the rollouts on this share of the fit frames after frame 0 (the
    # earliest ones), the generations split evenly among them, CMA-ES carried on from one to the next;
    # the last is 1 (the whole window). On a twin the loss over the first half of the window is a
    # wide bowl around the truth where the whole window's is a needle on a plateau
    # (docs/posterior.md, "SBC at small"); [1.0] = one stage
    frame_schedule: list[float] = field(default_factory=lambda: [1.0])
    # before each stage's CMA-ES, a coordinate sweep from its start: each parameter in turn over
    # this many evenly spread values of its whole range (the others at the best so far; one batched
    # rollout each), the best moving the start. A later window sees what the earlier one could not
    # (the bounce's restitution) where the earlier stage left it anywhere (docs/posterior.md,
    # "SBC at small"); 0 = none
    line_points: int = 0
    # the level's search coordinate: "mean" (log10 k itself) | "effective" (log10 k plus the soft
    # vector's effect on the anchors' mean stiffness, `level_offsets`: κ moves at a fixed stiffness).
    # The first frames see the stiffness, so the level and κ trade off along a diagonal valley there
    # that CMA-ES walks slowly (docs/posterior.md, "The SBC's misses up close")
    level: str = "mean"
    # the last window's CMA-ES runs from this many starts side by side: the previous window's best and
    # the best of its other regions, start_distance apart in the unit box; the worse half stops after
    # each phase (`halving_phases`). The whole window's basins are narrow and lie behind valleys that
    # one local search does not cross (docs/posterior.md, "The SBC's fourth draw"); 1 = one search
    starts: int = 1
    start_distance: float = 0.2
    # friction and restitution swept together on a contact_points x contact_points grid after each
    # coordinate sweep (`contact_grid`); 0 = none
    contact_points: int = 0
    images_per_call: int = 200  # rendered and scored together (sgdr.render.splat.render_batch); 1 = one at a time
    top_k: int = 5  # candidates whose futures the report compares (within equivalent_tolerance of the best)
    equivalent_tolerance: float = 0.05  # relative loss within which candidates count as fitting equally well
    spread_warning: float = 0.25  # warn when their predicted centres of mass part by more than this x the size
    choose: str = "best"  # the local stage's start: "best" (the lowest loss) | "medoid" (of the equally good
    #                       candidates, the one whose predicted future is nearest the others')


@dataclass
class ReconConfig:
    model: str = "spring_mass"  # the dynamic model (set by the method): spring_mass (Spring-Gaus) | pacnerf | ...
    #                             (sgdr.pipeline.run.MODELS; docs/baselines.md)
    iterations: int = 200  # dynamic-reconstruction passes over the fit frames
    lambda_dssim: float = 0.05  # λ of the dynamic loss
    substep_growth: list[float] = field(default_factory=lambda: [1.0, 1.5, 2.0])  # n_t = physics.n_substeps x
    #   these factors, split into equal spans over the passes (official: 100 -> 150 -> 200)
    cameras_per_frame: int = 1  # random cameras rendered per frame (official: 1)
    lr_log10_k: float = 1e-2  # Adam, per-anchor log10 k_i
    lr_kappa: float = 1e-2  # Adam, soft vector κ
    lr_friction: float = 1e-2  # Adam, ground friction
    lr_restitution: float = 1e-2  # Adam, restitution (coulomb contact)
    lr_v0: float = 5e-2  # Adam, initial velocity (scene units / s per step, roughly)
    v0_iterations: int = 100  # Adam steps of the initial-velocity stage
    refine_iterations: int = 300  # Adam steps refining scale, colour, opacity at IDW positions
    force: bool = False  # redo stages whose outputs exist
    share_stages: bool = True  # copy a stage with the same key (config, seed, data, inputs) from another run folder
    #                            of the same sequence beside this one (e.g. the static fit another method made)
    # ---- added by the pipeline (issue 6)
    mode: str = "truncated"  # "truncated" (official: per frame, detached state, Adam step per
    #                          frame, one random camera) | "full" (backprop through all fit
    #                          frames, one Adam step per pass, cameras_per_frame cameras each)
    lr_scale: float = 5e-3  # Adam, log scales during the refinement (frame 0)
    lr_color: float = 2.5e-2  # Adam, colour logits during the refinement
    lr_opacity: float = 5e-2  # Adam, opacity logits during the refinement
    refine_lambda_dssim: float = 0.2  # λ of the refinement loss (as the static fit)
    v0_lambda_dssim: float = 0.05  # λ of the initial-velocity loss
    v0_views_per_step: int = 1  # random views rendered per free-fall frame and v0 step (0 = all)
    log10_k_grid: list[float] = field(default_factory=list)  # uniform log10 k values scored by the
    #   deterministic all-view rollout loss before training; the best one replaces
    #   physics.log10_k_init as the start (empty = start at physics.log10_k_init)
    stiffness: str = "per_anchor"  # what the dynamic stage optimises for log10 k: "per_anchor" (one k_i
    #   per anchor, the paper's) | "global" (the single-k ablation: one log10 k shared by every anchor)
    log10_k_min: float = 0.0  # log10 k_i is clamped to [min, max] after each step
    log10_k_max: float = 7.0
    friction_max: float = 1.0  # friction clamped to [0, friction_max] after each step
    checkpoint_every: int = 1  # dynamic passes between checkpoints (0 = never)
    output_dir: str = "outputs"  # runs go to <output_dir>/<run_name>
    run_name: str = ""  # "" = <object>_<preset>_s<seed>
    render_videos: bool = True  # write side-by-side videos (ground truth | prediction)
    write_plys: bool = True  # write per-frame PLYs of Gaussian centres and anchors
    eval_emd: bool = True  # compute the EMD (exact assignment, the slowest metric)
    eval_workers: int = 0  # processes computing the per-frame EMDs side by side (0 = every CPU,
    #                        1 = in the main process); the scores do not depend on it
    contact_margin: float = -1.0  # the simulated ground (anchor contact plane) is raised by this
    #                               along its normal, scene units: the anchors are interior points,
    #                               the visible surface lies about one Gaussian scale beyond them
    #                               (< 0 = the median scale of the static fit's Gaussians)
    momentum_tolerance: float = 0.05  # scene units / s: the report warns when momentum-conserving springs
    #                                   (physics.springs=symmetric) push the predicted centre of mass by more
    simulate: SimulateConfig = field(default_factory=SimulateConfig)  # experiments/simulate.py
    # ---- identification in two stages (issue 32; sgdr.identify.dynamics, global_search)
    search: SearchConfig = field(default_factory=SearchConfig)  # the global stage
    field_prior_strengths: list[float] = field(default_factory=list)  # λ candidates of the stiffness field's
    #   prior (smoothness over the springs + shrinkage to the global level); the one whose fit on the first
    #   fit frames predicts the held-out last ones best is refitted on all; .inf = no field (the global level
    #   only). Empty: no prior, no choice (the official per-anchor field)
    field_shrink: float = 0.1  # shrinkage weight relative to smoothness in the prior
    holdout_frames: int = 0  # last fit frames held out to choose λ (0 = a quarter of the fit frames, >= 1)
    grad_clip: float = 0.0  # each parameter's gradient clipped to this norm before Adam (0 = not clipped)
    lr_decay: float = 1.0  # learning rates decay (cosine) to this fraction over the passes (1 = constant)
    eval_every: int = 0  # the all-view rollout loss at the prediction's n_t every this many passes; the best
    #                      parameters are kept (0 = the last pass's are kept)


SEARCH_CHECKS = {
    "parameters": list_of(choice("sgdr.identify.global_search:GLOBAL_PARAMETERS")),
    "log10_k_range": vector(2),
    "kappa_range": vector(2),
    "friction_range": vector(2),
    "restitution_range": vector(2),
    "images_per_call": at_least(1),
    "region_contrast_range": vector(2),
    "region_theta_range": vector(2),
    "region_phi_range": vector(2),
    "region_offset_range": vector(2),
    "sigma0": positive(),
    "popsize": at_least(2),
    "generations": at_least(1),
    "initial_samples": non_negative("0: CMA-ES starts at physics.*_init"),
    "frame_schedule": list_of(between(0.0, 1.0, lo_open=True), min_len=1),
    "line_points": non_negative("0: no coordinate sweep"),
    "level": choice("sgdr.identify.global_search:LEVELS"),
    "starts": at_least(1),
    "contact_points": non_negative("0: no contact grid"),
    "start_distance": positive(),
    "image_scale": at_least(1),
    "top_k": at_least(1),
    "equivalent_tolerance": non_negative(),
    "spread_warning": positive(),
    "choose": choice("sgdr.identify.global_search:CHOICES"),
}
CHECKS = {
    "model": choice("sgdr.pipeline.run:MODELS"),
    "iterations": non_negative("0: no dynamic passes, the start values are kept"),
    "lambda_dssim": between(0.0, 1.0),
    "substep_growth": list_of(positive(), min_len=1),
    "cameras_per_frame": at_least(1),
    "lr_log10_k": non_negative(),
    "lr_kappa": non_negative(),
    "lr_friction": non_negative(),
    "lr_restitution": non_negative(),
    "lr_v0": non_negative(),
    "v0_iterations": non_negative(),
    "refine_iterations": non_negative(),
    "mode": choice("sgdr.identify.dynamics:RECON_MODES"),
    "lr_scale": non_negative(),
    "lr_color": non_negative(),
    "lr_opacity": non_negative(),
    "refine_lambda_dssim": between(0.0, 1.0),
    "v0_lambda_dssim": between(0.0, 1.0),
    "v0_views_per_step": non_negative("0: every view"),
    "log10_k_grid": list_of(finite()),
    "stiffness": choice("sgdr.identify.dynamics:STIFFNESS"),
    "log10_k_min": finite(),
    "log10_k_max": finite(),
    "friction_max": non_negative(),
    "checkpoint_every": non_negative("0: never"),
    "output_dir": non_empty_text(),
    "run_name": folder_name(empty_ok=True),
    "eval_workers": non_negative("0: every CPU"),
    "contact_margin": finite(),
    "momentum_tolerance": positive(),
    "field_prior_strengths": list_of(
        Check(
            lambda x: isinstance(x, (int, float)) and not isinstance(x, bool) and x > 0, "must be > 0 (.inf: no field)"
        )
    ),
    "field_shrink": non_negative(),
    "holdout_frames": non_negative("0: a quarter of the fit frames"),
    "grad_clip": non_negative("0: not clipped"),
    "lr_decay": between(0.0, 1.0),
    "eval_every": non_negative("0: never, the last pass is kept"),
}
