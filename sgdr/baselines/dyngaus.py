"""Simplified Dynamic 3D Gaussians (Dy-Gaus; Luiten et al., "Dynamic 3D Gaussians: Tracking by
Persistent Dynamic View Synthesis", 3DV 2024): one row of the paper's Table 2, SIMPLIFIED.

The run's refined frame-0 Gaussians are tracked frame by frame, t = 1 .. n_fit-1. Their
appearance (scales, colours, opacities) is frozen; per frame the centres μ_i,t and (with
`rotations`) a rotation q_i,t per Gaussian are fitted by Adam to every view's image of frame t,
starting from frame t-1 (plus the last frame's velocity: Luiten et al.'s constant-velocity
initialisation), under the loss (Luiten et al., Sec. 4)

    L = L_im + w_rigid L_rigid + w_rot L_rot + w_iso L_iso,

    L_im    = mean over views of (1-λ) L1 + λ D-SSIM                      (sgdr.loss.image_loss)
    L_rigid = mean_ij w_ij || ΔR_i (μ_j,t-1 - μ_i,t-1) - (μ_j,t - μ_i,t) || / d̄
    L_rot   = mean_ij w_ij || Δq̂_j - Δq̂_i ||
    L_iso   = mean_ij w_ij | ||μ_j,t - μ_i,t|| - ||μ_j,0 - μ_i,0|| | / d̄

over the pairs (i, j): j among the `n_neighbours` nearest frame-0 centres of i, with weights
w_ij = exp(-λ_w (||μ_j,0 - μ_i,0|| / d̄)²) and d̄ the mean kNN distance. Δq_i = q_i,t q_i,t-1⁻¹
is the rotation of Gaussian i since the last frame (ΔR_i its matrix); the paper's rigidity term
R_i,t-1 R_i,t⁻¹ (μ_j,t - μ_i,t) compared with the previous offset is the same quantity rotated
by ΔR_i, which keeps lengths. Without `rotations`, ΔR_i = I (translation-only rigidity).

What is simplified relative to the original:
- Appearance is frozen at the refined frame-0 Gaussians; no per-timestep colour, opacity or
  scale, no background or segmentation loss, no densification.
- Gaussians are the sgdr static fit's (isotropic: the rotation does not change the render; it
  is a latent of the rigidity prior, and rotates anisotropic Gaussians when they are given).
- Every view (or `views_per_step` random views) per Adam step instead of one random camera;
  constant learning rates; `iterations` steps per frame at the preset's scale.
- The neighbour weights and the two distance priors are written relative to d̄ so the weights
  do not depend on the scene's units (Luiten et al. use λ_w = 2000 in their units).

Returns the centres of every fit frame (`ReconstructionResult`); nothing is carried past n_fit.
"""

from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import numpy as np
from scipy.spatial import cKDTree

from sgdr.arrays import array3_to_points, points_to_array3, scalar, to_numpy
from sgdr.backend import ad
from sgdr.baselines.common import (
    ReconstructionResult,
    check_targets,
    multiview_image_loss,
    steps_bar,
    view_choice,
)
from sgdr.baselines.config import DynGausConfig
from sgdr.identify.adam import make_adam


class DynGausError(ValueError):
    """Inputs the tracker cannot use; the message names what is wrong."""


# ---------------------------------------------------------------------------- neighbours
@dataclass
class Neighbours:
    """The kNN pairs (i, j) of the frame-0 centres the priors act on (fixed for the sequence)."""

    i: object  # UInt32 [P] first Gaussian of each pair
    j: object  # UInt32 [P] its neighbour
    weight: object  # Float [P] w_ij = exp(-λ_w (d_ij / d̄)²)
    rest_length: object  # Float [P] ||μ_j,0 - μ_i,0||, scene units
    mean_distance: float  # d̄: mean kNN distance, scene units
    pairs: np.ndarray  # [P, 2] int64, the same pairs on the host (tests, diagnostics)


def neighbour_pairs(centres0: np.ndarray, k: int, weight_falloff: float) -> Neighbours:
    """kNN pairs of `centres0` [M, 3] (each Gaussian with its k nearest others, k capped at M-1)."""

    centres0 = np.asarray(centres0, np.float64).reshape(-1, 3)
    m = centres0.shape[0]
    if m < 2:
        raise DynGausError(f"dyngaus: {m} Gaussian(s); the priors need at least 2")
    k = min(int(k), m - 1)
    dist, idx = cKDTree(centres0).query(centres0, k=k + 1)  # [M, k+1], nearest first (itself)
    dist = np.asarray(dist).reshape(m, k + 1)[:, 1:]
    idx = np.asarray(idx).reshape(m, k + 1)[:, 1:]
    d_bar = float(dist.mean())
    if not d_bar > 0:
        raise DynGausError("dyngaus: every Gaussian sits on its neighbours (mean kNN distance 0)")
    i = np.repeat(np.arange(m), k)
    j = idx.reshape(-1)
    d = dist.reshape(-1)
    w = np.exp(-float(weight_falloff) * (d / d_bar) ** 2)
    t = ad()
    return Neighbours(
        i=t.UInt32(i.astype(np.uint32)),
        j=t.UInt32(j.astype(np.uint32)),
        weight=t.Float(w.astype(np.float32)),
        rest_length=t.Float(d.astype(np.float32)),
        mean_distance=d_bar,
        pairs=np.stack([i, j], axis=1),
    )


# ---------------------------------------------------------------------------- quaternions
def _safe_norm(v, eps: float):
    """|v| with a finite gradient at 0 (sqrt(|v|² + eps²))."""
    return dr.sqrt(dr.squared_norm(v) + eps * eps)


def normalised(q):
    """Array4f (w, x, y, z) -> unit quaternion (guarded: a zero q has a finite gradient)."""
    return q * dr.rsqrt(dr.squared_norm(q) + 1e-12)


def quat_rotate(q, p):
    """Rotate Array3f p by the unit quaternion q = (w, x, y, z): p + 2w (v x p) + 2 v x (v x p)."""
    t = ad()
    v = t.Array3f(q[1], q[2], q[3])
    vxp = dr.cross(v, p)
    return p + 2.0 * q[0] * vxp + 2.0 * dr.cross(v, vxp)


def quat_mul(a, b):
    """Hamilton product a b of (w, x, y, z) quaternions (Array4f)."""
    t = ad()
    return t.Array4f(
        a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3],
        a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2],
        a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1],
        a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0],
    )


# ---------------------------------------------------------------------------- priors
@dataclass
class Priors:
    """The three priors of one frame (Dr.Jit scalars carrying gradients)."""

    rigid: object  # L_rigid
    rot: object  # L_rot (0 without rotations)
    iso: object  # L_iso


def priors(nb: Neighbours, means, means_prev, dq) -> Priors:
    """L_rigid, L_rot, L_iso of frame t (module docstring).

    means: Array3f [M] centres μ_t (carry gradients); means_prev: Array3f [M] μ_t-1 (detached);
    dq: Array4f [M] unit rotations since t-1, or None (identity: translation-only rigidity).
    """
    t = ad()
    eps = 1e-6 * nb.mean_distance
    inv_p = 1.0 / float(dr.width(nb.i))
    inv_d = 1.0 / nb.mean_distance
    offset = dr.gather(t.Array3f, means, nb.j) - dr.gather(t.Array3f, means, nb.i)  # [P] μ_j,t - μ_i,t
    offset_prev = dr.gather(t.Array3f, means_prev, nb.j) - dr.gather(t.Array3f, means_prev, nb.i)  # [P]
    rot = t.Float(0.0)
    if dq is not None:
        dq_i = dr.gather(t.Array4f, dq, nb.i)
        offset_prev = quat_rotate(dq_i, offset_prev)
        rot = dr.sum(nb.weight * _safe_norm(dr.gather(t.Array4f, dq, nb.j) - dq_i, 1e-6)) * inv_p
    rigid = dr.sum(nb.weight * _safe_norm(offset_prev - offset, eps)) * (inv_p * inv_d)
    iso = dr.sum(nb.weight * dr.abs(_safe_norm(offset, eps) - nb.rest_length)) * (inv_p * inv_d)
    return Priors(rigid, rot, iso)


# ---------------------------------------------------------------------------- tracking
def track_gaussians(
    gaussians,
    targets: list[list],
    cameras: list,
    render_cfg,
    cfg: DynGausConfig,
    seed: int,
    progress: bool = False,
) -> ReconstructionResult:
    """Track the frozen frame-0 Gaussians through the fit frames (module docstring).

    gaussians: the refined frame-0 `Gaussians` (M). targets: per fit frame f = 0 .. n_fit-1, the
    images of every view (TensorXf [H, W, 3] each; frame 0's are not used). cameras: one per view.
    Returns centres [n_fit, M, 3] (frame 0: `gaussians.means`) and the losses of every Adam step.
    """
    check_targets(targets, cameras, DynGausError, "dyngaus", "no fit frame to track")
    g = gaussians.detach()
    m = g.count
    mu0 = array3_to_points(g.means)  # [M, 3]
    nb = neighbour_pairs(mu0, cfg.n_neighbours, cfg.weight_falloff)
    own_rotation = to_numpy(g.rotations).T.reshape(-1, 4)  # [M, 4] the Gaussians' own (w, x, y, z)
    rng = np.random.default_rng(seed)
    lam = float(cfg.lambda_dssim)

    centres = [mu0]
    cumulative = np.tile([1.0, 0.0, 0.0, 0.0], (m, 1))  # [M, 4] q_t: rotation of each Gaussian since frame 0
    dq_last = np.tile([1.0, 0.0, 0.0, 0.0], (m, 1))  # [M, 4] Δq of the last tracked frame
    losses, image_losses, step_frames = [], [], []
    frames = steps_bar(range(1, len(targets)), "dyngaus frames", progress)
    for f in frames:
        # -- start: frame t-1, plus its velocity (and angular velocity) when extrapolating
        prev = centres[-1]
        velocity = prev - centres[-2] if cfg.extrapolate and len(centres) >= 2 else 0.0
        dq_start = dq_last if cfg.extrapolate else np.tile([1.0, 0.0, 0.0, 0.0], (m, 1))
        params = {"means": (points_to_array3(prev + velocity), cfg.lr_means)}
        if cfg.rotations:
            params["rotations"] = (_array4(dq_start), cfg.lr_rotations)
        opt = make_adam(params)
        means_prev = points_to_array3(prev)
        # the rendered rotation is Δq q_t-1 q_own (only anisotropic Gaussians see it)
        base = quat_mul(_array4(cumulative), _array4(own_rotation))

        for _ in steps_bar(range(int(cfg.iterations)), f"dyngaus frame {f}", progress):
            means = opt["means"]
            dq = normalised(opt["rotations"]) if cfg.rotations else None
            rotations = quat_mul(dq, base) if cfg.rotations else g.rotations
            posed = type(g)(means, g.log_scales, rotations, g.color_logits, g.opacity_logits)
            views = view_choice(rng, len(cameras), cfg.views_per_step)
            l_im = multiview_image_loss(posed, targets[f], cameras, views, render_cfg, lam)
            p = priors(nb, means, means_prev, dq)
            loss = l_im + float(cfg.w_rigid) * p.rigid + float(cfg.w_iso) * p.iso
            if cfg.rotations:
                loss = loss + float(cfg.w_rot) * p.rot
            dr.eval(loss, l_im)
            dr.backward(loss)
            opt.step()
            losses.append(scalar(loss))
            image_losses.append(scalar(l_im))
            step_frames.append(f)

        # -- the frame's result becomes the next frame's start
        centres.append(array3_to_points(opt["means"]))
        if cfg.rotations:
            dq_last = to_numpy(normalised(opt["rotations"])).T.reshape(-1, 4)
            cumulative = to_numpy(quat_mul(_array4(dq_last), _array4(cumulative))).T.reshape(-1, 4)
    return ReconstructionResult(np.stack(centres), np.asarray(losses), np.asarray(image_losses), step_frames)


def _array4(q: np.ndarray):
    """np [M, 4] -> Array4f [M]."""
    t = ad()
    return t.Array4f(*[t.Float(np.ascontiguousarray(q[:, k], dtype=np.float32)) for k in range(4)])
