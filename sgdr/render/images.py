"""Rendering Gaussians posed at given centres: `posed`, `render` (Dr.Jit, differentiable) and its
NumPy-returning forms, `to_tensor` for target images."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from sgdr.arrays import to_numpy
from sgdr.backend import ad
from sgdr.render.splat import render as splat


def to_tensor(img: np.ndarray):
    """[H, W, 3|4] float image in [0, 1] -> TensorXf [H, W, 3] (alpha dropped: the benchmark
    renders on black, so the RGB already holds the silhouette)."""
    t = ad()
    return t.TensorXf(np.ascontiguousarray(np.asarray(img)[..., :3], dtype=np.float32))


def posed(gaussians, means):
    """The Gaussians with their centres replaced (means: Array3f [M], may carry gradients)."""
    return replace(gaussians, means=means)


def isotropic_log_scale(gaussians):
    """Float [M]: the one log scale of each isotropic Gaussian (mean of its three entries)."""
    s = gaussians.log_scales
    return (s[0] + s[1] + s[2]) / 3.0


def as_array3(log_scale):
    """Float [M] -> Array3f [M] with three equal entries (isotropic scales)."""
    return ad().Array3f(log_scale, log_scale, log_scale)


def render(gaussians, camera, render_cfg):
    """`sgdr.render`'s splatting renderer (CONTRACTS.md): RenderOutput(rgb [H, W, 3], alpha)."""

    return splat(gaussians, camera, render_cfg)


def render_rgb_numpy(gaussians, camera, render_cfg) -> np.ndarray:
    """Forward-only render -> np [H, W, 3] float32 in [0, 1]."""
    import drjit as dr

    with dr.suspend_grad():
        out = render(gaussians, camera, render_cfg)
        return np.clip(to_numpy(out.rgb, np.float32), 0.0, 1.0)


def render_rgba_numpy(gaussians, camera, render_cfg) -> np.ndarray:
    """Forward-only render -> np [H, W, 4] float32 in [0, 1]: RGB over black (premultiplied) and
    the accumulated opacity, so a background (the report's ground) can be composited behind it."""
    import drjit as dr

    with dr.suspend_grad():
        out = render(gaussians, camera, render_cfg)
        rgb = to_numpy(out.rgb, np.float32)
        alpha = to_numpy(out.alpha, np.float32).reshape(rgb.shape[:2] + (1,))
        return np.clip(np.concatenate([rgb, alpha], axis=-1), 0.0, 1.0)
