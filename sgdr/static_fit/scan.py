"""The static fit of a real capture's scan and its registration into the dynamic frame.

`fit_scan`: the scan's cameras (COLMAP, arbitrary units and frame) are moved into a normalised
frame X_n = k (X - o), with o the centre and k = `static_fit.scan_size` / diagonal of the box
carved from the scan's masks, so the constant scale s0 and the learning rates (scene units)
mean the same as on the benchmark; the Gaussians are fitted there (`sgdr.static_fit.fit_static`)
and mapped back (centres X = X_n / k + o, log scales - log k).

`register_scan`: `sgdr.static_fit.register.register` on the dynamic sequence's frame 0 masks (and
the video frame's colours when the capture has them), from
the config's initial registration (DATA.REGIST: INIT_R Euler XYZ degrees, INIT_T, INIT_S);
returns the Gaussians in the dynamic frame and the `Registration`.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from sgdr.cameras import Camera
from sgdr.data.sequence import SequenceError
from sgdr.gaussians.model import Gaussians
from sgdr.static_fit.fit import box_from_masks, fit_static
from sgdr.static_fit.register import RegisterConfig, euler_xyz_deg, register


def normalised_cameras(cameras: list[Camera], origin: np.ndarray, k: float) -> list[Camera]:
    """The same cameras in the frame X_n = k (X - origin): R unchanged, t' = k (R origin + t)."""
    return [Camera(c.K, c.R, k * (c.R @ origin + c.t), c.width, c.height, c.name) for c in cameras]


def fit_scan(static_seq, cfg, render_cfg, seed: int = 0, progress: bool = False):
    """Gaussians fitted to a static scan (a one-frame Sequence), in the scan's own frame."""

    images = [static_seq.image(v, 0) for v in range(static_seq.n_views)]
    lo, hi = box_from_masks(images, static_seq.cameras, cfg)
    origin = 0.5 * (lo + hi)
    k = float(cfg.scan_size) / float(np.linalg.norm(hi - lo))
    cams = normalised_cameras(static_seq.cameras, origin, k)
    g = fit_static(images, cams, cfg, render_cfg, (k * (lo - origin), k * (hi - origin)), seed, progress=progress)
    p = g.to_numpy()
    return Gaussians.from_numpy(
        p["means"] / k + origin, p["log_scales"] - np.log(k), p["rotations"], p["color_logits"], p["opacity_logits"]
    )


def register_scan(gaussians, seq, cfg, render_cfg, seed: int = 0, progress: bool = False):
    """(Gaussians in the dynamic frame, Registration) from the scan's Gaussians and `seq`'s frame 0."""

    init = seq.extras.get("registration_init") or {}
    if not init.get("given"):
        raise SequenceError(
            f"{seq.extras.get('config', seq.root)}: field 'DATA.REGIST': missing; the registration of the static scan "
            "into the dynamic cameras starts from the config's INIT_R (Euler XYZ degrees), INIT_T and INIT_S, as the "
            "official configs give them"
        )
    masks = [seq.image(v, 0)[..., 3] for v in range(seq.n_views)]
    # the video frames' colours when there are any (masks as targets or not, as the official code registers)
    has_rgb = seq.mask_paths is not None and all(
        seq.image_paths[v][0] != seq.mask_paths[v][0] for v in range(seq.n_views)
    )
    rgb_seq = replace(seq, mask_only=False)
    images = [rgb_seq.image(v, 0) for v in range(seq.n_views)] if has_rgb else None
    rc = RegisterConfig(cfg.register_iterations, cfg.register_lr, cfg.register_lambda_center, cfg.register_lambda_rgb)
    R0 = euler_xyz_deg(init["rotation_euler_xyz_deg"])
    reg = register(
        gaussians, seq.cameras, masks, R0, init["translation"], init["scale"], rc, render_cfg, seed, progress, images
    )
    return reg.apply_gaussians(gaussians), reg
