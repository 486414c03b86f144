"""Regenerate the sequence fixtures of tests/data (all made by sgdr's own writers).

    python tests/data/make_fixtures.py            # from the repository root

Writes one tiny sequence (2 views, 3 frames, 16x12 RGBA: a shaded disc at the projection of a
moving ball, on black) in the three layouts sgdr reads:
- tests/data/sgdr_seq/     sgdr's own layout (sequence.json, images/, gt/)
- tests/data/spring_gaus/  Spring-Gaus layout (camera.json, <camera>/<fff>.png, sgdr_scene.json)
- tests/data/pac_nerf/     PAC-NeRF layout (all_data.json, data/r_<view>_<frame>.png, sgdr_scene.json)
"""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent.parent))

from sgdr.cameras import Camera  # noqa: E402
from sgdr.data import load_sequence, write_sequence  # noqa: E402
from sgdr.data.foreign import write_pac_nerf, write_scene_sidecar, write_spring_gaus  # noqa: E402

FPS = 24.0
N_FRAMES = 3
WIDTH, HEIGHT = 16, 12


def fixture_cameras() -> list[Camera]:
    target = np.array([0.5, 0.5, 0.4])
    return [
        Camera.look_at([0.5, -0.6, 1.0], target, [0, 0, 1], 50.0, WIDTH, HEIGHT, "cam_a"),
        Camera.look_at([1.5, 0.9, 0.8], target, [0, 0, 1], 45.0, WIDTH, HEIGHT, "cam_b"),
    ]


def ball_track() -> np.ndarray:
    """[N_FRAMES, 3] centres of a ball dropping with gravity (0, 0, -9.8)."""
    t = np.arange(N_FRAMES) / FPS
    return np.stack([0.5 + 0.2 * t, 0.5 + 0 * t, 0.5 - 4.9 * t**2], -1)


def disc_image(cam: Camera, centre: np.ndarray, radius: float) -> np.ndarray:
    """[H, W, 4]: the ball's projected disc (analytic coverage) with a shading gradient."""
    (u, v), z = (a[0] for a in cam.project(centre[None]))
    r_px = cam.K[0, 0] * radius / z
    ys, xs = np.mgrid[0:HEIGHT, 0:WIDTH] + 0.5
    d = np.hypot(xs - u, ys - v)
    alpha = np.clip(r_px + 0.5 - d, 0.0, 1.0)
    shade = 0.4 + 0.6 * np.clip(1.0 - d / max(r_px, 1e-6), 0.0, 1.0)
    rgb = np.stack([shade, 0.5 * shade, 0.2 + 0 * shade], -1) * alpha[..., None]
    return np.concatenate([rgb, alpha[..., None]], -1)


def make(root: Path = HERE) -> dict[str, Path]:
    cams = fixture_cameras()
    track = ball_track()
    images = [[disc_image(c, track[f], 0.08) for f in range(N_FRAMES)] for c in cams]
    paths = {"sgdr": root / "sgdr_seq", "spring_gaus": root / "spring_gaus", "pac_nerf": root / "pac_nerf"}
    for p in paths.values():
        shutil.rmtree(p, ignore_errors=True)
    write_sequence(
        paths["sgdr"],
        cameras=cams,
        images=images,
        fps=FPS,
        n_fit=2,
        hit_frame=2,
        ground_point=[0.5, 0.5, 0.1],
        ground_normal=[0, 0, 1],
        gravity=[0, 0, -9.8],
        gt_particles=[c[None] + np.zeros((4, 3)) for c in track],
        gt_params={"object": "ball", "radius": 0.08},
        gt_effects={},
    )
    seq = load_sequence(paths["sgdr"])
    write_spring_gaus(paths["spring_gaus"], cams, images)
    write_scene_sidecar(paths["spring_gaus"], seq)
    write_pac_nerf(paths["pac_nerf"], cams, images, FPS)
    write_scene_sidecar(paths["pac_nerf"], seq)
    return paths


if __name__ == "__main__":
    for layout, path in make().items():
        print(f"{layout}: {path}")
