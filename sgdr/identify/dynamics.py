"""Pipeline stage 5: dynamic reconstruction of the physical parameters.

One pass over the fit frames f = 1 .. n_fit-1:

    x_f = Φ(θ, x_{f-1})            simulate one frame, n_t substeps   (sgdr.physics, Eqs. 8-13)
    μ_f = IDW(x_f)                 bind the Gaussians to the anchors  (Eq. 14)
    I_f = render(μ_f, s, c, σ)     splat one or more cameras          (Eqs. 1-3)
    L_f = (1-λ) L1(I_f, I*_f) + λ D-SSIM(I_f, I*_f),  λ = recon.lambda_dssim (0.05)

θ = the learnable physical parameters of `PhysParams`: log10 k_i (per anchor), the soft
vector κ, the ground friction, and with `physics.contact = coulomb` the restitution. v0
(stage 4), ζ0, m0 and gravity stay fixed. The paper's ablations (Table 3) change θ:
`recon.stiffness = global` optimises one log10 k broadcast to every anchor (`STIFFNESS`), and
`physics.soft_vector = false` fixes η_j = 1 (the model's n_c = n_k) and leaves κ out of θ. The optimiser is Mitsuba's Adam with one learning
rate per parameter (`recon.lr_*`); after every step log10 k_i is clipped to
[recon.log10_k_min, recon.log10_k_max], friction to [0, recon.friction_max], restitution to
[0, 1] (Adam's moments are kept).

Two schedules (`recon.mode`, the registry `RECON_MODES`):
- `truncated` (official): each frame starts from the *detached* previous state, one random
  camera (`recon.cameras_per_frame`) is rendered, and Adam steps after every frame: the
  gradient of L_f reaches θ only through the last frame's n_t substeps. Memory: one frame's
  tape.
- `full`: the whole fit window is simulated with gradients through every frame
  (`rollout(grad_mode="full")`), the losses of all frames (cameras_per_frame random cameras
  each) are averaged and Adam steps once per pass. Memory: O(n_fit x n_t x N_A) (see
  sgdr.physics.simulate), heavier and slower per step but without truncation bias.

n_t of pass i is physics.n_substeps x recon.substep_growth[k], the growth factors split into
equal spans over the passes (official: 100 x [1, 1.5, 2] = 100 -> 150 -> 200).

Unstable frames (NaN/inf or the stability bound, `SimulationUnstable`) have one remedy, the
official one, owned by the simulator: n_t is doubled (`doubled_substeps`, with
physics.retry_on_nan, up to physics.max_substeps). In `full` mode `rollout` applies it inside
the pass and the next pass starts again from the growth schedule: the rollout re-derives the
need from the stability bound with the current parameters, so the stage keeps no hidden n_t.
In `truncated` mode the frames are simulated one by one with an Adam step in between, so
there is no whole rollout to redo: the unstable frame is redone with the doubled n_t, which
is kept for the rest of training (as the official code keeps its raised n_t).

Optional coarse start (`recon.log10_k_grid`, not in the official code): before the first pass
every listed uniform log10 k is scored by the deterministic all-view rollout loss and the best
one replaces physics.log10_k_init. Measured on the small torus, that loss is rugged in the
global stiffness and its local gradient points away from the better basin (docs/reconstruction-results.md).

The stage checkpoints after every `recon.checkpoint_every` passes (parameters, Adam moments,
loss history) and resumes exactly. Besides the noisy training loss (random cameras) it
reports a deterministic score before and after training: the loss of a forward rollout from
frame 0 over all fit frames and all views (`eval_loss_initial`, `eval_loss_final`).
"""

from __future__ import annotations

import json
import logging
import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import drjit as dr
import numpy as np

from sgdr.arrays import array3_to_points, scalar, to_numpy
from sgdr.identify.adam import adam_from_numpy, adam_to_numpy, make_adam
from sgdr.identify.config import ReconConfig
from sgdr.identify.global_search import (
    CHOICES,
    REGION_PARAMETERS,
    REGION_START,
    PopulationScorer,
    global_search,
    landscape,
    region_field,
    search_space,
)
from sgdr.loss import image_loss
from sgdr.physics import PhysParams, SimState, SimulationUnstable, doubled_substeps, rollout, simulate_frame
from sgdr.physics.laws import CONTACT_PARAMETERS
from sgdr.registry import Registry
from sgdr.render.images import posed, render

log = logging.getLogger(__name__)


@dataclass
class DynamicsResult:
    log10_k: np.ndarray  # [N_A] identified log10 k_i
    kappa: float  # soft vector κ
    friction: float  # ground friction μ
    restitution: float  # restitution e ("coulomb" contact; unchanged otherwise)
    n_substeps: int  # n_t at the end of training (growth schedule end; raised by the remedy in truncated mode)
    pass_losses: list[float] = field(default_factory=list)  # mean training loss per pass
    eval_loss_initial: float = float("nan")  # all views, all fit frames, before training
    eval_loss_final: float = float("nan")  # the same after training
    k_grid: dict[str, float] = field(default_factory=dict)  # uniform log10 k -> rollout loss (recon.log10_k_grid)
    search: dict = field(default_factory=dict)  # the global stage (GlobalSearchResult.to_json); {} without one
    field_prior: dict = field(default_factory=dict)  # the prior's choice: strengths, held-out losses, chosen λ
    best_pass: int = -1  # the pass whose parameters were kept (recon.eval_every; -1: the start, none improved it)


def learnable_names(physics_cfg) -> list[str]:
    """PhysParams fields optimised by the dynamic stage: log10 k_i, κ (unless
    physics.soft_vector is off: then η = 1 and κ acts on nothing) and the contact's Θ(B)."""

    kappa = ["kappa"] if physics_cfg.soft_vector else []
    return ["log10_k", *kappa, *CONTACT_PARAMETERS.get_named(physics_cfg.contact)]


@dataclass(frozen=True)
class StiffnessField:
    """How the optimised stiffness variable maps to PhysParams.log10_k (`recon.stiffness`)."""

    variable: Callable  # log10_k Float [N_A] -> the variable Adam optimises
    field: Callable  # (the variable, N_A) -> log10_k Float [N_A]


def _global_variable(log10_k):
    """One log10 k, the mean of the start field (uniform at the start), Float [1], opaque."""
    value = type(log10_k)(float(np.mean(to_numpy(dr.detach(log10_k)))))
    dr.make_opaque(value)
    return value


# per_anchor: the paper's k_i; global: the single-k ablation (Table 3), one log10 k whose
# gradient is the sum over the anchors (the broadcast's adjoint)
STIFFNESS = Registry(
    "stiffness parametrisation",
    "recon.stiffness",
    ValueError,
    {
        "per_anchor": StiffnessField(lambda log10_k: log10_k, lambda v, n: v),
        "global": StiffnessField(_global_variable, lambda v, n: dr.zeros(type(v), n) + v),
    },
)


def substeps_at(n_substeps: int, growth: list[float], it: int, iterations: int) -> int:
    """n_t of pass `it`: n_substeps (physics.n_substeps) times the growth factor of its span,
    the factors (recon.substep_growth) split into equal spans over the passes."""
    if not growth:
        raise ValueError("recon.substep_growth is empty")
    k = min(len(growth) - 1, (it * len(growth)) // max(1, iterations))
    return int(round(int(n_substeps) * float(growth[k])))


def _lr(cfg: ReconConfig, name: str) -> float:
    return float(getattr(cfg, f"lr_{name}"))


def clamp_to_ranges(opt, cfg: ReconConfig) -> None:
    """Project the optimised parameters back into their configured ranges (after each Adam step)."""
    opt["log10_k"] = dr.clip(opt["log10_k"], cfg.log10_k_min, cfg.log10_k_max)
    opt["friction"] = dr.clip(opt["friction"], 0.0, cfg.friction_max)
    if "restitution" in opt:
        opt["restitution"] = dr.clip(opt["restitution"], 0.0, 1.0)


def _with_opt(params, opt, cfg: ReconConfig):
    """`params` with the optimised fields of `opt`, the stiffness mapped by `recon.stiffness`."""
    values = {k: opt[k] for k in opt.keys()}
    values["log10_k"] = STIFFNESS[cfg.stiffness].field(values["log10_k"], dr.width(params.log10_k))
    return replace(params, **values)


def rollout_loss(
    model, params, binding, gaussians, v0, ground, targets, cameras, dt, n_t, physics_cfg, render_cfg, lam, frames=None
) -> float:
    """Forward-only mean loss over `frames` (default: fit frames 1..n_fit-1) and all views of a
    rollout from rest (open loop: frame 0 is the only state given).

    targets: [n_fit] lists of TensorXf [H, W, 3] per view; v0 [3]; dt seconds per frame.
    """

    with dr.suspend_grad():
        state0 = SimState.at_rest(model, v0)
        states = rollout(model, params.detach(), state0, ground, len(targets), dt, physics_cfg, n_substeps=n_t)
        total, count = 0.0, 0
        for f in range(1, len(targets)) if frames is None else frames:
            g = posed(gaussians, binding.apply(states[f].x))
            for v, cam in enumerate(cameras):
                total += scalar(image_loss(render(g, cam, render_cfg).rgb, targets[f][v], lam))
                count += 1
    return total / max(count, 1)


def _frame_loss(gaussians, binding, x, targets_f, cameras, views, render_cfg, lam):
    """Mean image loss of the bound Gaussians at anchor positions x (Array3f [N_A]) over `views`."""

    g = posed(gaussians, binding.apply(x))
    loss = 0.0
    for v in views:
        loss = loss + image_loss(render(g, cameras[int(v)], render_cfg).rgb, targets_f[int(v)], lam)
    return loss / float(len(views))


@dataclass(frozen=True)
class FieldPrior:
    """The stiffness field's prior: log10 k_i = L + δ_i around the global level L, and

        P(δ) = λ / N_A Σ_i [ (1/n_k) Σ_{j ∈ springs of i} (δ_i - δ_j)² + r δ_i² ]

    smoothness over the spring graph plus shrinkage to the level (r = recon.field_shrink). A
    homogeneous object's field then has nothing to gain from noise, and a field with regions
    (torus_hetero's halves) pays only along their border. λ is chosen on held-out time
    (`fit_dynamics`). Its value and gradient are computed on the host (N_A values, bincount
    sums in a fixed order): the gradient is added to the rendered loss's before each Adam step."""

    strength: float  # λ
    shrink: float  # r
    level: float  # L, the global level
    source: np.ndarray  # [N_A n_k] int64 anchor i of each spring
    target: np.ndarray  # [N_A n_k] int64 anchor j of each spring
    n_k: int

    @staticmethod
    def of(model, strength: float, shrink: float, level: float) -> FieldPrior:
        j = to_numpy(model.spring_j, np.int64)
        return FieldPrior(float(strength), float(shrink), float(level), np.arange(j.size) // model.n_k, j, model.n_k)

    def value(self, log10_k: np.ndarray) -> float:
        d = np.asarray(log10_k, float) - self.level
        n = d.size
        return self.strength / n * (np.sum((d[self.source] - d[self.target]) ** 2) / self.n_k + self.shrink * d @ d)

    def gradient(self, log10_k: np.ndarray) -> np.ndarray:
        """dP/d log10 k_i, [N_A] float64."""
        d = np.asarray(log10_k, float) - self.level
        n = d.size
        diff = d[self.source] - d[self.target]  # [N_A n_k]
        g = np.bincount(self.source, weights=diff, minlength=n) - np.bincount(self.target, weights=diff, minlength=n)
        return self.strength / n * (2.0 / self.n_k * g + 2.0 * self.shrink * d)


def condition_gradients(p: _Pass, opt) -> None:
    """Before an Adam step: add the field prior's gradient to log10 k's, then clip each
    parameter's gradient to the norm recon.grad_clip (a rare frame with a huge gradient would
    otherwise fill Adam's second moment and stall that parameter for many steps)."""
    if p.prior is not None and dr.width(opt["log10_k"]) > 1:
        k = to_numpy(dr.detach(opt["log10_k"]))
        g = to_numpy(dr.grad(opt["log10_k"])) + p.prior.gradient(k)
        dr.set_grad(opt["log10_k"], type(opt["log10_k"])(g.astype(np.float32)))
    if p.grad_clip > 0:
        for name in opt.keys():
            g = to_numpy(dr.grad(opt[name]))
            norm = float(np.sqrt(np.sum(g * g)))
            if np.isfinite(norm) and norm > p.grad_clip:
                dr.set_grad(opt[name], type(opt[name])((g * (p.grad_clip / norm)).astype(np.float32)))


@dataclass
class _Pass:
    """What one training pass reads: the fixed inputs of `fit_dynamics`."""

    model: object  # SpringModel
    binding: object  # IDWBinding
    gaussians: object  # Gaussians, detached (appearance fixed)
    base: object  # PhysParams; the learnable fields come from the optimiser
    v0: tuple  # (3,) initial velocity
    ground: object  # physics Ground
    targets: list  # [n_fit][n_views] TensorXf [H, W, 3]
    cameras: list
    dt: float  # seconds per frame
    physics_cfg: object  # PhysicsConfig
    cfg: ReconConfig
    render_cfg: object
    lam: float  # λ of the loss
    per_frame: int  # cameras rendered per frame
    prior: FieldPrior | None = None  # the stiffness field's prior (its gradient is added before each step)
    grad_clip: float = 0.0  # each parameter's gradient norm clipped to this (0: not clipped)


# How one pass over the fit frames trains (`recon.mode`): (pass inputs, Adam, rng, n_t) ->
# (loss of every fit frame, n_t for the rest of training).
RECON_MODES = Registry("reconstruction mode", "recon.mode", ValueError)


@RECON_MODES.register("truncated")
def pass_truncated(p: _Pass, opt, rng, n_t: int) -> tuple[list[float], int]:
    """Official: frame by frame from the detached previous state, an Adam step per frame. An
    unstable frame is redone with the doubled n_t, kept for the rest of training (module doc)."""

    frame_losses: list[float] = []
    state = SimState.at_rest(p.model, p.v0)
    for f in range(1, len(p.targets)):
        views = rng.choice(len(p.cameras), size=p.per_frame, replace=False)
        while True:
            params = _with_opt(p.base, opt, p.cfg)
            try:
                new = simulate_frame(p.model, params, state, p.ground, p.dt, n_t, p.physics_cfg)
                loss = _frame_loss(p.gaussians, p.binding, new.x, p.targets[f], p.cameras, views, p.render_cfg, p.lam)
                value = scalar(loss)
            except SimulationUnstable:
                value = float("nan")
            if math.isfinite(value):
                break
            more = doubled_substeps(n_t, p.physics_cfg)
            if more is None:
                raise SimulationUnstable(
                    f"dynamics: frame {f} is unstable with n_t={n_t} (NaN/inf or the stability bound) and "
                    f"physics.retry_on_nan={p.physics_cfg.retry_on_nan} / physics.max_substeps="
                    f"{p.physics_cfg.max_substeps} allow no more substeps; raise physics.n_substeps or "
                    f"physics.max_substeps, or lower recon.lr_log10_k or recon.log10_k_max"
                )
            n_t = more
            log.warning("dynamics: non-finite frame %d, n_t raised to %d", f, n_t)
        dr.backward(loss)
        condition_gradients(p, opt)
        finite_step(opt, p.cfg)
        frame_losses.append(value)
        state = new.detach()
        dr.eval(state.x, state.v)
    return frame_losses, n_t


@RECON_MODES.register("full")
def pass_full(p: _Pass, opt, rng, n_t: int) -> tuple[list[float], int]:
    """Gradients through every fit frame, one Adam step per pass; `rollout` applies the
    substep remedy within the pass, so the pass's n_t is returned unchanged (module doc)."""

    params = _with_opt(p.base, opt, p.cfg)
    states = rollout(
        p.model,
        params,
        SimState.at_rest(p.model, p.v0),
        p.ground,
        len(p.targets),
        p.dt,
        p.physics_cfg,
        grad_mode="full",
        n_substeps=n_t,
    )
    frame_losses: list[float] = []
    loss = 0.0
    for f in range(1, len(p.targets)):
        views = rng.choice(len(p.cameras), size=p.per_frame, replace=False)
        lf = _frame_loss(p.gaussians, p.binding, states[f].x, p.targets[f], p.cameras, views, p.render_cfg, p.lam)
        loss = loss + lf
        frame_losses.append(scalar(lf))
    loss = loss / float(len(p.targets) - 1)
    if not math.isfinite(scalar(loss)):
        raise RuntimeError(f"dynamics (full): non-finite loss with n_t={states.n_substeps}; raise physics.n_substeps")
    dr.backward(loss)
    condition_gradients(p, opt)
    finite_step(opt, p.cfg)
    return frame_losses, n_t


def finite_step(opt, cfg) -> bool:
    """One Adam step and the range clamp, unless it would leave a parameter NaN/inf: a NaN/inf
    gradient, or a finite one so large that Adam's second moment overflows float32 (seen on the
    small cross under gravity x1.15). Then the step is undone (values and moments restored), the
    gradients cleared, a warning logged, and False returned; one such step would otherwise make
    every parameter NaN and the next rollout fail."""
    bad = [name for name in opt.keys() if not np.all(np.isfinite(to_numpy(dr.grad(opt[name]))))]
    if not bad:
        before = adam_to_numpy(opt)
        opt.step()
        clamp_to_ranges(opt, cfg)
        bad = [name for name in opt.keys() if not np.all(np.isfinite(to_numpy(opt[name])))]
        if not bad:
            return True
        adam_from_numpy(opt, before)
    for name in opt.keys():
        dr.clear_grad(opt[name])
    log.warning("dynamics: the Adam step would make %s non-finite; skipped", ", ".join(bad))
    return False


def _cosine_lr(cfg: ReconConfig, it: int, iterations: int) -> float:
    """The learning-rate factor of pass `it`: cosine from 1 to recon.lr_decay over the passes."""
    d = float(cfg.lr_decay)
    if iterations <= 1 or d >= 1.0:
        return 1.0
    return d + (1.0 - d) * 0.5 * (1.0 + math.cos(math.pi * it / (iterations - 1)))


@dataclass
class _Train:
    """One local fit's outcome: the kept parameters and what training saw."""

    params: object  # PhysParams, detached: the best evaluated (or the last) parameters
    pass_losses: list[float]
    n_t: int
    eval_loss: float  # all-view rollout loss of `params` on the training frames (nan when not evaluated)
    best_pass: int


def _train(
    inputs: _Pass,
    opt,
    start: int,
    iterations: int,
    seed: int,
    schedule: Callable[[int], int],
    n_t_floor: int,
    evaluate: Callable[[object], float] | None,
    best: tuple[float, int, dict] | None,
    ckpt=None,
    ckpt_extra: dict | None = None,
    on_pass=None,
    progress: bool = False,
    pass_losses: list[float] | None = None,
) -> _Train:
    """Adam passes `start` .. iterations-1 (recon.mode), with the learning-rate schedule; every
    recon.eval_every passes the parameters are scored by `evaluate` and the best kept. `best`:
    (loss, pass, Adam values) to beat, e.g. the start's."""
    cfg = inputs.cfg
    train_pass = RECON_MODES.get_named(cfg.mode)
    pass_losses = list(pass_losses or [])
    lrs = {name: _lr(cfg, name) for name in opt.keys()}
    passes = range(start, int(iterations))
    if progress:
        from tqdm import tqdm

        passes = tqdm(passes, desc=f"dynamics ({cfg.mode})", initial=start, total=int(iterations), leave=False)
    n_t = max(schedule(start), n_t_floor)
    every = int(cfg.eval_every)
    for it in passes:
        rng = np.random.default_rng([int(seed), it])
        n_t = max(schedule(it), n_t_floor)
        factor = _cosine_lr(cfg, it, int(iterations))
        opt.set_learning_rate({name: lr * factor for name, lr in lrs.items()})
        frame_losses, n_t_after = train_pass(inputs, opt, rng, n_t)
        if n_t_after > n_t:
            n_t = n_t_floor = n_t_after
        pass_losses.append(float(np.mean(frame_losses)))
        if evaluate is not None and every > 0 and ((it + 1) % every == 0 or it + 1 == int(iterations)):
            loss = evaluate(_with_opt(inputs.base, opt, cfg).detach())
            log.info("dynamics: pass %d all-view rollout loss %.5f", it, loss)
            if best is None or loss < best[0]:
                best = (loss, it, {name: to_numpy(dr.detach(opt[name])) for name in opt.keys()})
        if on_pass is not None:
            on_pass(it, pass_losses[-1], n_t)
        if progress:
            passes.set_postfix(loss=f"{pass_losses[-1]:.4f}", n_t=n_t)
        if ckpt is not None and cfg.checkpoint_every > 0 and (it + 1) % cfg.checkpoint_every == 0:
            extra = dict(ckpt_extra or {})
            if best is not None:
                extra.update({"best/loss": np.float64(best[0]), "best/pass": np.int64(best[1])})
                extra.update({f"best/{k}": v for k, v in best[2].items()})
            ckpt.save(
                it + 1,
                {
                    **adam_to_numpy(opt),
                    "pass_losses": np.asarray(pass_losses),
                    "n_t_floor": np.int64(n_t_floor),
                    **extra,
                },
            )
    if best is not None and every > 0:
        t = type(dr.detach(opt["friction"]))
        values = {name: t(v.astype(np.float32)) for name, v in best[2].items()}
        params = replace(
            inputs.base,
            **{**values, "log10_k": STIFFNESS[cfg.stiffness].field(values["log10_k"], dr.width(inputs.base.log10_k))},
        )
        dr.make_opaque(params)
        return _Train(params.detach(), pass_losses, n_t, float(best[0]), int(best[1]))
    return _Train(_with_opt(inputs.base, opt, cfg).detach(), pass_losses, n_t, float("nan"), int(iterations) - 1)


def _start_values(base, physics_cfg, stiffness) -> dict:
    values = {name: getattr(base, name) for name in learnable_names(physics_cfg)}
    values["log10_k"] = stiffness.variable(base.log10_k)
    return values


def _with_values(base, values: dict, model=None):
    """`base` with global values {log10_k: a uniform level, kappa, friction, restitution, and the
    two regions region_* (`global_search.region_field` of `model`'s anchors) about the level}."""
    t_f = type(base.friction)
    fields = {}
    regions = {n: [float(v)] for n, v in values.items() if n in REGION_PARAMETERS}
    if "log10_k" in values or regions:
        level = float(values.get("log10_k", np.mean(to_numpy(base.log10_k))))
        k = np.full(dr.width(base.log10_k), level)
        if regions:
            k = k + region_field(array3_to_points(model.x_rest), regions)[0]
        fields["log10_k"] = type(base.log10_k)(k.astype(np.float32))
    for name, v in values.items():
        if name != "log10_k" and name not in REGION_PARAMETERS:
            fields[name] = t_f(float(v))
    out = replace(base, **fields)
    dr.make_opaque(out)
    return out


def fit_dynamics(
    model,
    binding,
    gaussians,
    v0: np.ndarray,
    gravity: np.ndarray,
    ground,
    targets: list[list],
    cameras: list,
    fps: float,
    physics_cfg,
    cfg: ReconConfig,
    render_cfg,
    seed: int,
    ckpt=None,
    on_pass: Callable[[int, float, int], None] | None = None,
    progress: bool = False,
    n_predict: int = 0,
) -> DynamicsResult:
    """Identify log10 k_i, κ, friction (and restitution) from the fit frames.

    model: SpringModel; binding: IDWBinding; gaussians: refined Gaussians (appearance fixed);
    v0 [3], gravity [3]: from stage 4 and the sequence; ground: physics Ground; targets:
    [n_fit][n_views] TensorXf [H, W, 3]; fps: frames per second. ckpt: a stage Checkpoint or
    None. on_pass(pass, mean loss, n_t) is called after every pass (tracking). n_predict: the
    frames the asset will predict (the global stage's landscape compares the futures of its
    best candidates up to it; 0: n_fit).

    The order (module docstring): the start (recon.log10_k_grid, or the global search of
    recon.search.parameters), the prior's strength chosen on held-out time
    (recon.field_prior_strengths), then the local Adam passes on all fit frames.
    """

    stiffness = STIFFNESS.get_named(cfg.stiffness)
    n_fit = len(targets)
    if n_fit < 2:
        raise ValueError(f"dynamic reconstruction needs at least 2 fit frames, the sequence has n_fit={n_fit}")
    dt = 1.0 / float(fps)
    lam = float(cfg.lambda_dssim)
    per_frame = max(1, min(int(cfg.cameras_per_frame), len(cameras)))
    base = PhysParams.init(model, physics_cfg, v0=tuple(map(float, v0)), gravity=tuple(map(float, gravity)))
    g = gaussians.detach()
    iterations = int(cfg.iterations)

    def schedule(it: int) -> int:
        return substeps_at(physics_cfg.n_substeps, list(cfg.substep_growth), it, cfg.iterations)

    n_t0 = schedule(0)
    n_t_final = schedule(max(iterations - 1, 0))  # the n_t the prediction uses

    def evaluate_on(frames):
        return lambda params: rollout_loss(
            model, params, binding, g, v0, ground, targets, cameras, dt, n_t_final, physics_cfg, render_cfg, lam, frames
        )

    resumed = ckpt.load() if ckpt is not None else None
    start_info = (
        json.loads(str(resumed[1]["start_info"])) if resumed is not None and "start_info" in resumed[1] else None
    )

    # ---- 1. the start: the global search, or the coarse grid, or physics.*_init
    if start_info is None:
        start_info = _start(model, binding, g, v0, base, ground, targets, cameras, dt, n_t0, n_t_final, physics_cfg,
                            cfg, render_cfg, lam, seed, progress, max(int(n_predict), n_fit))  # fmt: skip
    base = _with_values(base, start_info["values"], model)
    level = float(start_info["values"].get("log10_k", physics_cfg.log10_k_init))

    def inputs_for(frame_targets, prior):
        p = _Pass(
            model,
            binding,
            g,
            base,
            tuple(map(float, v0)),
            ground,
            frame_targets,
            cameras,
            dt,
            physics_cfg,
            cfg,
            render_cfg,
            lam,
            per_frame,
            prior,
            float(cfg.grad_clip),
        )
        return p

    def prior_of(strength):
        if strength is None or cfg.stiffness != "per_anchor":
            return None
        return FieldPrior.of(model, strength, cfg.field_shrink, level)

    # ---- 2. the prior's strength, chosen on held-out time
    if "field_prior" not in start_info:
        start_info["field_prior"] = _choose_prior(
            cfg,
            n_fit,
            iterations,
            seed,
            schedule,
            evaluate_on,
            inputs_for,
            prior_of,
            base,
            physics_cfg,
            stiffness,
            targets,
            progress,
        )
    chosen = start_info["field_prior"].get("chosen")
    chosen = None if chosen is None else float(chosen)

    # ---- 3. the local stage on all fit frames
    eval_all = evaluate_on(None)
    final, trained, eval_start = _local_stage(
        base, start_info, chosen, resumed, ckpt, cfg, physics_cfg, stiffness, inputs_for, prior_of, targets,
        iterations, seed, schedule, n_t_final, eval_all, on_pass, progress,
    )  # fmt: skip
    eval_final = trained.eval_loss if math.isfinite(trained.eval_loss) else eval_all(final)
    return DynamicsResult(
        log10_k=to_numpy(final.log10_k).reshape(-1),
        kappa=scalar(final.kappa),
        friction=scalar(final.friction),
        restitution=scalar(final.restitution),
        n_substeps=int(max(trained.n_t, n_t_final)),
        pass_losses=trained.pass_losses,
        eval_loss_initial=eval_start,
        eval_loss_final=eval_final,
        k_grid=start_info["k_grid"],
        search=start_info["search"],
        field_prior=start_info["field_prior"],
        best_pass=trained.best_pass,
    )


def _choose_prior(
    cfg,
    n_fit,
    iterations,
    seed,
    schedule,
    evaluate_on,
    inputs_for,
    prior_of,
    base,
    physics_cfg,
    stiffness,
    targets,
    progress,
) -> dict:
    """recon.field_prior_strengths: with one value, that one; with several, each fitted on the
    first n_fit - h fit frames from the start and scored by the open-loop rollout's all-view
    loss on the last h (h = recon.holdout_frames); .inf scores the start itself (no field).
    A fit window too short to hold a frame out (h automatic) takes the strongest prior.
    Returns {"strengths", "holdout_frames", "holdout_losses", "chosen"} (chosen None: no prior)."""
    strengths = [float(v) for v in cfg.field_prior_strengths]
    if not strengths or cfg.stiffness != "per_anchor":
        return {"strengths": [f"{v:g}" for v in strengths], "chosen": None}
    if len(strengths) == 1:
        return {"strengths": [f"{v:g}" for v in strengths], "chosen": f"{strengths[0]:g}"}
    h = int(cfg.holdout_frames) or max(1, n_fit // 4)
    if n_fit - h < 2 and not int(cfg.holdout_frames):
        # too short a fit window to hold any frame out: no evidence for a field, the strongest prior
        log.warning("dynamics: %d fit frames are too few to choose the field prior on held-out time", n_fit)
        return {
            "strengths": [f"{v:g}" for v in strengths],
            "chosen": f"{max(strengths):g}",
            "note": f"{n_fit} fit frames: too few to hold any out; the strongest prior taken",
        }
    if n_fit - h < 2:
        raise ValueError(
            f"recon.holdout_frames={cfg.holdout_frames}: {h} held-out frames leave fewer than 2 of the "
            f"{n_fit} fit frames to fit on; lower it or give one recon.field_prior_strengths value"
        )
    held_out = evaluate_on(list(range(n_fit - h, n_fit)))
    early = evaluate_on(None)
    losses = {}
    for strength in strengths:
        if math.isinf(strength):
            losses[strength] = held_out(base)
        else:
            inputs = inputs_for(targets[: n_fit - h], prior_of(strength))
            opt = make_adam(
                {name: (value, _lr(cfg, name)) for name, value in _start_values(base, physics_cfg, stiffness).items()}
            )
            early_frames = list(range(1, n_fit - h))
            best = None
            if int(cfg.eval_every) > 0:
                early = evaluate_on(early_frames)
                best = (early(base), -1, {name: to_numpy(dr.detach(opt[name])) for name in opt.keys()})
            trained = _train(inputs, opt, 0, iterations, seed, schedule, 0, early, best, progress=progress)
            losses[strength] = held_out(trained.params)
        log.info("dynamics: field prior %g -> held-out loss %.5f", strength, losses[strength])
    chosen = min(strengths, key=lambda v: losses[v])
    return {  # strengths as text ("inf" for no field): strict JSON
        "strengths": [f"{v:g}" for v in strengths],
        "holdout_frames": h,
        "holdout_losses": {f"{k:g}": v for k, v in losses.items()},
        "chosen": f"{chosen:g}",
    }


def _start(model, binding, g, v0, base, ground, targets, cameras, dt, n_t0, n_t_final, physics_cfg, cfg, render_cfg,
           lam, seed, progress, n_predict) -> dict:  # fmt: skip
    """Step 1, the start: the global search of recon.search.parameters (its landscape's futures
    compared up to frame n_predict), else the best of recon.log10_k_grid, else physics.*_init.
    Returns the start's record {"k_grid", "search", "values"}."""
    n_fit = len(targets)
    start_info = {"k_grid": {}, "search": {}, "values": {}}
    if cfg.search.parameters:
        space = search_space(cfg.search, physics_cfg, model, dt, n_t_final, cfg.stiffness == "per_anchor")
        scorer = PopulationScorer(model, binding, g, base, ground, targets, cameras, dt, n_t_final, physics_cfg,
                                  render_cfg, lam, cfg.search.image_scale, cfg.search.images_per_call)  # fmt: skip
        init = {
            n: REGION_START[n] if n in REGION_START else scalar(getattr(base, n)) for n in space.names if n != "log10_k"
        }
        init["log10_k"] = float(physics_cfg.log10_k_init)  # (ignored when the level is not searched)
        found = global_search(scorer, space, init, cfg.search, seed, progress)
        found.landscape = landscape(scorer, found, cfg.search, n_predict, n_fit)
        start_info["search"] = found.to_json()
        start_info["values"] = CHOICES[cfg.search.choose](found)
        start_info["search"]["choose"] = cfg.search.choose
        start_info["search"]["chosen"] = start_info["values"]
        log.info(
            "dynamics: global search -> %s (best %s, loss %.5f)", start_info["values"], found.best, found.best_loss
        )
    elif cfg.log10_k_grid:
        # the rollout loss is rugged in the global stiffness (bounces and contacts shift in time)
        for value in cfg.log10_k_grid:
            trial = _with_values(base, {"log10_k": float(value)})
            start_info["k_grid"][f"{float(value):g}"] = rollout_loss(
                model, trial, binding, g, v0, ground, targets, cameras, dt, n_t0, physics_cfg, render_cfg, lam
            )
        best = min(start_info["k_grid"], key=start_info["k_grid"].get)
        log.info("dynamics: uniform log10 k grid %s -> start at %s", start_info["k_grid"], best)
        start_info["values"] = {"log10_k": float(best)}
    return start_info


def _local_stage(base, start_info, chosen, resumed, ckpt, cfg, physics_cfg, stiffness, inputs_for, prior_of, targets,
                 iterations, seed, schedule, n_t_final, eval_all, on_pass, progress):  # fmt: skip
    """Step 3, the local Adam passes on all fit frames under the chosen prior (none when the
    chosen strength is .inf: the start is the asset), resumed from `resumed` (a checkpoint's
    (pass, arrays), or None). The start is checkpointed first, so a resumed stage does not
    search again. Returns (final params, _Train, the start's all-view rollout loss)."""
    if resumed is not None:
        eval_start = float(resumed[1]["eval_loss_initial"])
    else:
        eval_start = eval_all(base)
        if ckpt is not None and cfg.checkpoint_every > 0:
            ckpt.save(0, {"eval_loss_initial": np.float64(eval_start), "start_info": np.array(json.dumps(start_info))})
    if chosen is not None and math.isinf(chosen):  # no field: the global values are the asset
        return base.detach(), _Train(base.detach(), [], n_t_final, eval_start, -1), eval_start
    inputs = inputs_for(targets, prior_of(chosen))
    opt = make_adam(
        {name: (value, _lr(cfg, name)) for name, value in _start_values(base, physics_cfg, stiffness).items()}
    )
    start, pass_losses, n_t_floor, best = 0, [], 0, None
    if int(cfg.eval_every) > 0:
        best = (eval_start, -1, {name: to_numpy(dr.detach(opt[name])) for name in opt.keys()})
    if resumed is not None and "pass_losses" in resumed[1]:  # (a step-0 checkpoint holds the start only)
        start, arrays = resumed
        adam_from_numpy(opt, arrays)
        pass_losses = [float(x) for x in arrays["pass_losses"]]
        n_t_floor = int(arrays["n_t_floor"])
        if "best/loss" in arrays:
            names = [k[len("best/") :] for k in arrays if k.startswith("best/") and k not in ("best/loss", "best/pass")]
            best = (float(arrays["best/loss"]), int(arrays["best/pass"]), {k: arrays[f"best/{k}"] for k in names})
    trained = _train(inputs, opt, start, iterations, seed, schedule, n_t_floor, eval_all, best, ckpt,
                     {"eval_loss_initial": np.float64(eval_start), "start_info": np.array(json.dumps(start_info))},
                     on_pass, progress, pass_losses)  # fmt: skip
    return trained.params, trained, eval_start
