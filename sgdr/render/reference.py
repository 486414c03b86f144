"""Slow, dense NumPy reference of `sgdr.render.splat` (float64; used only by tests).

Same projection, footprint radius, tile membership (bounding square, then the disc test), depth order, alpha cutoffs, α clamp and
early termination as the Dr.Jit renderer, written as plainly as possible: Gaussians are
visited one at a time in front-to-back order and composited into every pixel of every tile
their footprint rectangle overlaps (vectorised over pixels only). Gradients of the reference are
taken by central finite differences (`reference_vjp`).
"""

from __future__ import annotations

import numpy as np

from sgdr.cameras import Camera
from sgdr.render.config import RenderConfig


def _sigmoid(x):
    return 1.0 / (1.0 + np.exp(-x))


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """[M, 4] (w, x, y, z) -> [M, 3, 3] rotations (normalised first)."""
    q = q / np.sqrt(np.maximum((q * q).sum(-1, keepdims=True), 1e-24))
    w, x, y, z = q.T
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def project_numpy(p: dict, camera: Camera, cfg: RenderConfig) -> dict:
    """Per-Gaussian screen quantities, as `splat.project` (float64)."""
    pc = p["means"] @ camera.R.T + camera.t  # [M, 3]
    z = pc[:, 2]
    visible = z > cfg.near
    zs = np.where(visible, z, 1.0)
    fx, fy, cx, cy = camera.K[0, 0], camera.K[1, 1], camera.K[0, 2], camera.K[1, 2]
    u = fx * pc[:, 0] / zs + cx
    v = fy * pc[:, 1] / zs + cy
    lim_x = cfg.guard_band * 0.5 * camera.width / fx
    lim_y = cfg.guard_band * 0.5 * camera.height / fy
    tx = np.clip(pc[:, 0] / zs, -lim_x, lim_x)
    ty = np.clip(pc[:, 1] / zs, -lim_y, lim_y)
    m = len(z)
    J = np.zeros((m, 2, 3))
    J[:, 0, 0] = fx / zs
    J[:, 0, 2] = -fx * tx / zs
    J[:, 1, 1] = fy / zs
    J[:, 1, 2] = -fy * ty / zs
    Rq = quat_to_matrix(p["rotations"])
    Sig = Rq @ (np.exp(2 * p["log_scales"])[:, :, None] * np.transpose(Rq, (0, 2, 1)))  # [M,3,3]
    T = J @ camera.R  # [M, 2, 3]
    cov = T @ Sig @ np.transpose(T, (0, 2, 1)) + cfg.dilation * np.eye(2)
    a, b, c = cov[:, 0, 0], cov[:, 0, 1], cov[:, 1, 1]
    det = a * c - b * b
    visible &= det > 0
    dets = np.where(visible, det, 1.0)
    mid = 0.5 * (a + c)
    lam = mid + np.sqrt(np.maximum(0.1, mid * mid - det))
    opacity = _sigmoid(p["opacity_logits"])
    with np.errstate(divide="ignore"):
        k_sigma = np.minimum(3.0, np.sqrt(np.maximum(2.0 * np.log(opacity / cfg.alpha_min), 0.0)))
    radius = np.where(visible, np.ceil(k_sigma * np.sqrt(lam)), 0.0)
    return {
        "uv": np.stack([u, v], -1),
        "conic": np.stack([c / dets, -b / dets, a / dets], -1),
        "color": _sigmoid(p["color_logits"]),
        "opacity": opacity,
        "depth": z,
        "radius": radius,
    }


def render_numpy(p: dict, camera: Camera, cfg: RenderConfig) -> tuple[np.ndarray, np.ndarray]:
    """Dense reference render: (rgb [H, W, 3], alpha [H, W]) in float64.

    p: the dict of `Gaussians.to_numpy()` (means, log_scales, rotations, color_logits [M, 3|4],
    opacity_logits [M]).
    """
    H, W, ts = camera.height, camera.width, int(cfg.tile_size)
    tiles_x, tiles_y = -(-W // ts), -(-H // ts)
    bg = np.asarray(cfg.background, dtype=np.float64)
    C = np.zeros((H, W, 3))
    T = np.ones((H, W))
    done = np.zeros((H, W), dtype=bool)
    if len(p["opacity_logits"]) == 0:
        return C + bg, 1.0 - T
    q = project_numpy(p, camera, cfg)
    ys, xs = np.mgrid[0:H, 0:W]
    pxc, pyc = xs + 0.5, ys + 0.5
    tile_of_x, tile_of_y = xs // ts, ys // ts
    order = np.argsort(np.where(q["radius"] > 0, q["depth"], np.inf), kind="stable")
    for i in order:
        r = q["radius"][i]
        if r <= 0:
            continue
        u, v = q["uv"][i]
        x0 = int(np.clip(np.floor((u - r) / ts), 0, tiles_x))
        x1 = int(np.clip(np.floor((u + r + ts - 1) / ts), 0, tiles_x))
        y0 = int(np.clip(np.floor((v - r) / ts), 0, tiles_y))
        y1 = int(np.clip(np.floor((v + r + ts - 1) / ts), 0, tiles_y))
        in_rect = (tile_of_x >= x0) & (tile_of_x < x1) & (tile_of_y >= y0) & (tile_of_y < y1)
        # the footprint disc must reach a pixel centre of the pixel's tile
        tx0, ty0 = tile_of_x * ts + 0.5, tile_of_y * ts + 0.5
        ddx = u - np.clip(u, tx0, tx0 + ts - 1)
        ddy = v - np.clip(v, ty0, ty0 + ts - 1)
        in_rect &= ddx * ddx + ddy * ddy <= r * r
        a_, b_, c_ = q["conic"][i]
        dx, dy = u - pxc, v - pyc
        power = -0.5 * (a_ * dx * dx + c_ * dy * dy) - b_ * dx * dy
        alpha = np.minimum(cfg.alpha_max, q["opacity"][i] * np.exp(power))
        contrib = in_rect & ~done & (power <= 0) & (alpha >= cfg.alpha_min)
        T_next = T * (1 - alpha)
        stop = contrib & (T_next < cfg.transmittance_min)
        done |= stop
        contrib &= ~stop
        C += np.where(contrib[..., None], q["color"][i] * (alpha * T)[..., None], 0.0)
        T = np.where(contrib, T_next, T)
    return C + T[..., None] * bg, 1.0 - T


FIELDS = ("means", "log_scales", "rotations", "color_logits", "opacity_logits")


def reference_vjp(p: dict, camera: Camera, cfg: RenderConfig, w_rgb: np.ndarray, w_alpha: np.ndarray, eps=1e-5) -> dict:
    """Gradient of L = <w_rgb, rgb> + <w_alpha, alpha> w.r.t. every entry of every field of
    `p`, by central finite differences of `render_numpy` (float64). Returns arrays shaped
    like the fields."""

    def loss(pp):
        rgb, alpha = render_numpy(pp, camera, cfg)
        return float((w_rgb * rgb).sum() + (w_alpha * alpha).sum())

    grads = {}
    for name in FIELDS:
        base = np.asarray(p[name], dtype=np.float64)
        g = np.zeros_like(base)
        for idx in np.ndindex(base.shape):
            hi = {k: np.array(v, dtype=np.float64) for k, v in p.items()}
            lo = {k: np.array(v, dtype=np.float64) for k, v in p.items()}
            hi[name][idx] += eps
            lo[name][idx] -= eps
            g[idx] = (loss(hi) - loss(lo)) / (2 * eps)
        grads[name] = g
    return grads
