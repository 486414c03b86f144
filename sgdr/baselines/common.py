"""Pieces the baselines share: the multi-view image loss of posed Gaussians and the result type."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from tqdm import tqdm

from sgdr.arrays import points_to_array3, scalar
from sgdr.loss import image_loss
from sgdr.render.images import posed, render


@dataclass
class ReconstructionResult:
    """What a dynamic-reconstruction baseline returns."""

    centres: np.ndarray  # [n_fit, M, 3] float64, world, scene units; frame 0: the given Gaussians' centres
    losses: np.ndarray  # [n_steps] total loss (image + priors) of every Adam step, in the order they ran
    image_losses: np.ndarray  # [n_steps] the image part of each step's loss
    step_frames: list = field(default_factory=list)  # per step: the frame it fitted (-1: all fit frames jointly)


def check_targets(targets: list, cameras: list, error: type[Exception], name: str, empty: str = "no fit frame") -> None:
    """Raise `error` (prefixed with the method's `name`) unless there is a fit frame and every
    frame has one target image per camera."""
    if not targets:
        raise error(f"{name}: {empty}")
    for f, views in enumerate(targets):
        if len(views) != len(cameras):
            raise error(f"{name}: frame {f} has {len(views)} target views, expected {len(cameras)} (cameras)")


def view_choice(rng: np.random.Generator, n_views: int, views_per_step: int) -> list[int]:
    """The views one Adam step renders: every view (views_per_step 0, or >= n_views), else a
    random subset of that size, in increasing order."""
    if views_per_step <= 0 or views_per_step >= n_views:
        return list(range(n_views))
    return sorted(int(v) for v in rng.choice(n_views, size=views_per_step, replace=False))


def multiview_image_loss(gaussians, targets: list, cameras: list, views: list[int], render_cfg, lam: float):
    """Mean over `views` of (1-λ) L1 + λ D-SSIM between the render of `gaussians` and the target
    (TensorXf [H, W, 3] each): a Float [1] that carries the Gaussians' gradients."""

    loss = 0.0
    for v in views:
        loss = loss + image_loss(render(gaussians, cameras[v], render_cfg).rgb, targets[v], lam).array
    return loss * (1.0 / len(views))


def steps_bar(steps, desc: str, progress: bool, **kwargs):
    """`steps` wrapped in a tqdm bar when `progress` (as the pipeline's other stages do)."""
    if not progress:
        return steps

    return tqdm(steps, desc=desc, leave=False, **kwargs)


def all_view_loss(gaussians, centres: np.ndarray, targets: list, cameras: list, render_cfg, lam: float) -> float:
    """Mean over fit frames 1 .. n_fit-1 and every view of (1-λ) L1 + λ D-SSIM of `gaussians` posed
    at `centres` [n_fit, M, 3] against `targets` (per frame, per view TensorXf): the deterministic
    loss a run reports before and after the fit (forward only). 0 when there is no frame after 0."""
    import drjit as dr

    if len(centres) < 2:
        return 0.0
    views = list(range(len(cameras)))
    with dr.suspend_grad():
        losses = [
            scalar(
                multiview_image_loss(
                    posed(gaussians, points_to_array3(centres[f])), targets[f], cameras, views, render_cfg, lam
                )
            )
            for f in range(1, len(centres))
        ]
    return float(np.mean(losses))
