"""Pipeline stage 3: refine scale, colour and opacity at the IDW positions (frame 0).

Binding the Gaussians to the anchors moves their centres: with the official IDW form
(Eq. 14) a centre becomes the weighted mean of its n_b anchors, μ_i = Σ_j w_ij x_j / Σ_j w_ij,
which is generally not where the static fit put it. This stage keeps those bound centres
fixed (`means` = binding applied to the rest anchors, no gradient) and re-fits each Gaussian's
isotropic log scale, colour logits and opacity logit with Adam on the first frame of every
view, so the bound Gaussians render frame 0 correctly before any dynamics.

Inputs: Gaussians (static fit), bound centres Array3f [M] world, frame-0 targets (TensorXf
[H, W, 3] per view), cameras. Output: refined Gaussians (detached) and the loss per step.
"""

from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import numpy as np

from sgdr.arrays import scalar
from sgdr.identify.adam import make_adam
from sgdr.identify.config import ReconConfig
from sgdr.loss import image_loss
from sgdr.render.images import as_array3, isotropic_log_scale, render


@dataclass
class RefineResult:
    gaussians: object  # Gaussians [M], detached, centres at the IDW positions
    losses: list[float]  # (1-λ) L1 + λ D-SSIM per step


def refine_appearance(
    gaussians, means, targets: list, cameras: list, cfg: ReconConfig, render_cfg, seed: int, progress: bool = False
) -> RefineResult:
    """Adam over (log scale [M], colour logits [M, 3], opacity logits [M]) at fixed `means`.

    One random view per step (seeded); `cfg.refine_iterations` steps; learning rates
    `cfg.lr_scale`, `cfg.lr_color`, `cfg.lr_opacity`; loss weight `cfg.refine_lambda_dssim`.
    """

    means = dr.detach(means)
    g = gaussians.detach()
    opt = make_adam(
        {
            "log_scale": (isotropic_log_scale(g), cfg.lr_scale),
            "color_logits": (g.color_logits, cfg.lr_color),
            "opacity_logits": (g.opacity_logits, cfg.lr_opacity),
        }
    )
    rng = np.random.default_rng(seed)
    losses: list[float] = []
    steps = range(int(cfg.refine_iterations))
    if progress:
        from tqdm import tqdm

        steps = tqdm(steps, desc="refine", leave=False)
    for _ in steps:
        v = int(rng.integers(len(cameras)))
        current = type(g)(
            means=means,
            log_scales=as_array3(opt["log_scale"]),
            rotations=g.rotations,
            color_logits=opt["color_logits"],
            opacity_logits=opt["opacity_logits"],
        )
        loss = image_loss(render(current, cameras[v], render_cfg).rgb, targets[v], cfg.refine_lambda_dssim)
        dr.backward(loss)
        opt.step()
        losses.append(scalar(loss))
    out = type(g)(
        means=means,
        log_scales=as_array3(dr.detach(opt["log_scale"])),
        rotations=g.rotations,
        color_logits=dr.detach(opt["color_logits"]),
        opacity_logits=dr.detach(opt["opacity_logits"]),
    )
    return RefineResult(out, losses)
