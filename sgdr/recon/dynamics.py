"""Pipeline stage 5: dynamic reconstruction of the physical parameters.

One pass over the fit frames f = 1 .. n_fit-1:

    x_f = Φ(θ, x_{f-1})            simulate one frame, n_t substeps   (sgdr.physics, Eqs. 8-13)
    μ_f = IDW(x_f)                 bind the Gaussians to the anchors  (Eq. 14)
    I_f = render(μ_f, s, c, σ)     splat one or more cameras          (Eqs. 1-3)
    L_f = (1-λ) L1(I_f, I*_f) + λ D-SSIM(I_f, I*_f),  λ = recon.lambda_dssim (0.05)

θ = the learnable physical parameters of `PhysParams`: log10 k_i (per anchor), the soft
vector κ, the ground friction, and with `physics.contact = coulomb` the restitution. v0
(stage 4), ζ0, m0 and gravity stay fixed. The optimiser is Mitsuba's Adam with one learning
rate per parameter (`recon.lr_*`); after every step log10 k_i is clipped to
[recon.log10_k_min, recon.log10_k_max], friction to [0, recon.friction_max], restitution to
[0, 1] (Adam's moments are kept).

Two schedules (`recon.mode`):
- `truncated` (official): each frame starts from the *detached* previous state, one random
  camera (`recon.cameras_per_frame`) is rendered, and Adam steps after every frame: the
  gradient of L_f reaches θ only through the last frame's n_t substeps. Memory: one frame's
  tape. If a frame becomes unstable (NaN/inf, `SimulationUnstable`) it is redone with
  `recon.nan_substep_increase` more substeps, kept for the rest of training (official remedy).
- `full`: the whole fit window is simulated with gradients through every frame
  (`rollout(grad_mode="full")`), the losses of all frames (cameras_per_frame random cameras
  each) are averaged and Adam steps once per pass. Memory: O(n_fit x n_t x N_A) (see
  sgdr.physics.simulate), heavier and slower per step but without truncation bias.

n_t follows `recon.substep_schedule` over the passes (official: 100 -> 150 -> 200).

Optional coarse start (`recon.log10_k_grid`, not in the official code): before the first pass
every listed uniform log10 k is scored by the deterministic all-view rollout loss and the best
one replaces physics.log10_k_init. Measured on the small torus, that loss is rugged in the
global stiffness and its local gradient points away from the better basin (README).

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

from sgdr.recon.common import posed, scalar
from sgdr.recon.config import ReconConfig
from sgdr.recon.optim import adam_from_numpy, adam_to_numpy, make_adam

log = logging.getLogger(__name__)


@dataclass
class DynamicsResult:
    log10_k: np.ndarray  # [N_A] identified log10 k_i
    kappa: float  # soft vector κ
    friction: float  # ground friction μ
    restitution: float  # restitution e ("coulomb" contact; unchanged otherwise)
    n_substeps: int  # n_t at the end of training (schedule end, raised on NaN)
    pass_losses: list[float] = field(default_factory=list)  # mean training loss per pass
    eval_loss_initial: float = float("nan")  # all views, all fit frames, before training
    eval_loss_final: float = float("nan")  # the same after training
    k_grid: dict[str, float] = field(default_factory=dict)  # uniform log10 k -> rollout loss (recon.log10_k_grid)


def learnable_names(physics_cfg) -> list[str]:
    """PhysParams fields optimised by the dynamic stage."""
    names = ["log10_k", "kappa", "friction"]
    if physics_cfg.contact == "coulomb":
        names.append("restitution")
    return names


def substeps_at(schedule: list[int], it: int, iterations: int) -> int:
    """n_t of pass `it`: the schedule split into equal spans over the passes."""
    if not schedule:
        raise ValueError("recon.substep_schedule is empty")
    k = min(len(schedule) - 1, (it * len(schedule)) // max(1, iterations))
    return int(schedule[k])


def _lr(cfg: ReconConfig, name: str) -> float:
    return float(getattr(cfg, f"lr_{name}"))


def clamp_to_ranges(opt, cfg: ReconConfig) -> None:
    """Project the optimised parameters back into their configured ranges (after each Adam step)."""
    opt["log10_k"] = dr.clip(opt["log10_k"], cfg.log10_k_min, cfg.log10_k_max)
    opt["friction"] = dr.clip(opt["friction"], 0.0, cfg.friction_max)
    if "restitution" in opt:
        opt["restitution"] = dr.clip(opt["restitution"], 0.0, 1.0)


def _with_opt(params, opt):
    return replace(params, **{k: opt[k] for k in opt.keys()})


def rollout_loss(model, params, binding, gaussians, v0, ground, targets, cameras, dt, n_t, physics_cfg, render_cfg, lam) -> float:
    """Forward-only mean loss over fit frames 1..n_fit-1 and all views of a rollout from rest.

    targets: [n_fit] lists of TensorXf [H, W, 3] per view; v0 [3]; dt seconds per frame.
    """
    from sgdr.physics import SimState, rollout
    from sgdr.recon.common import render
    from sgdr.render.losses import image_loss

    with dr.suspend_grad():
        state0 = SimState.at_rest(model, v0)
        states = rollout(model, params.detach(), state0, ground, len(targets), dt, physics_cfg, grad_mode="truncated", n_substeps=n_t)
        total, count = 0.0, 0
        for f in range(1, len(targets)):
            g = posed(gaussians, binding.apply(states[f].x))
            for v, cam in enumerate(cameras):
                total += scalar(image_loss(render(g, cam, render_cfg).rgb, targets[f][v], lam))
                count += 1
    return total / max(count, 1)


def _frame_loss(gaussians, binding, x, targets_f, cameras, views, render_cfg, lam):
    """Mean image loss of the bound Gaussians at anchor positions x (Array3f [N_A]) over `views`."""
    from sgdr.recon.common import render
    from sgdr.render.losses import image_loss

    g = posed(gaussians, binding.apply(x))
    loss = 0.0
    for v in views:
        loss = loss + image_loss(render(g, cameras[int(v)], render_cfg).rgb, targets_f[int(v)], lam)
    return loss / float(len(views))


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
    from sgdr.physics import PhysParams, SimState, SimulationUnstable, rollout, simulate_frame

    if cfg.mode not in ("truncated", "full"):
        raise ValueError(f"recon.mode must be 'truncated' or 'full', got {cfg.mode!r}")
    n_fit = len(targets)
    if n_fit < 2:
        raise ValueError(f"dynamic reconstruction needs at least 2 fit frames, the sequence has n_fit={n_fit}")
    dt = 1.0 / float(fps)
    lam = float(cfg.lambda_dssim)
    n_views = len(cameras)
    per_frame = max(1, min(int(cfg.cameras_per_frame), n_views))
    base = PhysParams.init(model, physics_cfg, v0=tuple(map(float, v0)), gravity=tuple(map(float, gravity)))
    n_t0 = substeps_at(list(cfg.substep_schedule), 0, cfg.iterations)
    resumed = ckpt.load() if ckpt is not None else None
    k_grid: dict[str, float] = {}
    if resumed is None and cfg.log10_k_grid:
        # ---- coarse start: the rollout loss is rugged in the global stiffness (bounces and
        # contacts shift in time), its local gradient does not point to the best basin
        for value in cfg.log10_k_grid:
            trial = replace(base, log10_k=dr.full(type(base.log10_k), float(value), model.n_anchors))
            k_grid[f"{float(value):g}"] = rollout_loss(model, trial, binding, gaussians.detach(), v0, ground, targets, cameras, dt, n_t0, physics_cfg, render_cfg, lam)
        best = min(k_grid, key=k_grid.get)
        log.info("dynamics: uniform log10 k grid %s -> start at %s", k_grid, best)
        base = replace(base, log10_k=dr.full(type(base.log10_k), float(best), model.n_anchors))
        dr.make_opaque(base.log10_k)
    opt = make_adam({name: (getattr(base, name), _lr(cfg, name)) for name in learnable_names(physics_cfg)})
    g = gaussians.detach()

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
        eval_initial = rollout_loss(model, base, binding, g, v0, ground, targets, cameras, dt, n_t0, physics_cfg, render_cfg, lam)

    passes = range(start, int(cfg.iterations))
    if progress:
        from tqdm import tqdm

        passes = tqdm(passes, desc=f"dynamics ({cfg.mode})", initial=start, total=int(cfg.iterations), leave=False)
    n_t = max(substeps_at(list(cfg.substep_schedule), start, cfg.iterations), n_t_floor)
    for it in passes:
        rng = np.random.default_rng([int(seed), it])
        n_t = max(substeps_at(list(cfg.substep_schedule), it, cfg.iterations), n_t_floor)
        frame_losses: list[float] = []
        if cfg.mode == "truncated":
            # ---- official schedule: frame by frame from the detached previous state
            state = SimState.at_rest(model, tuple(map(float, v0)))
            for f in range(1, n_fit):
                views = rng.choice(n_views, size=per_frame, replace=False)
                while True:
                    params = _with_opt(base, opt)
                    try:
                        new = simulate_frame(model, params, state, ground, dt, n_t, physics_cfg)
                        loss = _frame_loss(g, binding, new.x, targets[f], cameras, views, render_cfg, lam)
                        value = scalar(loss)
                    except SimulationUnstable:
                        value = float("nan")
                    if math.isfinite(value):
                        break
                    n_t = n_t_floor = n_t + int(cfg.nan_substep_increase)
                    if n_t > physics_cfg.max_substeps:
                        raise RuntimeError(
                            f"dynamics: frame {f} stays unstable with n_t={n_t} > physics.max_substeps="
                            f"{physics_cfg.max_substeps}; lower recon.lr_log10_k or recon.log10_k_max"
                        )
                    log.warning("dynamics: non-finite frame %d, n_t raised to %d", f, n_t)
                dr.backward(loss)
                opt.step()
                clamp_to_ranges(opt, cfg)
                frame_losses.append(value)
                state = new.detach()
                dr.eval(state.x, state.v)
        else:
            # ---- full: gradients through every fit frame, one step per pass
            params = _with_opt(base, opt)
            states = rollout(model, params, SimState.at_rest(model, tuple(map(float, v0))), ground, n_fit, dt, physics_cfg, grad_mode="full", n_substeps=n_t)
            loss = 0.0
            for f in range(1, n_fit):
                views = rng.choice(n_views, size=per_frame, replace=False)
                lf = _frame_loss(g, binding, states[f].x, targets[f], cameras, views, render_cfg, lam)
                loss = loss + lf
                frame_losses.append(scalar(lf))
            loss = loss / float(n_fit - 1)
            if not math.isfinite(scalar(loss)):
                raise RuntimeError(f"dynamics (full): non-finite loss at pass {it}; raise physics.n_substeps")
            dr.backward(loss)
            opt.step()
            clamp_to_ranges(opt, cfg)
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

    final = _with_opt(base, opt).detach()
    eval_final = rollout_loss(model, final, binding, g, v0, ground, targets, cameras, dt, n_t, physics_cfg, render_cfg, lam)

    def host(x) -> np.ndarray:
        return np.asarray(dr.detach(x).numpy(), dtype=np.float64).reshape(-1)

    return DynamicsResult(
        log10_k=host(final.log10_k),
        kappa=float(host(final.kappa)[0]),
        friction=float(host(final.friction)[0]),
        restitution=float(host(final.restitution)[0]),
        n_substeps=int(n_t),
        pass_losses=pass_losses,
        eval_loss_initial=eval_initial,
        eval_loss_final=eval_final,
        k_grid=k_grid,
    )
