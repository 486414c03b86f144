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

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import drjit as dr
import numpy as np

from sgdr.arrays import scalar, to_numpy
from sgdr.identify.adam import adam_from_numpy, adam_to_numpy, make_adam
from sgdr.identify.common import posed
from sgdr.pipeline.config import ReconConfig
from sgdr.registry import Registry

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


def learnable_names(physics_cfg) -> list[str]:
    """PhysParams fields optimised by the dynamic stage: log10 k_i, κ (unless
    physics.soft_vector is off: then η = 1 and κ acts on nothing) and the contact's Θ(B)."""
    from sgdr.physics.laws import CONTACT_PARAMETERS

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
    model, params, binding, gaussians, v0, ground, targets, cameras, dt, n_t, physics_cfg, render_cfg, lam
) -> float:
    """Forward-only mean loss over fit frames 1..n_fit-1 and all views of a rollout from rest.

    targets: [n_fit] lists of TensorXf [H, W, 3] per view; v0 [3]; dt seconds per frame.
    """
    from sgdr.identify.common import render
    from sgdr.loss import image_loss
    from sgdr.physics import SimState, rollout

    with dr.suspend_grad():
        state0 = SimState.at_rest(model, v0)
        states = rollout(model, params.detach(), state0, ground, len(targets), dt, physics_cfg, n_substeps=n_t)
        total, count = 0.0, 0
        for f in range(1, len(targets)):
            g = posed(gaussians, binding.apply(states[f].x))
            for v, cam in enumerate(cameras):
                total += scalar(image_loss(render(g, cam, render_cfg).rgb, targets[f][v], lam))
                count += 1
    return total / max(count, 1)


def _frame_loss(gaussians, binding, x, targets_f, cameras, views, render_cfg, lam):
    """Mean image loss of the bound Gaussians at anchor positions x (Array3f [N_A]) over `views`."""
    from sgdr.identify.common import render
    from sgdr.loss import image_loss

    g = posed(gaussians, binding.apply(x))
    loss = 0.0
    for v in views:
        loss = loss + image_loss(render(g, cameras[int(v)], render_cfg).rgb, targets_f[int(v)], lam)
    return loss / float(len(views))


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


# How one pass over the fit frames trains (`recon.mode`): (pass inputs, Adam, rng, n_t) ->
# (loss of every fit frame, n_t for the rest of training).
RECON_MODES = Registry("reconstruction mode", "recon.mode", ValueError)


@RECON_MODES.register("truncated")
def pass_truncated(p: _Pass, opt, rng, n_t: int) -> tuple[list[float], int]:
    """Official: frame by frame from the detached previous state, an Adam step per frame. An
    unstable frame is redone with the doubled n_t, kept for the rest of training (module doc)."""
    from sgdr.physics import SimState, SimulationUnstable, doubled_substeps, simulate_frame

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
        finite_step(opt, p.cfg)
        frame_losses.append(value)
        state = new.detach()
        dr.eval(state.x, state.v)
    return frame_losses, n_t


@RECON_MODES.register("full")
def pass_full(p: _Pass, opt, rng, n_t: int) -> tuple[list[float], int]:
    """Gradients through every fit frame, one Adam step per pass; `rollout` applies the
    substep remedy within the pass, so the pass's n_t is returned unchanged (module doc)."""
    from sgdr.physics import SimState, rollout

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
    finite_step(opt, p.cfg)
    return frame_losses, n_t


def finite_step(opt, cfg) -> bool:
    """One Adam step and the range clamp, unless a gradient is NaN/inf: then the step is skipped
    and the gradients cleared (one such step would make every parameter NaN, and the next
    rollout fail), with a warning; False when skipped. A finite loss can still have a
    non-finite gradient (a near-coincident spring or contact in one substep)."""
    bad = [name for name in opt.keys() if not np.all(np.isfinite(to_numpy(dr.grad(opt[name]))))]
    if bad:
        for name in opt.keys():
            dr.clear_grad(opt[name])
        log.warning("dynamics: non-finite gradient of %s; the Adam step is skipped", ", ".join(bad))
        return False
    opt.step()
    clamp_to_ranges(opt, cfg)
    return True


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
) -> DynamicsResult:
    """Identify log10 k_i, κ, friction (and restitution) from the fit frames.

    model: SpringModel; binding: IDWBinding; gaussians: refined Gaussians (appearance fixed);
    v0 [3], gravity [3]: from stage 4 and the sequence; ground: physics Ground; targets:
    [n_fit][n_views] TensorXf [H, W, 3]; fps: frames per second. ckpt: a stage Checkpoint or
    None. on_pass(pass, mean loss, n_t) is called after every pass (tracking).
    """
    from sgdr.physics import PhysParams

    train_pass = RECON_MODES.get_named(cfg.mode)
    stiffness = STIFFNESS.get_named(cfg.stiffness)
    n_fit = len(targets)
    if n_fit < 2:
        raise ValueError(f"dynamic reconstruction needs at least 2 fit frames, the sequence has n_fit={n_fit}")
    dt = 1.0 / float(fps)
    lam = float(cfg.lambda_dssim)
    per_frame = max(1, min(int(cfg.cameras_per_frame), len(cameras)))
    base = PhysParams.init(model, physics_cfg, v0=tuple(map(float, v0)), gravity=tuple(map(float, gravity)))

    def schedule(it: int) -> int:
        return substeps_at(physics_cfg.n_substeps, list(cfg.substep_growth), it, cfg.iterations)

    n_t0 = schedule(0)
    resumed = ckpt.load() if ckpt is not None else None
    k_grid: dict[str, float] = {}
    if resumed is None and cfg.log10_k_grid:
        # ---- coarse start: the rollout loss is rugged in the global stiffness (bounces and
        # contacts shift in time), its local gradient does not point to the best basin
        for value in cfg.log10_k_grid:
            trial = replace(base, log10_k=dr.full(type(base.log10_k), float(value), model.n_anchors))
            k_grid[f"{float(value):g}"] = rollout_loss(
                model,
                trial,
                binding,
                gaussians.detach(),
                v0,
                ground,
                targets,
                cameras,
                dt,
                n_t0,
                physics_cfg,
                render_cfg,
                lam,
            )
        best = min(k_grid, key=k_grid.get)
        log.info("dynamics: uniform log10 k grid %s -> start at %s", k_grid, best)
        base = replace(base, log10_k=dr.full(type(base.log10_k), float(best), model.n_anchors))
        dr.make_opaque(base.log10_k)
    start_values = {name: getattr(base, name) for name in learnable_names(physics_cfg)}
    start_values["log10_k"] = stiffness.variable(base.log10_k)
    opt = make_adam({name: (value, _lr(cfg, name)) for name, value in start_values.items()})
    g = gaussians.detach()
    inputs = _Pass(
        model,
        binding,
        g,
        base,
        tuple(map(float, v0)),
        ground,
        targets,
        cameras,
        dt,
        physics_cfg,
        cfg,
        render_cfg,
        lam,
        per_frame,
    )

    # ---- resume or start
    start, pass_losses, n_t_floor = 0, [], 0
    eval_initial = float("nan")
    if resumed is not None:
        start, arrays = resumed
        adam_from_numpy(opt, arrays)
        pass_losses = [float(x) for x in arrays["pass_losses"]]
        n_t_floor = int(arrays["n_t_floor"])
        eval_initial = float(arrays["eval_loss_initial"])
    elif k_grid:
        eval_initial = min(k_grid.values())
    else:
        eval_initial = rollout_loss(
            model, base, binding, g, v0, ground, targets, cameras, dt, n_t0, physics_cfg, render_cfg, lam
        )

    passes = range(start, int(cfg.iterations))
    if progress:
        from tqdm import tqdm

        passes = tqdm(passes, desc=f"dynamics ({cfg.mode})", initial=start, total=int(cfg.iterations), leave=False)
    n_t = max(schedule(start), n_t_floor)
    for it in passes:
        rng = np.random.default_rng([int(seed), it])
        n_t = max(schedule(it), n_t_floor)
        frame_losses, n_t_after = train_pass(inputs, opt, rng, n_t)
        if n_t_after > n_t:
            n_t = n_t_floor = n_t_after
        pass_losses.append(float(np.mean(frame_losses)))
        if on_pass is not None:
            on_pass(it, pass_losses[-1], n_t)
        if progress:
            passes.set_postfix(loss=f"{pass_losses[-1]:.4f}", n_t=n_t)
        if ckpt is not None and cfg.checkpoint_every > 0 and (it + 1) % cfg.checkpoint_every == 0:
            ckpt.save(
                it + 1,
                {
                    **adam_to_numpy(opt),
                    "pass_losses": np.asarray(pass_losses),
                    "n_t_floor": np.int64(n_t_floor),
                    "eval_loss_initial": np.float64(eval_initial),
                },
            )

    final = _with_opt(base, opt, cfg).detach()
    eval_final = rollout_loss(
        model, final, binding, g, v0, ground, targets, cameras, dt, n_t, physics_cfg, render_cfg, lam
    )
    return DynamicsResult(
        log10_k=to_numpy(final.log10_k).reshape(-1),
        kappa=scalar(final.kappa),
        friction=scalar(final.friction),
        restitution=scalar(final.restitution),
        n_substeps=int(n_t),
        pass_losses=pass_losses,
        eval_loss_initial=eval_initial,
        eval_loss_final=eval_final,
        k_grid=k_grid,
    )
