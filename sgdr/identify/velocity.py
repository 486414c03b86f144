"""Pipeline stage 4: the initial velocity v0 from the frames before ground contact.

Before the hit frame the object falls freely: no spring is stretched (every anchor moves
with the same velocity, so Eqs. 8-9 give zero force) and the ground is not touched, so the
semi-implicit Euler rollout is a rigid translation. We use its closed form,

    μ_i(t) = μ_i(0) + v0 t + g t² / 2,        t = f / fps,

for the bound centres μ_i (an IDW-bound Gaussian follows a rigid translation of all anchors
exactly: the weights sum to one). Semi-implicit Euler with n_t substeps per frame differs from
it by g t² / (2 n_t f), below a pixel at every preset. v0 is fitted by rendering loss with
Adam (lr `recon.lr_v0`, `recon.v0_iterations` steps), as the paper does; gravity g is the
sequence's.

Frames used: 1 .. hit_frame - 1 (frame 0 is the rest pose and carries no velocity
information). With fewer than one such frame there is nothing to fit and v0 = 0 is returned
with a note.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import drjit as dr
import numpy as np

from sgdr.arrays import scalar, to_numpy
from sgdr.backend import ad
from sgdr.identify.adam import make_adam
from sgdr.identify.config import ReconConfig
from sgdr.loss import image_loss
from sgdr.render.images import posed, render


@dataclass
class VelocityResult:
    v0: np.ndarray  # [3] scene units / s, world frame
    losses: list[float] = field(default_factory=list)  # mean loss over frames per step
    frames: list[int] = field(default_factory=list)  # frames the loss used
    note: str = ""


def fit_initial_velocity(
    gaussians,
    targets_by_frame: dict[int, list],
    cameras: list,
    fps: float,
    gravity: np.ndarray,
    cfg: ReconConfig,
    render_cfg,
    seed: int,
    progress: bool = False,
) -> VelocityResult:
    """Fit v0 [3] on the free-fall frames.

    gaussians: refined Gaussians at rest (frame 0). targets_by_frame: {f: [TensorXf [H, W, 3]
    per view]} for the pre-contact frames f >= 1. gravity [3] scene units / s².
    """

    frames = sorted(f for f in targets_by_frame if f >= 1)
    if not frames:
        return VelocityResult(np.zeros(3), note="no free-fall frame before the hit frame; v0 = 0")
    t = ad()
    g = gaussians.detach()
    mu0 = g.means
    gravity_v = t.Array3f(*map(float, np.asarray(gravity, float).reshape(3)))
    opt = make_adam({"v0": (t.Array3f(0.0, 0.0, 0.0), cfg.lr_v0)})
    rng = np.random.default_rng(seed)
    n_views = len(cameras)
    per_step = n_views if cfg.v0_views_per_step <= 0 else min(cfg.v0_views_per_step, n_views)
    losses: list[float] = []
    steps = range(int(cfg.v0_iterations))
    if progress:
        from tqdm import tqdm

        steps = tqdm(steps, desc="v0", leave=False)
    for _ in steps:
        v0 = opt["v0"]
        loss = t.Float(0.0)
        for f in frames:
            time_s = f / float(fps)
            means = mu0 + v0 * time_s + gravity_v * (0.5 * time_s * time_s)
            for v in rng.choice(n_views, size=per_step, replace=False):
                rgb = render(posed(g, means), cameras[int(v)], render_cfg).rgb
                loss += image_loss(rgb, targets_by_frame[f][int(v)], cfg.v0_lambda_dssim)
        loss = loss / float(len(frames) * per_step)
        dr.backward(loss)
        opt.step()
        losses.append(scalar(loss))
    v0_np = to_numpy(opt["v0"]).reshape(3)
    return VelocityResult(v0_np, losses, frames)
