"""Known-motion cases for the dynamic-reconstruction baselines: a cube of Gaussians moved by a known motion and
rendered by sgdr's own splatting renderer, so the true centres of every frame are known
(tests/test_baselines_dynrecon.py, evaluation/studies/baseline_twins.py).

The cube: `n_gaussians` isotropic Gaussians (scale 0.02, opacity 0.9, a colour gradient along
the three axes) uniform in a cube of side 0.16 around (0.5, 0.5, 0.2), seen by 4 cameras of
32 x 32 pixels at distance 0.7. The interior Gaussians are hidden from every view, as the
interior of a real object is.

Motions (frame f, scene units):
- "rigid": a rotation of 6° per frame about the axis (0.3, 0.2, 1) through the centre, plus
  f x (0.015, -0.01, -0.02);
- "twist": a twist about z, 10° per frame at the top face, 0 at mid height, opposite at the
  bottom (a smooth non-rigid deformation), plus the same translation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from sgdr.arrays import points_to_array3
from sgdr.cameras import Camera
from sgdr.gaussians.model import Gaussians
from sgdr.render.config import RenderConfig
from sgdr.render.images import posed, render_rgb_numpy, to_tensor

CENTRE = np.array([0.5, 0.5, 0.2])  # the cube's centre, world
HALF_SIDE = 0.08  # half the cube's side, scene units
STEP = np.array([0.015, -0.01, -0.02])  # translation per frame, scene units


def rigid_motion(centres: np.ndarray, f: int) -> np.ndarray:
    """[M, 3] centres at frame f of the "rigid" motion."""

    axis = np.array([0.3, 0.2, 1.0]) / np.linalg.norm([0.3, 0.2, 1.0])
    return Rotation.from_rotvec(np.deg2rad(6.0 * f) * axis).apply(centres - CENTRE) + CENTRE + f * STEP


def twist_motion(centres: np.ndarray, f: int) -> np.ndarray:
    """[M, 3] centres at frame f of the "twist" motion."""
    p = centres - CENTRE
    th = np.deg2rad(10.0 * f) * p[:, 2] / HALF_SIDE
    x, y = np.cos(th) * p[:, 0] - np.sin(th) * p[:, 1], np.sin(th) * p[:, 0] + np.cos(th) * p[:, 1]
    return np.stack([x, y, p[:, 2]], axis=1) + CENTRE + f * STEP


MOTIONS = {"rigid": rigid_motion, "twist": twist_motion}


@dataclass
class KnownMotion:
    gaussians: object  # Gaussians at frame 0 (M)
    cameras: list  # 4 Camera, 32 x 32
    render_cfg: object  # RenderConfig (defaults)
    truth: np.ndarray  # [n_frames, M, 3] true centres; frame 0 = gaussians' means
    targets: list  # per frame, per view TensorXf [32, 32, 3]: the renders of the true centres

    def error_ratio(self, centres: np.ndarray) -> np.ndarray:
        """[n_frames - 1] per moving frame: mean centre error / mean motion since frame 0."""
        err = np.linalg.norm(centres - self.truth, axis=-1).mean(1)
        motion = np.linalg.norm(self.truth - self.truth[0], axis=-1).mean(1)
        return err[1:] / motion[1:]


def known_motion_cube(motion: str, n_gaussians: int = 250, n_frames: int = 4, seed: int = 0) -> KnownMotion:
    """The cube moved by MOTIONS[motion] over `n_frames` frames, rendered from 4 views."""

    rng = np.random.default_rng(seed)
    centres = rng.uniform(-HALF_SIDE, HALF_SIDE, (n_gaussians, 3)) + CENTRE
    colours = 0.2 + 0.6 * (centres - centres.min(0)) / np.ptp(centres, 0)
    g = Gaussians.isotropic(centres, 0.02, colours, 0.9)
    cams = [
        Camera.look_at(CENTRE + 0.7 * np.array(d), CENTRE, [0, 0, 1], 50.0, 32, 32, f"c{i}")
        for i, d in enumerate([(1, 0, 0.3), (0, 1, 0.3), (-0.7, -0.7, 0.5), (0.7, -0.7, 0.6)])
    ]
    rcfg = RenderConfig()
    truth = np.stack([MOTIONS[motion](centres, f) for f in range(n_frames)])  # [F, M, 3]
    targets = [
        [to_tensor(render_rgb_numpy(posed(g, points_to_array3(truth[f])), c, rcfg)) for c in cams]
        for f in range(n_frames)
    ]
    return KnownMotion(g, cams, rcfg, truth, targets)
