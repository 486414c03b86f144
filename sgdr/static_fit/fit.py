"""Static reconstruction: fit Gaussians to the first frame of every view (pipeline stage (a)).

The official Spring-Gaus recipe: `n_init` points drawn uniformly inside a box around the
object (so the kernels fill the volume instead of hugging the surface), one constant isotropic
scale s0 (not optimised in this stage), identity rotations, and Adam (`mi.ad.Adam`, i.e.
`drjit.opt.Adam`) on centres, colour logits and opacity logits with per-parameter learning
rates from `StaticFitConfig`. Each step renders `views_per_step` random views and minimises

    L = (1 - λ) L1 + λ D-SSIM  (+ λ_mask |A - mask|)      λ = `lambda_dssim` (0.2 in the paper)

against the images composited over the render background. Every `prune_every` steps (and at
the end) Gaussians whose opacity fell below `prune_opacity` are removed; Adam's moments are
reset for the smaller arrays (3DGS instead subsets them; with rare prunings this is minor).
The position learning rate decays exponentially from `lr_position` to `lr_position_final`
(the 3DGS schedule).

Inputs: RGBA images [H, W, 4] float32 in [0, 1], RGB premultiplied (on black), alpha = mask, as
`Sequence.image` returns them, and their cameras (OpenCV).
Output: detached `Gaussians` (isotropic, log-scale log(s0)).
"""

from __future__ import annotations

import logging

import drjit as dr
import numpy as np
from tqdm import tqdm

from sgdr.arrays import to_numpy
from sgdr.backend import ad
from sgdr.cameras import Camera
from sgdr.gaussians.model import Gaussians, sigmoid
from sgdr.loss import image_loss, mask_loss
from sgdr.render.config import RenderConfig
from sgdr.render.splat import render
from sgdr.static_fit.config import StaticFitConfig

log = logging.getLogger(__name__)


class StaticFitError(ValueError):
    """Invalid static-fit input; the message names the view or setting."""


def _check_inputs(images, cameras):
    if len(images) == 0 or len(images) != len(cameras):
        raise StaticFitError(
            f"fit_static: need one image per camera, got {len(images)} images and {len(cameras)} cameras"
        )
    for i, (img, cam) in enumerate(zip(images, cameras)):
        shape = np.shape(img)
        if shape != (cam.height, cam.width, 4):
            raise StaticFitError(
                f"fit_static: image {i} (camera {cam.name!r}) has shape {shape}, "
                f"expected ({cam.height}, {cam.width}, 4) RGBA from the camera"
            )
        if not np.all(np.isfinite(img)):
            raise StaticFitError(f"fit_static: image {i} (camera {cam.name!r}) has non-finite values")


def common_look_point(cameras: list[Camera]) -> np.ndarray:
    """[3] least-squares point closest to every camera's optical axis (world)."""
    A, b = np.zeros((3, 3)), np.zeros(3)
    for cam in cameras:
        d = cam.R[2]  # viewing direction (camera z) in world coordinates
        P = np.eye(3) - np.outer(d, d)
        A += P
        b += P @ cam.centre
    return np.linalg.lstsq(A + 1e-9 * np.eye(3), b, rcond=None)[0]


def box_from_masks(images, cameras: list[Camera], cfg: StaticFitConfig) -> tuple[np.ndarray, np.ndarray]:
    """Visual-hull box: voxels of a cube around the cameras' common look point are kept when
    they project inside the mask (alpha > 0.5) of every view; returns their bounding box,
    padded by one voxel and `box_margin` (relative)."""
    _check_inputs(images, cameras)
    centre = common_look_point(cameras)
    half = cfg.carve_extent * np.mean([np.linalg.norm(c.centre - centre) for c in cameras])
    n = int(cfg.carve_grid)
    ax = np.linspace(-half, half, n)
    pts = centre + np.stack(np.meshgrid(ax, ax, ax, indexing="ij"), -1).reshape(-1, 3)
    keep = np.ones(len(pts), dtype=bool)
    for img, cam in zip(images, cameras):
        uv, z = cam.project(pts)
        with np.errstate(invalid="ignore"):
            x, y = np.floor(uv[:, 0]), np.floor(uv[:, 1])
        inside = (z > 0) & (x >= 0) & (x < cam.width) & (y >= 0) & (y < cam.height)
        hit = np.zeros(len(pts), dtype=bool)
        hit[inside] = np.asarray(img)[y[inside].astype(int), x[inside].astype(int), 3] > 0.5
        keep &= hit
    if not keep.any():
        raise StaticFitError(
            "fit_static: carving the masks left no voxel inside every view's mask; "
            "pass an explicit box or check the cameras/masks (static_fit.carve_extent)"
        )
    voxel = 2 * half / (n - 1)
    lo, hi = pts[keep].min(0) - voxel, pts[keep].max(0) + voxel
    pad = cfg.box_margin * (hi - lo)
    return lo - pad, hi + pad


def _targets(images, background):
    t = ad()
    bg = np.asarray(background, dtype=np.float32)
    rgbs, masks = [], []
    for img in images:
        img = np.asarray(img, dtype=np.float32)
        a = img[..., 3:4]  # RGB is premultiplied (on black, sgdr.data.sequence): over the background
        rgbs.append(t.TensorXf(np.ascontiguousarray(img[..., :3] + bg * (1 - a))))
        masks.append(t.TensorXf(np.ascontiguousarray(img[..., 3])))
    return rgbs, masks


def _make_optimizer(means, color_logits, opacity_logits, cfg: StaticFitConfig):
    import mitsuba as mi

    opt = mi.ad.Adam(lr=cfg.lr_position)
    opt["means"] = means
    opt["color_logits"] = color_logits
    opt["opacity_logits"] = opacity_logits
    opt.set_learning_rate({"means": cfg.lr_position, "color_logits": cfg.lr_color, "opacity_logits": cfg.lr_opacity})
    return opt


def fit_static(
    images: list[np.ndarray],
    cameras: list[Camera],
    cfg: StaticFitConfig,
    render_cfg: RenderConfig,
    box: tuple[np.ndarray, np.ndarray] | None = None,
    seed: int = 0,
    progress: bool = True,
) -> Gaussians:
    """Fit isotropic Gaussians of constant scale `cfg.s0` to posed RGBA images (see module)."""

    t = ad()
    _check_inputs(images, cameras)
    if cfg.n_init <= 0 or cfg.s0 <= 0 or cfg.iterations < 0:
        raise StaticFitError(f"static_fit: n_init, s0 must be positive and iterations >= 0, got {cfg}")
    if box is None:
        lo, hi = box_from_masks(images, cameras, cfg)
    else:
        lo, hi = (np.asarray(x, dtype=np.float64).reshape(3) for x in box)
        if not np.all(hi > lo):
            raise StaticFitError(f"fit_static: box must have hi > lo, got lo={lo}, hi={hi}")
    rng = np.random.default_rng(seed)
    g0 = Gaussians.isotropic(rng.uniform(lo, hi, (int(cfg.n_init), 3)), cfg.s0, np.full(3, 0.5), cfg.init_opacity)
    targets, masks = _targets(images, render_cfg.background)
    opt = _make_optimizer(g0.means, g0.color_logits, g0.opacity_logits, cfg)
    n_views, k = len(cameras), min(int(cfg.views_per_step), len(cameras))
    n_it = int(cfg.iterations)
    decay = (cfg.lr_position_final / cfg.lr_position) ** (1.0 / max(n_it - 1, 1))

    def current(count):
        rot = t.Array4f(
            dr.ones(t.Float, count), dr.zeros(t.Float, count), dr.zeros(t.Float, count), dr.zeros(t.Float, count)
        )
        s = dr.full(t.Float, float(np.log(cfg.s0)), count)
        return Gaussians(opt["means"], t.Array3f(s, s, s), rot, opt["color_logits"], opt["opacity_logits"])

    def prune():
        nonlocal opt
        op = sigmoid(to_numpy(opt["opacity_logits"]))
        keep = op >= cfg.prune_opacity
        if keep.all():
            return
        if not keep.any():
            raise StaticFitError(
                f"fit_static: every Gaussian fell below static_fit.prune_opacity={cfg.prune_opacity}; "
                "check the images/masks or lower the threshold"
            )
        lr_now = opt.learning_rate("means")
        sub = current(len(op)).subset(keep)
        opt = _make_optimizer(sub.means, sub.color_logits, sub.opacity_logits, cfg)
        opt.set_learning_rate({"means": lr_now})

    bar = tqdm(range(n_it), disable=not progress, desc="static fit", unit="it")
    for it in bar:
        g = current(dr.width(opt["opacity_logits"]))
        views = rng.choice(n_views, size=k, replace=False)
        loss = None
        for v in views:
            out = render(g, cameras[v], render_cfg)
            term = image_loss(out.rgb, targets[v], cfg.lambda_dssim)
            if cfg.lambda_mask > 0:
                term = term + cfg.lambda_mask * mask_loss(out.alpha, masks[v])
            loss = term if loss is None else loss + term
        loss = loss / float(k)
        dr.backward(loss)
        opt.step()
        opt.set_learning_rate({"means": cfg.lr_position * decay ** (it + 1)})
        if progress and it % 25 == 0:
            bar.set_postfix(loss=f"{float(loss.array[0]):.4f}", n=dr.width(opt["opacity_logits"]))
        if cfg.prune_every > 0 and (it + 1) % cfg.prune_every == 0:
            prune()
    prune()
    final = current(dr.width(opt["opacity_logits"]))
    return final.detach()
