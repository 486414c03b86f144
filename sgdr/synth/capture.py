"""A simulated real capture in the Spring-Gaus layout (`sgdr.data.capture_layout`), with its truth.

`simulate_real_capture(out_dir, cfg, seed)` makes what a real capture would hold: a static scan
of the object at rest on a table (photos, masks, a COLMAP model in the scan's own frame), a
dynamic capture of it dropping onto another table from three calibrated video cameras (frames,
masks, clean background plates, checkerboard images, cameras_calib.json), the official-style
config.yaml, and the truth under gt/ (truth.json, per-frame particles).

Frames (all similarities, `sgdr.synth.similarity`):
- simulation frame U: sgdr's unit cube (z up, scene units), where the object is built, dropped
  by the MPM (`sgdr.synth.generate.simulate_drop`, ground plane z = z_g, gravity
  -cfg.gravity / cfg.metres_per_unit) and rendered (Mitsuba, `sgdr.synth.capture_scene`);
- dynamic frame D (metres): the world checkerboard's frame (`sgdr.data.board`), the board
  lying on the table under the drop, z pointing down into the table; X_D = m R_UD (X_U - o_U)
  with m = metres_per_unit, R_UD turning U's z into -z and its x by board_yaw_deg. The ground
  is z = 0 with normal (0, 0, -1), gravity is (0, 0, +cfg.gravity), as in the official real
  captures (BC [[0, 0, g], [0, 0, -1]], G [0, 0, 9.8]);
- static frame S (the COLMAP model's): the registration X_D = s_r R_r X_S + t_r maps the scan's
  object onto frame 0 of the drop (s_r = static_scale, R_r uniform random, t_r such that the
  object's centroid sits at a random point within +-static_offset of S's origin).

The static scan photographs frame 0's particles (the rest shape: the MPM starts from it) with a
table raised to touch its lowest surface point, from static_views cameras on rings around it;
so the scan's object is the dynamic frame 0's object moved rigidly, and the truth similarity
maps one onto the other exactly. The three video cameras look from video_azimuth /
video_elevation at video_radius at a point between the world board's centre and frame 0's
centroid (video_target); their intrinsics are the official loader's
rule applied to the photo camera: fx = fx_S W / W_S, fy = fy_S H / H_S, principal point
(W / 2, H / 2) (equal focal lengths need equal aspect ratios; config rule), written also in
cameras_calib.json (no distortion), so both readings agree.

Images: path-traced linear radiance x exposure x white balance + Gaussian noise -> sRGB ->
8-bit JPEG; the photos and the videos have their own exposure, white balance and table.
Masks: coverage of an object-only render > 0.5. Background plates: the video table alone,
noise drawn anew. Checkerboards (analytic, `board.board_image`, over the camera's linear plate):
per camera image 0 is the world board on the table, the others face the camera tilted by up
to board_tilt_deg at random, filling board_fill of the image width, fully inside the image.

The truth (gt/truth.json): the registration (s, R, t; also in the official parametrisation
X_D = s R (X_S - c_S) + t_c about the static particles' centroid c_S, with the rough INIT_*
written to config.yaml), U -> D, each video camera's K, R, t (D), the photo camera's K, fps,
gravity, ground, hit frame (`contact_frame`: the first frame the MPM's ground acts on; at 120
fps sgdr.synth's centre-of-mass test of the generator flags it only frames later),
v0 (D, m/s), the board (pattern, square, margin, every image's board-to-camera pose), the
exposures and timings. gt/particles_<fff>.npy: [P, 3] float32 particles in D, metres.

Idempotent: everything is written to `<out_dir>.partial`, the marker `COMPLETE.json` (the
settings and seed) last, then the folder is renamed to out_dir; a complete capture with the
same settings is skipped, one with other settings is replaced only with `cfg.overwrite`, and a
non-empty folder that is not a capture is never touched.

Cost on the 2-core CPU (measured, torus, seed 0): tiny (the defaults, conf/preset/tiny.yaml)
6-8 s in all (MPM ~1 s, videos ~1.5 s, photos ~1.2 s, checkerboards ~1.2 s; 9.6 s wall for the
driver with an empty Dr.Jit kernel cache, Python's start included); small 34 s (videos 22 s).
"""

from __future__ import annotations

import json
import logging
import shutil
import time
from dataclasses import asdict
from pathlib import Path

import cv2
import numpy as np
import yaml
from omegaconf import OmegaConf
from scipy.spatial.transform import Rotation
from tqdm import tqdm

from sgdr.cameras import Camera
from sgdr.checks import ConfigError
from sgdr.data import capture_layout as layout
from sgdr.data.board import Board, board_image
from sgdr.data.calibrate import Calibration, write_cameras_calib
from sgdr.data.colmap import ColmapCamera, ColmapImage, rotmat_to_qvec, write_colmap
from sgdr.synth.capture_config import RealCaptureSimConfig, rule_problem
from sgdr.synth.capture_scene import (
    build_scene,
    expose,
    mask_scene,
    render_linear,
    table_dict,
    table_texture,
    write_jpeg,
    write_mask,
)
from sgdr.synth.config import EffectsConfig, SynthConfig
from sgdr.synth.generate import CONTACT_CELLS, simulate_drop
from sgdr.synth.objects import build_object
from sgdr.synth.render_gt import sensor_dict, surface_mesh
from sgdr.synth.similarity import Similarity, camera_in, random_rotation

log = logging.getLogger(__name__)

BOARD_WHITE, BOARD_BLACK = 0.55, 0.03  # linear radiance of the board's white and black squares
BOARD_EDGE_PX = 2.0  # the board's outline stays this far inside the image, pixels
BOARD_TRIES = 1000  # random board poses tried per image before giving up


def as_config(cfg) -> RealCaptureSimConfig:
    """`cfg` as a RealCaptureSimConfig (accepts the Hydra DictConfig node `cfg.realcap`)."""
    if isinstance(cfg, RealCaptureSimConfig):
        return cfg

    return OmegaConf.to_object(OmegaConf.merge(OmegaConf.structured(RealCaptureSimConfig), cfg))


def capture_key(cfg: RealCaptureSimConfig, seed: int) -> dict:
    """What a capture depends on: every setting but `overwrite`, and the seed."""
    d = asdict(cfg)
    d.pop("overwrite")
    return {"realcap": d, "seed": int(seed)}


def read_marker(root) -> dict | None:
    try:
        return json.loads((Path(root) / layout.COMPLETE).read_text())
    except (OSError, json.JSONDecodeError):
        return None


def is_complete(root, cfg: RealCaptureSimConfig, seed: int) -> bool:
    marker = read_marker(root)
    return marker is not None and marker.get("key") == json.loads(json.dumps(capture_key(cfg, seed)))


def simulate_real_capture(out_dir, cfg, seed: int, progress: bool = True) -> Path:
    """Write a simulated real capture to out_dir (module docstring); returns out_dir.

    cfg: RealCaptureSimConfig (or the `realcap` node of the composed config); seed: the object's
    particle jitter, the path tracer, the registration, noise, textures and board poses.
    """
    cfg = as_config(cfg)
    problem = rule_problem(cfg)
    if problem:
        raise ConfigError(problem)
    out = Path(out_dir)
    if is_complete(out, cfg, seed):
        log.info("%s: complete with these settings, skipped", out)
        return out
    if out.exists() and any(out.iterdir()):
        if read_marker(out) is None:
            raise ConfigError(f"{out}: exists and is not a simulated capture; choose another folder")
        if not cfg.overwrite:
            raise ConfigError(f"{out}: holds a capture made with other settings; realcap.overwrite=true replaces it")
    partial = out.with_name(out.name + ".partial")
    if partial.exists():
        shutil.rmtree(partial)
    partial.mkdir(parents=True)
    timings = _write_capture(partial, cfg, int(seed), progress)
    if out.exists():
        shutil.rmtree(out)
    partial.rename(out)
    log.info("%s: capture written, %s", out, {k: round(v, 2) for k, v in timings.items()})
    return out


# ---------------------------------------------------------------------------- geometry
def _synth_config(cfg: RealCaptureSimConfig):
    """The sgdr.synth settings of the drop (the rest are SynthConfig's defaults)."""

    return SynthConfig(
        object=cfg.object,
        n_frames=cfg.n_frames,
        n_fit=max(1, cfg.n_frames - 1),
        fps=cfg.fps,
        hit_frame=cfg.hit_frame,
        v0=list(cfg.v0),
        mpm_grid=cfg.mpm_grid,
        particles_per_cell=cfg.particles_per_cell,
        E=cfg.E,
        nu=cfg.nu,
        density=cfg.density,
        ground="friction",
        ground_friction=cfg.ground_friction,
        surface_grid=cfg.surface_grid,
        effects=EffectsConfig(gravity=cfg.gravity / cfg.metres_per_unit),
    )


def sim_to_dynamic(cfg: RealCaptureSimConfig, board: Board, ground_z: float, landing_xy) -> Similarity:
    """U -> D: the board's inner-corner centre under the landing point, on the ground plane."""
    yaw = np.radians(cfg.board_yaw_deg)
    e_x = np.array([np.cos(yaw), np.sin(yaw), 0.0])
    e_z = np.array([0.0, 0.0, -1.0])
    R = np.stack([e_x, np.cross(e_z, e_x), e_z])  # rows: D's axes in U
    m = cfg.metres_per_unit
    centre_u = np.array([landing_xy[0], landing_xy[1], ground_z])
    origin_u = centre_u - R.T @ board.centre() / m
    return Similarity(m, R, -m * R @ origin_u)


def contact_frame(frames_u: np.ndarray, ground_z: float, dx: float) -> int:
    """The first frame in which the MPM's ground acts: its lowest particle is within
    `sgdr.synth.generate.CONTACT_CELLS` Δx of the plane (its B-spline stencil reaches the
    collider band); frames before it are free flight. frames_u: [F, P, 3] simulation frame."""

    near = np.nonzero(frames_u[:, :, 2].min(1) - ground_z < CONTACT_CELLS * dx)[0]
    return int(near[0]) if len(near) else len(frames_u) - 1


def _ring_directions(elevations, n_views: int) -> np.ndarray:
    """[n_views, 3] unit directions (z up) on rings at `elevations` (degrees), views split as
    evenly as possible, each ring's azimuths shifted by a fraction of its spacing."""
    n_rings = len(elevations)
    counts = [n_views // n_rings + (1 if k < n_views % n_rings else 0) for k in range(n_rings)]
    dirs = []
    for k, (el, n) in enumerate(zip(elevations, counts)):
        el = np.radians(el)
        az = 2.0 * np.pi * (np.arange(n) + k / n_rings) / n
        dirs += [[np.cos(el) * np.cos(a), np.cos(el) * np.sin(a), np.sin(el)] for a in az]
    return np.array(dirs)


def _look_at(eye, target, K, width, height, name) -> Camera:
    """A camera with intrinsics K at eye looking at target, image up = the simulation's +z."""
    fov = float(np.degrees(2.0 * np.arctan(0.5 * width / K[0, 0])))
    c = Camera.look_at(eye, target, [0.0, 0.0, 1.0], fov, width, height, name)
    return Camera(K, c.R, c.t, width, height, name)


def _inside(camera: Camera, points, edge: float) -> bool:
    uv, z = camera.project(points)
    return bool(np.all(z > 0) and np.all(uv >= edge) and np.all(uv[:, 0] <= camera.width - edge)) and bool(
        np.all(uv[:, 1] <= camera.height - edge)
    )


def board_poses(camera: Camera, board: Board, n: int, tilt_deg: float, fill, rng) -> list[tuple]:
    """n - 1 random board-to-camera poses (R [3, 3], t [3]) facing `camera` (module docstring)."""

    f, W = camera.K[0, 0], camera.width
    width = (board.cols + 1 + 2 * board.margin) * board.square
    poses = []
    for _ in range(BOARD_TRIES * n):
        if len(poses) == n - 1:
            break
        axis = rng.normal(size=2)
        tilt = Rotation.from_rotvec(
            np.radians(rng.uniform(-tilt_deg, tilt_deg)) * np.r_[axis / np.linalg.norm(axis), 0]
        )
        R = (tilt * Rotation.from_rotvec([0.0, 0.0, rng.uniform(-np.pi, np.pi)])).as_matrix()
        phi = rng.uniform(fill[0], fill[1])
        depth = f * width / (phi * W)
        spread = 0.5 * (1.0 - phi) * depth / f * np.array([camera.width, camera.height])
        centre = np.r_[rng.uniform(-1, 1, 2) * spread, depth]  # the board's centre, camera frame
        t = centre - R @ board.centre()
        board_cam = Camera(camera.K, R, t, camera.width, camera.height)
        if _inside(board_cam, board.outline(), BOARD_EDGE_PX):
            poses.append((R, t))
    if len(poses) < n - 1:
        raise ConfigError(
            f"camera {camera.name}: cannot place {n - 1} boards inside the image; lower realcap.board_fill or "
            "realcap.board_tilt_deg"
        )
    return poses


# ---------------------------------------------------------------------------- writing
def _write_capture(root: Path, cfg: RealCaptureSimConfig, seed: int, progress: bool) -> dict:
    """Write the whole capture into root; returns the timings (seconds per part)."""

    timings = {}
    obj_name = cfg.obj_name or cfg.object
    rng_reg, rng_noise, rng_board, rng_tex, rng_init = (
        np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(5)
    )
    synth = _synth_config(cfg)
    board = Board(int(cfg.board_pattern[0]), int(cfg.board_pattern[1]), float(cfg.board_square))
    total = cfg.n_frames - 1 + cfg.n_frames + 1 + cfg.static_views + len(layout.CAMERAS)
    bar = tqdm(total=total, desc=f"capture {obj_name}", unit="step", leave=False, disable=not progress)

    # --- the drop, in the simulation frame
    t0 = time.perf_counter()
    spacing = (1.0 / synth.mpm_grid) / synth.particles_per_cell ** (1.0 / 3.0)
    obj = build_object(synth.object, spacing, 0.5 / synth.surface_grid, synth.pattern_scale, seed)
    frames_u, info = simulate_drop(obj, synth, progress=lambda f: bar.update())
    timings["mpm_s"] = time.perf_counter() - t0
    ground_z = float(info["ground_point"][2])
    hit_frame = contact_frame(frames_u, ground_z, info["dx"])

    def surface(x):
        return surface_mesh(
            x, obj.colours, obj.particle_volume, 1.0 / synth.surface_grid, synth.surface_sigma, synth.surface_level
        )

    U2D = sim_to_dynamic(cfg, board, ground_z, frames_u[-1].mean(0)[:2])
    particles_d = [U2D.apply(x) for x in frames_u]

    # --- cameras: the photo camera's K, and the official rule for the videos'
    W, H, W_S, H_S = cfg.video_width, cfg.video_height, cfg.static_width, cfg.static_height
    K_s = Camera.intrinsics_from_fov(cfg.camera_fov, W_S, H_S)
    K_d = np.array([[K_s[0, 0] * W / W_S, 0.0, W / 2], [0.0, K_s[1, 1] * H / H_S, H / 2], [0.0, 0.0, 1.0]])
    board_centre_u = U2D.inverse().apply(board.centre()[None])[0]
    target = board_centre_u + cfg.video_target * (frames_u[0].mean(0) - board_centre_u)
    yaw = np.radians(cfg.board_yaw_deg)
    video_u, video_d = [], []
    for name, az, el in zip(layout.CAMERAS, cfg.video_azimuth, cfg.video_elevation):
        a, e = yaw + np.radians(az), np.radians(el)
        eye = target + cfg.video_radius * np.array([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)])
        cam = _look_at(eye, target, K_d, W, H, name)
        video_u.append(cam)
        video_d.append(camera_in(cam, U2D))
        if not _inside(video_d[-1], board.outline(), BOARD_EDGE_PX):
            raise ConfigError(
                f"camera {name}: the world checkerboard leaves the image; change realcap.video_radius, "
                "realcap.video_azimuth, realcap.video_elevation or realcap.board_square"
            )
    light = {
        "target": target,
        "up": [0.0, 0.0, 1.0],
        "env_radiance": cfg.env_radiance,
        "light_radiance": cfg.light_radiance,
        "light_size": cfg.light_size,
        "light_height": cfg.light_height,
        "max_depth": cfg.max_depth,
    }

    t0 = time.perf_counter()
    plates, frame_files = _write_videos(root, cfg, seed, surface, frames_u, video_u, target, ground_z, light, rng_tex,
                                        rng_noise, bar)  # fmt: skip
    timings["video_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    S2D = _write_static_scan(root, cfg, obj_name, seed, surface, frames_u, particles_d, U2D, K_s, light, rng_tex,
                             rng_reg, rng_noise, bar)  # fmt: skip
    timings["static_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    poses = _write_boards(root, cfg, video_d, board, K_d, plates, rng_board, rng_noise, bar)
    timings["boards_s"] = time.perf_counter() - t0
    bar.close()

    # --- sequence files, config.yaml and the truth
    (root / "dynamic" / "sync.json").write_text(json.dumps({c: 0 for c in layout.CAMERAS}, indent=2))
    seq = {"hit_frame": hit_frame, **{c: frame_files for c in layout.CAMERAS}}
    path = layout.sequence_file(root, obj_name, cfg.seq)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(seq, indent=2))
    gt = root / "gt"
    gt.mkdir()
    for f, x in enumerate(particles_d):
        np.save(gt / f"particles_{f:03d}.npy", x.astype(np.float32))
    np.save(gt / "particle_colours.npy", obj.colours.astype(np.float32))
    frames = {"U2D": U2D, "S2D": S2D, "video": video_d, "K_s": K_s, "particles": particles_d}
    truth = _truth(cfg, seed, info, hit_frame, frames, board, poses, rng_init, timings)
    (gt / "truth.json").write_text(json.dumps(truth, indent=2))
    _write_config_yaml(root / "config.yaml", cfg, obj_name, truth, particles_d)
    marker = {"key": capture_key(cfg, seed), "timings": timings}
    (root / layout.COMPLETE).write_text(json.dumps(marker, indent=2))
    return timings


def _write_videos(root, cfg, seed, surface, frames_u, video_u, target, ground_z, light, rng_tex, rng_noise, bar):
    """The video frames of every camera (JPEG, exposed, noisy) with their masks, and the clean
    background plates. Returns (the plates' linear images [V, H, W, 4], the frame file names)."""
    import mitsuba as mi  # after the backend has chosen Mitsuba's variant

    sensors = [mi.load_dict(sensor_dict(c, cfg.video_spp)) for c in video_u]
    tex = table_texture(cfg.table_colour, cfg.table_texture, cfg.table_texture_cells, rng_tex)
    table = table_dict(target, ground_z, cfg.table_size, tex)
    frame_files = [layout.frame_file(f) for f in range(cfg.n_frames)]
    for f in range(cfg.n_frames):
        surf = surface(frames_u[f])
        rgb = render_linear(build_scene(surf, table, light), sensors, cfg.video_spp, seed * 100003 + f)
        alpha = render_linear(mask_scene(surf), sensors, cfg.mask_spp, seed * 100003 + f)[..., 3]
        for v, name in enumerate(layout.CAMERAS):
            image = expose(rgb[v, ..., :3], cfg.video_exposure, cfg.video_wb, cfg.noise_sigma, rng_noise)
            write_jpeg(layout.video_frame(root, name, frame_files[f]), image, cfg.jpeg_quality)
            write_mask(layout.video_mask(root, name, frame_files[f]), alpha[v] > 0.5)
        bar.update()
    plates = render_linear(build_scene(None, table, light), sensors, cfg.plate_spp, seed * 100003 + cfg.n_frames)
    for v, name in enumerate(layout.CAMERAS):
        image = expose(plates[v, ..., :3], cfg.video_exposure, cfg.video_wb, cfg.noise_sigma, rng_noise)
        write_jpeg(layout.background_plate(root, name), image, cfg.jpeg_quality)
    bar.update()
    return plates, frame_files


def _write_static_scan(root, cfg, obj_name, seed, surface, frames_u, particles_d, U2D, K_s, light, rng_tex, rng_reg,
                       rng_noise, bar):  # fmt: skip
    """The static scan: frame 0's shape on a raised table, photographed on a ring, its masks and
    the COLMAP model in the scan's own frame (a random similarity away from the dynamic frame).
    Returns that similarity, static -> dynamic."""
    import mitsuba as mi  # after the backend has chosen Mitsuba's variant

    W_S, H_S = cfg.static_width, cfg.static_height
    rest = surface(frames_u[0])
    centre_u = frames_u[0].mean(0)
    static_light = light | {"target": centre_u}
    static_tex = table_texture(cfg.static_table_colour, cfg.table_texture, cfg.table_texture_cells, rng_tex)
    static_table = table_dict(centre_u, float(rest.vertices[:, 2].min()), cfg.table_size, static_tex)
    c_s = rng_reg.uniform(-cfg.static_offset, cfg.static_offset, 3)
    R_r = random_rotation(rng_reg)
    c_d = particles_d[0].mean(0)
    S2D = Similarity(cfg.static_scale, R_r, c_d - cfg.static_scale * R_r @ c_s)
    U2S = U2D.then(S2D.inverse())
    photos_u = [
        _look_at(centre_u + cfg.static_radius * d, centre_u, K_s, W_S, H_S, f"IMG_{i + 1:04d}")
        for i, d in enumerate(_ring_directions(cfg.static_elevation, cfg.static_views))
    ]
    scene, masks = build_scene(rest, static_table, static_light), mask_scene(rest)
    images = {}
    for i, cam in enumerate(photos_u):
        sensor = [mi.load_dict(sensor_dict(cam, cfg.static_spp))]
        rgb = render_linear(scene, sensor, cfg.static_spp, seed * 7919 + i)[0]
        alpha = render_linear(masks, sensor, cfg.mask_spp, seed * 7919 + i)[0, ..., 3]
        image = expose(rgb[..., :3], cfg.static_exposure, cfg.static_wb, cfg.noise_sigma, rng_noise)
        write_jpeg(layout.static_image(root, obj_name, cam.name), image, cfg.jpeg_quality)
        write_mask(layout.static_mask(root, obj_name, cam.name), alpha > 0.5)
        cam_s = camera_in(cam, U2S)
        images[i + 1] = ColmapImage(f"{cam.name}.JPG", rotmat_to_qvec(cam_s.R), cam_s.t, 1)
        bar.update()
    colmap = layout.colmap_dir(root, obj_name)
    params = np.array([K_s[0, 0], K_s[1, 1], K_s[0, 2], K_s[1, 2]])
    write_colmap(colmap, {1: ColmapCamera("PINHOLE", W_S, H_S, params)}, images)
    _write_ply(colmap / "colmap_pcd.ply", U2S.apply(rest.vertices))
    return S2D


def _write_boards(root, cfg, video_d, board, K_d, plates, rng_board, rng_noise, bar) -> dict:
    """The checkerboard images of every video camera (the world board in its first pose, then
    `realcap.board_views` random poses) and cameras_calib.json. Returns the poses per camera."""
    poses = {}
    for v, cam in enumerate(video_d):
        views = [(cam.R, cam.t)] + board_poses(
            cam, board, cfg.board_views, cfg.board_tilt_deg, cfg.board_fill, rng_board
        )
        poses[cam.name] = views
        for i, (R, t) in enumerate(views):
            lum = board_image(cam, R, t, board, BOARD_WHITE, BOARD_BLACK, plates[v, ..., :3], cfg.board_supersample)
            image = expose(lum, cfg.video_exposure, cfg.video_wb, cfg.noise_sigma, rng_noise)
            write_jpeg(layout.checkerboard_dir(root, cam.name) / f"{i}.jpg", image, cfg.jpeg_quality)
        bar.update()
    layout.checkerboard_pattern_file(root).write_text(
        json.dumps({"pattern": [board.cols, board.rows], "square_size": board.square})
    )
    calib = {c.name: Calibration(K_d, np.zeros(5), cv2.Rodrigues(c.R)[0].reshape(3), c.t, 0.0) for c in video_d}
    write_cameras_calib(root / "dynamic" / "cameras_calib.json", calib)
    return poses


def _write_ply(path: Path, points) -> None:
    """A binary PLY point cloud (the official code's static/colmap/<obj>/colmap_pcd.ply)."""
    import trimesh

    trimesh.PointCloud(np.asarray(points, dtype=np.float64)).export(str(path))


def _euler_xyz_deg(R) -> list:
    """Intrinsic XYZ Euler angles (R = Rx Ry Rz), degrees: the official INIT_R convention."""

    return Rotation.from_matrix(R).as_euler("XYZ", degrees=True).tolist()


def _truth(cfg, seed, info, hit_frame, frames, board, poses, rng, timings) -> dict:
    """gt/truth.json (module docstring). frames: the similarities U2D, S2D, the video cameras (D),
    the photo K_s and the particles (D) per frame; rng draws the rough initial registration."""

    U2D, S2D, video_d, K_s, particles_d = (frames[k] for k in ("U2D", "S2D", "video", "K_s", "particles"))
    c_s = S2D.inverse().apply(particles_d[0]).mean(0)
    t_c = S2D.apply(c_s[None])[0]  # the official translation: where the static centroid lands
    size = float(np.ptp(particles_d[0], axis=0).max())
    axis = rng.normal(size=3)
    R_err = Rotation.from_rotvec(np.radians(cfg.init_rot_deg) * axis / np.linalg.norm(axis)).as_matrix()
    direction = rng.normal(size=3)
    init = {
        "R_euler_xyz_deg": _euler_xyz_deg(R_err @ S2D.R),
        "t": (t_c + cfg.init_trans_err * size * direction / np.linalg.norm(direction)).tolist(),
        "s": float(S2D.s * (1.0 + cfg.init_scale_err * rng.choice([-1.0, 1.0]))),
    }
    return {
        "object": cfg.object,
        "seed": int(seed),
        "units": "dynamic frame: metres, z down into the table; static frame: the scan's units",
        "registration": {
            **S2D.to_dict(),
            "maps": "X_dynamic = s R X_static + t (frame 0's particles from the static scan's)",
            "static_centroid": c_s.tolist(),
            "official": {"s": S2D.s, "R_euler_xyz_deg": _euler_xyz_deg(S2D.R), "t": t_c.tolist()},
            "init": init,
        },
        "sim_to_dynamic": U2D.to_dict(),
        "cameras": {
            c.name: {"K": c.K.tolist(), "R": c.R.tolist(), "t": c.t.tolist(), "width": c.width, "height": c.height}
            for c in video_d
        },
        "static_camera": {"K": K_s.tolist(), "width": cfg.static_width, "height": cfg.static_height},
        "fps": float(cfg.fps),
        "n_frames": int(cfg.n_frames),
        "gravity": [0.0, 0.0, float(cfg.gravity)],
        "ground": {"point": [0.0, 0.0, 0.0], "normal": [0.0, 0.0, -1.0]},
        "hit_frame": int(hit_frame),
        "hit_frame_planned": int(cfg.hit_frame),
        "hit_frame_com_1e-3": int(info["hit_frame"]),  # sgdr.synth's: centre of mass 1e-3 units off free flight
        "v0": U2D.apply_vector(cfg.v0).tolist(),
        "material": {"E": cfg.E, "nu": cfg.nu, "density_per_unit3": cfg.density, "law": "neo_hookean"},
        "mpm": {"dx": info["dx"], "substeps_per_frame": info["substeps_per_frame"], "dt": info["dt"]},
        "n_particles": int(len(particles_d[0])),
        "checkerboard": {
            "pattern": [board.cols, board.rows],
            "square_size": board.square,
            "margin_squares": board.margin,
            "convention": "inner corner (i, j) at (i a, j a, 0); the outer square next to corner (0, 0) is black",
            "first_image_is_world": True,
            "poses": {k: [{"R": R.tolist(), "t": t.tolist()} for R, t in v] for k, v in poses.items()},
        },
        "exposure": {
            "video": {"gain": cfg.video_exposure, "wb": list(cfg.video_wb)},
            "static": {"gain": cfg.static_exposure, "wb": list(cfg.static_wb)},
            "noise_sigma": cfg.noise_sigma,
        },
        "timings": timings,
    }


def _write_config_yaml(path: Path, cfg, obj_name: str, truth: dict, particles_d) -> None:
    """The official-style config.yaml (DATA, DYNAMIC / VELOCITY gravity), self-contained."""

    allp = np.concatenate(particles_d)
    lo, hi = allp.min(0), allp.max(0)
    pad = 0.1 * float((hi - lo).max())
    lo, hi = lo - pad, hi + pad
    hi[2] = min(hi[2], 0.0)  # the box stays on the object's side of the ground z = 0
    init = truth["registration"]["init"]
    data = {
        "TYPE": "Real_Capture",
        "DATA_ROOT": ".",
        "OBJ_NAME": obj_name,
        "SEQ": int(cfg.seq),
        "N_CAM": len(layout.CAMERAS),
        "FRAME_ALL": int(cfg.n_frames),
        "H": int(cfg.video_height),
        "W": int(cfg.video_width),
        "H_S": int(cfg.static_height),
        "W_S": int(cfg.static_width),
        "WHITE_BKG": False,
        "BC": [[truth["ground"]["point"], truth["ground"]["normal"]]],
        "XYZ_MIN": lo.round(4).tolist(),
        "XYZ_MAX": hi.round(4).tolist(),
        "REGIST": {
            "INIT_R": [round(a, 3) for a in init["R_euler_xyz_deg"]],
            "INIT_T": [round(a, 5) for a in init["t"]],
            "INIT_S": [round(init["s"], 6)],
        },
        "FREQ": float(cfg.fps),
        "EVAL_FREQ": float(cfg.fps),
        "EVAL_FRAME": int(cfg.n_frames),
        "IMG_IS_MASK": True,
    }
    g = truth["gravity"]
    doc = {"REAL": True, "DATA": data, "VELOCITY": {"G": list(g)}, "DYNAMIC": {"G": list(g)}}
    header = (
        "# A simulated Spring-Gaus real capture (sgdr.synth.capture); DATA_ROOT is this file's folder.\n"
        "# REGIST.INIT_* is a rough registration (the official X_d = s R (X_s - mean X_s) + t, R from intrinsic\n"
        "# XYZ Euler degrees); the truth is gt/truth.json.\n"
    )
    path.write_text(header + yaml.safe_dump(doc, default_flow_style=None, sort_keys=False))
