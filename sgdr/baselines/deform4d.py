"""Simplified 4D Gaussian Splatting (4D-Gaus; Wu et al., "4D Gaussian Splatting for Real-Time
Dynamic Scene Rendering", CVPR 2024): one row of the paper's Table 2, SIMPLIFIED.

One deformation model for all fit frames moves the run's refined frame-0 Gaussians (the
canonical Gaussians; appearance frozen): a regular grid of R x R x R nodes over the frame-0
centres' box (padded by `box_margin` of its size per side) holds, per fit frame f = 1 .. n_fit-1,
a displacement D_f[n] of every node n, and

    μ_i,f = μ_i,0 + Σ_c w_ic D_f[n_ic]                  (trilinear: the 8 nodes of i's cell)

with the weights w_ic fixed by the frame-0 centre μ_i,0. Frame 0 is the given Gaussians (D_0 = 0).
All grids are fitted jointly by Adam on

    L = mean_f L_im,f + w_tv L_tv + w_time L_time,

    L_im,f = mean over views of (1-λ) L1 + λ D-SSIM of frame f             (sgdr.loss.image_loss)
    L_tv   = mean over frames and grid edges (n, n') of ρ((D_f[n'] - D_f[n]) / h)   (ρ: `tv`)
    L_time = mean over frames and nodes of ||D_f+1[n] - 2 D_f[n] + D_f-1[n]||² / h̄²

h is the cell size along the edge's axis, h̄ the mean cell size; ρ is `TV_PENALTIES[tv]`:
"l2" ||·||² (smoothness) or "l1" ||·|| (total variation). L_time is the second difference over
time of K-Planes / HexPlane's time smoothness (4D-GS's regulariser of its time planes).

The grids start at zero (`init: zero`) or, because the benchmark's object falls by more than its
size over the fit frames and a render that does not overlap its target has no gradient towards
it, frame by frame (`init: sequential`): D_f starts at D_f-1 (plus the last change with
`extrapolate`) and is fitted alone for `warmup_iterations` steps, before the joint fit.

What is simplified relative to the original:
- A dense per-frame displacement grid instead of 4D-GS's multi-resolution HexPlane (six
  factorised space-time planes) decoded by a small MLP; no time interpolation between frames
  (only the fit frames exist here).
- Only the centres deform (4D-GS also deforms rotations and scales); appearance is frozen at the
  refined frame-0 Gaussians; no densification, no coarse static stage (the refined Gaussians
  are the canonical space).
- Every view (or `views_per_step` random views) of every fit frame per Adam step, constant
  learning rate; the sequential start is ours (see above).

Returns the centres of every fit frame (`ReconstructionResult`); nothing is carried past n_fit.
"""

from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import numpy as np

from sgdr.arrays import array3_to_points, points_to_array3, scalar
from sgdr.backend import ad
from sgdr.baselines.common import (
    ReconstructionResult,
    check_targets,
    multiview_image_loss,
    steps_bar,
    view_choice,
)
from sgdr.baselines.config import Deform4DConfig
from sgdr.identify.adam import make_adam
from sgdr.registry import Registry


class Deform4DError(ValueError):
    """Inputs the deformation fit cannot use; the message names what is wrong."""


# ---------------------------------------------------------------------------- penalties
TV_PENALTIES = Registry("grid smoothness penalty", "baseline.deform4d.tv", ValueError)


@TV_PENALTIES.register("l2")
def tv_l2(diff):
    """||Δ||² of each edge's scaled difference (Array3f [E]) -> Float [E]: smoothness."""
    return dr.squared_norm(diff)


@TV_PENALTIES.register("l1")
def tv_l1(diff):
    """||Δ|| of each edge's scaled difference (Array3f [E]) -> Float [E]: total variation (a
    finite gradient at Δ = 0: sqrt(||Δ||² + 1e-12))."""
    return dr.sqrt(dr.squared_norm(diff) + 1e-12)


# ---------------------------------------------------------------------------- the grid
@dataclass
class DisplacementGrid:
    """Fixed layout of the per-frame grids and of the trilinear lookup at the frame-0 centres."""

    resolution: int  # R: nodes per axis
    lower: np.ndarray  # [3] the box's lower corner, world, scene units
    cell: np.ndarray  # [3] cell size h per axis, scene units
    corner_index: list  # 8 x UInt32 [M] node index (within one frame) of each Gaussian's cell corners
    corner_weight: list  # 8 x Float [M] trilinear weights w_ic (sum to 1 per Gaussian)
    edge_a: np.ndarray  # [E] int64 first node of each grid edge (within one frame)
    edge_b: np.ndarray  # [E] int64 its neighbour along one axis
    edge_inv_h: np.ndarray  # [E] float 1 / h along the edge's axis

    @property
    def nodes(self) -> int:
        """Nodes per frame, R³."""
        return self.resolution**3


def build_grid(centres0: np.ndarray, resolution: int, box_margin: float) -> DisplacementGrid:
    """The grid over the box of `centres0` [M, 3] and the trilinear lookup at those centres."""
    t = ad()
    centres0 = np.asarray(centres0, np.float64).reshape(-1, 3)
    if centres0.shape[0] == 0:
        raise Deform4DError("deform4d: no Gaussian to deform")
    r = int(resolution)
    lo, hi = centres0.min(0), centres0.max(0)
    size = np.maximum(hi - lo, 1e-6 * max(float(np.max(hi - lo)), 1e-6))  # a flat object keeps a cell
    lo, hi = lo - box_margin * size, hi + box_margin * size
    cell = (hi - lo) / (r - 1)
    u = (centres0 - lo) / cell  # [M, 3] in [0, R-1]
    i0 = np.clip(np.floor(u), 0, r - 2).astype(np.int64)  # [M, 3] lower corner of the cell
    frac = u - i0  # [M, 3] in [0, 1]
    index, weight = [], []
    for c in range(8):
        bits = np.array([(c >> 2) & 1, (c >> 1) & 1, c & 1])
        corner = i0 + bits  # [M, 3]
        index.append(t.UInt32(((corner[:, 0] * r + corner[:, 1]) * r + corner[:, 2]).astype(np.uint32)))
        w = np.prod(np.where(bits, frac, 1.0 - frac), axis=1)
        weight.append(t.Float(w.astype(np.float32)))
    grid_ids = np.arange(r**3).reshape(r, r, r)
    a, b, inv_h = [], [], []
    for axis in range(3):
        lo_slice = [slice(None)] * 3
        hi_slice = [slice(None)] * 3
        lo_slice[axis], hi_slice[axis] = slice(0, r - 1), slice(1, r)
        a.append(grid_ids[tuple(lo_slice)].reshape(-1))
        b.append(grid_ids[tuple(hi_slice)].reshape(-1))
        inv_h.append(np.full(a[-1].size, 1.0 / cell[axis]))
    return DisplacementGrid(r, lo, cell, index, weight, np.concatenate(a), np.concatenate(b), np.concatenate(inv_h))


def displacement(grid: DisplacementGrid, values, frame_offset):
    """Σ_c w_ic D[n_ic + frame_offset]: the displacement of every Gaussian (Array3f [M]).

    values: Array3f [F R³] the grids of F frames, node-major within a frame; frame_offset: UInt32
    (opaque) index of the frame's first node."""
    t = ad()
    out = t.Array3f(0.0)
    for idx, w in zip(grid.corner_index, grid.corner_weight):
        out += w * dr.gather(t.Array3f, values, idx + frame_offset)
    return out


@dataclass
class _Regulariser:
    """Index arrays of the smoothness terms over F frames' grids (Dr.Jit, fixed per fit)."""

    a: object  # UInt32 [F E] edge ends
    b: object  # UInt32 [F E]
    inv_h: object  # Float [F E] 1 / h along the edge
    t_mid: object  # UInt32 [T] node of frame f (f = 1 .. F-1 of the stacked grids, 0-based in `values`)
    t_next: object  # UInt32 [T] the same node in the next frame
    t_prev: object  # UInt32 [T] the same node in the previous frame (any index where it is frame 0)
    t_prev_live: object  # Float [T] 0 where the previous frame is frame 0 (D_0 = 0), else 1
    inv_h_mean: float  # 1 / h̄


def _regulariser(grid: DisplacementGrid, n_frames: int) -> _Regulariser:
    """Terms over `n_frames` stacked grids, the first of which is fit frame 1 (D_0 = 0 before it)."""
    t = ad()
    n = grid.nodes
    offsets = np.repeat(np.arange(n_frames) * n, grid.edge_a.size)
    a = np.tile(grid.edge_a, n_frames) + offsets
    b = np.tile(grid.edge_b, n_frames) + offsets
    inv_h = np.tile(grid.edge_inv_h, n_frames)
    # second differences D_k+1 - 2 D_k + D_k-1 for stacked frames k = 0 .. n_frames-2 (k-1 = -1: D_0 = 0)
    k = np.repeat(np.arange(max(n_frames - 1, 0)), n)
    node = np.tile(np.arange(n), max(n_frames - 1, 0))
    mid, nxt = k * n + node, (k + 1) * n + node
    prev = np.maximum(k - 1, 0) * n + node
    live = (k >= 1).astype(np.float32)
    return _Regulariser(
        a=t.UInt32(a.astype(np.uint32)),
        b=t.UInt32(b.astype(np.uint32)),
        inv_h=t.Float(inv_h.astype(np.float32)),
        t_mid=t.UInt32(mid.astype(np.uint32)),
        t_next=t.UInt32(nxt.astype(np.uint32)),
        t_prev=t.UInt32(prev.astype(np.uint32)),
        t_prev_live=t.Float(live),
        inv_h_mean=float(1.0 / grid.cell.mean()),
    )


def smoothness(reg: _Regulariser, values, penalty) -> object:
    """L_tv of the stacked grids `values` (Array3f [F R³]): a Float [1]."""
    t = ad()
    diff = (dr.gather(t.Array3f, values, reg.b) - dr.gather(t.Array3f, values, reg.a)) * reg.inv_h
    return dr.sum(penalty(diff)) * (1.0 / float(dr.width(reg.a)))


def time_smoothness(reg: _Regulariser, values) -> object:
    """L_time of the stacked grids (zero when there is one frame): a Float [1]."""
    t = ad()
    if dr.width(reg.t_mid) == 0:
        return t.Float(0.0)
    mid = dr.gather(t.Array3f, values, reg.t_mid)
    acc = (
        dr.gather(t.Array3f, values, reg.t_next)
        - 2.0 * mid
        + reg.t_prev_live * dr.gather(t.Array3f, values, reg.t_prev)
    )
    return dr.sum(dr.squared_norm(acc)) * (reg.inv_h_mean**2 / float(dr.width(reg.t_mid)))


# ---------------------------------------------------------------------------- the fit
def fit_deformation(
    gaussians,
    targets: list[list],
    cameras: list,
    render_cfg,
    cfg: Deform4DConfig,
    seed: int,
    progress: bool = False,
) -> ReconstructionResult:
    """Fit the per-frame displacement grids to the fit frames (module docstring).

    gaussians: the refined frame-0 `Gaussians` (M, the canonical ones). targets: per fit frame
    f = 0 .. n_fit-1, the images of every view (TensorXf [H, W, 3] each; frame 0's are not used).
    Returns centres [n_fit, M, 3] (frame 0: `gaussians.means`) and the losses of every Adam step.
    """
    check_targets(targets, cameras, Deform4DError, "deform4d")
    t = ad()
    g = gaussians.detach()
    mu0_np = array3_to_points(g.means)  # [M, 3]
    mu0 = g.means
    grid = build_grid(mu0_np, cfg.grid_resolution, cfg.box_margin)
    penalty = TV_PENALTIES.get_named(cfg.tv)
    n_moving = len(targets) - 1  # frames 1 .. n_fit-1
    n = grid.nodes
    rng = np.random.default_rng(seed)
    lam = float(cfg.lambda_dssim)
    losses, image_losses, step_frames = [], [], []
    if n_moving == 0:
        return ReconstructionResult(mu0_np[None], np.zeros(0), np.zeros(0), [])

    def posed(means):
        return type(g)(means, g.log_scales, g.rotations, g.color_logits, g.opacity_logits)

    def record(loss, l_im, frame):
        losses.append(scalar(loss))
        image_losses.append(scalar(l_im))
        step_frames.append(frame)

    # -- start: zero, or frame by frame (each grid alone, from the last)
    grids = np.zeros((n_moving, n, 3))  # [F-1, R³, 3]
    if cfg.init == "sequential":
        one = _regulariser(grid, 1)
        zero_offset = dr.opaque(t.UInt32, 0)
        for f in steps_bar(range(1, n_moving + 1), "deform4d start", progress):
            last = grids[f - 2] if f >= 2 else np.zeros((n, 3))
            before = grids[f - 3] if f >= 3 else np.zeros((n, 3))
            start = last + (last - before) if cfg.extrapolate else last
            opt = make_adam({"grid": (points_to_array3(start), cfg.lr)})
            for _ in range(int(cfg.warmup_iterations)):
                values = opt["grid"]
                views = view_choice(rng, len(cameras), cfg.views_per_step)
                means = mu0 + displacement(grid, values, zero_offset)
                l_im = multiview_image_loss(posed(means), targets[f], cameras, views, render_cfg, lam)
                loss = l_im + float(cfg.w_tv) * smoothness(one, values, penalty)
                dr.eval(loss, l_im)
                dr.backward(loss)
                opt.step()
                record(loss, l_im, f)
            grids[f - 1] = array3_to_points(opt["grid"])

    # -- joint fit of every frame's grid
    reg = _regulariser(grid, n_moving)
    offsets = [dr.opaque(t.UInt32, (f - 1) * n) for f in range(1, n_moving + 1)]
    opt = make_adam({"grid": (points_to_array3(grids.reshape(-1, 3)), cfg.lr)})
    for _ in steps_bar(range(int(cfg.iterations)), "deform4d joint", progress):
        values = opt["grid"]
        l_im = t.Float(0.0)
        for f in range(1, n_moving + 1):
            views = view_choice(rng, len(cameras), cfg.views_per_step)
            means = mu0 + displacement(grid, values, offsets[f - 1])
            l_im = l_im + multiview_image_loss(posed(means), targets[f], cameras, views, render_cfg, lam)
        l_im = l_im * (1.0 / n_moving)
        loss = l_im + float(cfg.w_tv) * smoothness(reg, values, penalty)
        if n_moving >= 2:
            loss = loss + float(cfg.w_time) * time_smoothness(reg, values)
        dr.eval(loss, l_im)
        dr.backward(loss)
        opt.step()
        record(loss, l_im, -1)

    values = dr.detach(opt["grid"])
    centres = [mu0_np]
    with dr.suspend_grad():
        for f in range(1, n_moving + 1):
            centres.append(array3_to_points(mu0 + displacement(grid, values, offsets[f - 1])))
    return ReconstructionResult(np.stack(centres), np.asarray(losses), np.asarray(image_losses), step_frames)
