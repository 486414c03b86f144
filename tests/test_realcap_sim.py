"""The simulated real capture (sgdr.synth.capture, issue 17 parts 2-3) and the real-capture tools.

One tiny capture is written once for the module by the driver (`experiments/simulate_capture.py
preset=tiny`, a subprocess: the driver's smoke test too). On it:
- every file of the Spring-Gaus layout exists, with the sizes and channels the official loader
  reads; config.yaml is official-style, its rough registration has the configured errors;
- the truth is consistent: the photos' COLMAP cameras reproject the rest particles (static
  frame, by the inverse registration) into the photo masks, the videos' cameras_calib.json
  cameras reproject the particles into the video masks, and the official loader's intrinsics
  rule gives exactly the K of cameras_calib.json;
- the tools recover the truth: checkerboard calibration (K, world pose), background subtraction
  (masks), and a missing board fails naming the file.
Without the capture: COLMAP round trip (against pycolmap's own reader too), frame changes of
cameras, the board's first-corner convention under any in-plane rotation.
"""

import json
import shutil
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml
from omegaconf import OmegaConf

from sgdr.cameras import Camera
from sgdr.config import compose
from sgdr.data import capture_layout as layout
from sgdr.data.board import Board, board_image, canonical_order
from sgdr.data.calibrate import CalibrationError, calibrate_from_checkerboards, read_cameras_calib
from sgdr.data.colmap import (
    ColmapCamera,
    ColmapImage,
    qvec_to_rotmat,
    read_colmap,
    read_points3d_bin,
    rotmat_to_qvec,
    write_colmap,
)
from sgdr.data.masks import masks_from_background
from sgdr.synth.similarity import Similarity, camera_in, random_rotation, rotation_angle_deg

ROOT = Path(__file__).resolve().parent.parent


def _tiny():
    return OmegaConf.to_object(compose(["preset=tiny"])).realcap


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    """(root, cfg, truth, seconds) of the tiny capture written by the driver."""
    out = tmp_path_factory.mktemp("realcap") / "cap"
    t0 = time.perf_counter()
    proc = subprocess.run(
        [sys.executable, "experiments/simulate_capture.py", "preset=tiny", f"out={out}"],
        cwd=ROOT,
        capture_output=True,
        text=True,
    )
    seconds = time.perf_counter() - t0
    assert proc.returncode == 0, proc.stderr[-3000:]
    last = json.loads(proc.stdout.strip().splitlines()[-1])
    assert Path(last["capture"]) == out and last["object"] == "torus"
    truth = json.loads((out / "gt" / "truth.json").read_text())
    return out, _tiny(), truth, seconds


def _read_mask(path) -> np.ndarray:
    m = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    assert m is not None and m.ndim == 2 and m.dtype == np.uint8, path
    assert set(np.unique(m)) <= {0, 255}, path
    return m == 255


def _read_rgb(path) -> np.ndarray:
    from PIL import Image

    with Image.open(path) as im:
        assert im.format == "JPEG" and im.mode == "RGB", path
        return np.asarray(im, dtype=np.float64) / 255.0


def _fraction_inside(camera: Camera, points, mask) -> float:
    uv, z = camera.project(points)
    iu = np.floor(uv).astype(int)
    ok = (z > 0) & (iu[:, 0] >= 0) & (iu[:, 0] < camera.width) & (iu[:, 1] >= 0) & (iu[:, 1] < camera.height)
    inside = np.zeros(len(points), bool)
    inside[ok] = mask[iu[ok, 1], iu[ok, 0]]
    return float(inside.mean())


def _photo_cameras(root, obj):
    cams, images = read_colmap(layout.colmap_dir(root, obj))
    (cam,) = cams.values()
    fx, fy, cx, cy = cam.params
    K = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]])
    return cam, {
        im.name: Camera(K, qvec_to_rotmat(im.qvec), im.tvec, cam.width, cam.height, im.name) for im in images.values()
    }


# ---------------------------------------------------------------------------- the capture
def test_generation_is_quick_and_idempotent(capture):
    from sgdr.synth.capture import read_marker, simulate_real_capture

    root, cfg, truth, seconds = capture
    assert seconds < 60, f"the tiny capture took {seconds:.1f} s (process start included)"
    marker = read_marker(root)
    t0 = time.perf_counter()
    assert simulate_real_capture(root, cfg, 0, progress=False) == root  # same settings: skipped
    assert time.perf_counter() - t0 < 2.0 and read_marker(root) == marker
    other = replace(cfg, n_frames=cfg.n_frames - 1)
    with pytest.raises(ValueError, match="other settings; realcap.overwrite=true"):
        simulate_real_capture(root, other, 0, progress=False)
    print(f"\ntiny capture: {seconds:.1f} s by the driver; parts {marker['timings']}")


def test_layout_has_every_file(capture):
    root, cfg, truth, _ = capture
    obj = cfg.object
    colmap = layout.colmap_dir(root, obj)
    for name in ("cameras.bin", "images.bin", "points3D.bin"):
        assert (colmap / name).is_file(), name
    assert read_points3d_bin(colmap / "points3D.bin").shape == (0, 3)
    cam, photos = _photo_cameras(root, obj)
    assert cam.model == "PINHOLE" and (cam.width, cam.height) == (cfg.static_width, cfg.static_height)
    assert len(photos) == cfg.static_views
    for name in photos:
        assert name.endswith(".JPG")
        stem = name[: -len(".JPG")]
        image = _read_rgb(layout.static_image(root, obj, stem))
        mask = _read_mask(layout.static_mask(root, obj, stem))
        assert image.shape == (cfg.static_height, cfg.static_width, 3) and mask.shape == image.shape[:2]
        assert 0.02 < mask.mean() < 0.8  # the object, with table around it
        assert image[~mask].std() > 0.01  # the background is a textured table, not black
    calib = json.loads((root / "dynamic" / "cameras_calib.json").read_text())
    assert list(calib) == list(layout.CAMERAS)
    for c in calib.values():
        assert len(c["rvecs"]) == 3 and len(c["tvecs"]) == 3 and np.shape(c["K"]) == (3, 3) and c["dist"] == [0.0] * 5
    assert json.loads((root / "dynamic" / "sync.json").read_text()) == {c: 0 for c in layout.CAMERAS}
    seq = json.loads(layout.sequence_file(root, obj, cfg.seq).read_text())
    assert seq["hit_frame"] == truth["hit_frame"] and 1 <= seq["hit_frame"] < cfg.n_frames
    for cam_name in layout.CAMERAS:
        assert seq[cam_name] == [f"{f:06d}.jpg" for f in range(cfg.n_frames)]
        for frame in seq[cam_name]:
            image = _read_rgb(layout.video_frame(root, cam_name, frame))
            mask = _read_mask(layout.video_mask(root, cam_name, frame))
            assert image.shape == (cfg.video_height, cfg.video_width, 3) and mask.shape == image.shape[:2]
            assert mask.any()
        plate = _read_rgb(layout.background_plate(root, cam_name))
        assert plate.shape == image.shape and 0.05 < plate.mean() < 0.95 and plate.std() > 0.01
        boards = sorted(layout.checkerboard_dir(root, cam_name).glob("*.jpg"), key=lambda p: int(p.stem))
        assert [p.name for p in boards] == [f"{i}.jpg" for i in range(cfg.board_views)]
        assert _read_rgb(boards[0]).shape == image.shape
    for f in range(cfg.n_frames):
        x = np.load(root / "gt" / f"particles_{f:03d}.npy")
        assert x.dtype == np.float32 and x.shape == (truth["n_particles"], 3)
        assert x[:, 2].max() < 0.002  # on the object's side of the ground z = 0 (z points into the table)
    assert truth["gravity"] == [0.0, 0.0, cfg.gravity] and truth["ground"] == {
        "point": [0.0, 0.0, 0.0],
        "normal": [0.0, 0.0, -1.0],
    }
    assert truth["checkerboard"]["pattern"] == list(cfg.board_pattern)
    assert truth["checkerboard"]["square_size"] == cfg.board_square
    assert (root / layout.COMPLETE).is_file() and not root.with_name(root.name + ".partial").exists()


def test_the_drop_falls_with_gravity_in_metres(capture):
    root, cfg, truth, _ = capture
    com = np.array([np.load(root / "gt" / f"particles_{f:03d}.npy").mean(0) for f in range(cfg.n_frames)])
    dt = 1.0 / truth["fps"]
    hit = truth["hit_frame"]
    # Before the hit the centre of mass flies freely: its second difference is g dt² (z down, metres);
    # from the hit frame on, the ground slows it down.
    acc = (com[2:] - 2 * com[1:-1] + com[:-2]) / dt**2  # acc[k]: about frame k + 1
    np.testing.assert_allclose(acc[: hit - 2, 2], cfg.gravity, rtol=1e-3)
    np.testing.assert_allclose(acc[: hit - 2, :2], 0.0, atol=1e-3 * cfg.gravity)
    assert acc[hit - 1 : hit + 2, 2].min() < 0.95 * cfg.gravity
    # The first frame's mean velocity is v0 plus g dt (n+1) / (2n) for n symplectic substeps.
    v_first = (com[1] - com[0]) / dt - np.array(truth["v0"])
    np.testing.assert_allclose(v_first[:2], 0.0, atol=1e-3)
    assert 0.5 * cfg.gravity * dt <= v_first[2] <= 1.0 * cfg.gravity * dt
    assert com[-1, 2] > com[0, 2]  # it ends lower (z down) than it started


def test_config_yaml_is_official_style(capture):
    root, cfg, truth, _ = capture
    doc = yaml.safe_load((root / "config.yaml").read_text())
    assert "DEFAULT" not in doc and doc["DYNAMIC"]["G"] == [0.0, 0.0, cfg.gravity]
    d = doc["DATA"]
    assert d["TYPE"] == "Real_Capture" and d["OBJ_NAME"] == cfg.object and d["SEQ"] == cfg.seq and d["N_CAM"] == 3
    assert (d["W"], d["H"], d["W_S"], d["H_S"]) == (
        cfg.video_width,
        cfg.video_height,
        cfg.static_width,
        cfg.static_height,
    )
    assert d["FRAME_ALL"] == cfg.n_frames and d["FREQ"] == cfg.fps and d["IMG_IS_MASK"] is True
    (point, normal), *rest = d["BC"]
    assert not rest and point == [0.0, 0.0, 0.0] and normal == [0.0, 0.0, -1.0]  # axis-aligned, ground -> object
    lo, hi = np.array(d["XYZ_MIN"]), np.array(d["XYZ_MAX"])
    for f in (0, cfg.n_frames - 1):
        x = np.load(root / "gt" / f"particles_{f:03d}.npy")
        assert np.all(x.min(0) >= lo - 1e-4) and np.all(x.max(0) <= hi + 1e-3)

    # The official registration X_d = s R (X_s - mean X_s) + t, R = Rx Ry Rz of INIT_R's degrees
    # (pytorch3d's euler_angles_to_matrix(..., "XYZ"), written out).
    def euler(degs):
        (ca, cb, cc), (sa, sb, sc) = np.cos(np.radians(degs)), np.sin(np.radians(degs))
        Rx = np.array([[1, 0, 0], [0, ca, -sa], [0, sa, ca]])
        Ry = np.array([[cb, 0, sb], [0, 1, 0], [-sb, 0, cb]])
        Rz = np.array([[cc, -sc, 0], [sc, cc, 0], [0, 0, 1]])
        return Rx @ Ry @ Rz

    reg = truth["registration"]
    S2D = Similarity.from_dict(reg)
    x0 = np.load(root / "gt" / "particles_000.npy")
    xs = S2D.inverse().apply(x0)
    off = reg["official"]
    official = off["s"] * (xs - xs.mean(0)) @ euler(off["R_euler_xyz_deg"]).T + off["t"]
    np.testing.assert_allclose(official, x0, atol=1e-5)
    r = d["REGIST"]
    assert len(r["INIT_R"]) == 3 and len(r["INIT_T"]) == 3 and len(r["INIT_S"]) == 1
    assert rotation_angle_deg(euler(r["INIT_R"]), S2D.R) == pytest.approx(cfg.init_rot_deg, abs=0.01)
    assert abs(r["INIT_S"][0] / S2D.s - 1.0) == pytest.approx(cfg.init_scale_err, abs=1e-4)
    size = np.ptp(x0, axis=0).max()
    assert np.linalg.norm(np.array(r["INIT_T"]) - off["t"]) == pytest.approx(cfg.init_trans_err * size, rel=1e-3)


def test_static_cameras_reproject_the_rest_shape_into_the_photo_masks(capture):
    root, cfg, truth, _ = capture
    S2D = Similarity.from_dict(truth["registration"])
    rest_static = S2D.inverse().apply(np.load(root / "gt" / "particles_000.npy"))
    _, photos = _photo_cameras(root, cfg.object)
    inside, shifted = [], []
    shift = 0.3 * np.ptp(rest_static, axis=0).max() * np.array([1.0, 0.0, 0.0])
    for name, cam in photos.items():
        mask = _read_mask(layout.static_mask(root, cfg.object, name[: -len(".JPG")]))
        inside.append(_fraction_inside(cam, rest_static, mask))
        shifted.append(_fraction_inside(cam, rest_static + shift, mask))
    print(f"\nphotos: rest particles inside the masks, min {min(inside):.4f}, mean {np.mean(inside):.4f}")
    assert min(inside) >= 0.95
    assert np.mean(shifted) < 0.9  # the check sees a registration 30% of the object off


def test_video_cameras_reproject_the_particles_into_the_video_masks(capture):
    root, cfg, truth, _ = capture
    cams = read_cameras_calib(root / "dynamic" / "cameras_calib.json", cfg.video_width, cfg.video_height)
    worst = 1.0
    for name, cam in cams.items():
        t = truth["cameras"][name]
        np.testing.assert_allclose(cam.R, t["R"], atol=1e-9)
        np.testing.assert_allclose(cam.t, t["t"], atol=1e-12)
        for f in (0, truth["hit_frame"], cfg.n_frames - 1):
            x = np.load(root / "gt" / f"particles_{f:03d}.npy")
            mask = _read_mask(layout.video_mask(root, name, layout.frame_file(f)))
            worst = min(worst, _fraction_inside(cam, x, mask))
            if f == 0:  # the check sees the drop: frame 0 is not where the last frame's mask is
                last = _read_mask(layout.video_mask(root, name, layout.frame_file(cfg.n_frames - 1)))
                assert _fraction_inside(cam, x, last) < 0.9
    print(f"\nvideos: particles inside the masks, worst camera x frame {worst:.4f}")
    assert worst >= 0.95


def test_official_loader_intrinsics_equal_cameras_calib(capture):
    root, cfg, _, _ = capture
    doc = yaml.safe_load((root / "config.yaml").read_text())["DATA"]
    cams, _ = read_colmap(layout.colmap_dir(root, cfg.object))
    p = cams[1].params
    W, H, W_S, H_S = doc["W"], doc["H"], doc["W_S"], doc["H_S"]
    K_official = np.array([[p[0] * W / W_S, 0, W / 2], [0, p[1] * H / H_S, H / 2], [0, 0, 1]])
    calib = json.loads((root / "dynamic" / "cameras_calib.json").read_text())
    for name in layout.CAMERAS:
        np.testing.assert_allclose(np.array(calib[name]["K"]), K_official, rtol=1e-12)
    assert K_official[0, 0] == pytest.approx(K_official[1, 1], rel=1e-12)  # square pixels


def test_checkerboard_calibration_recovers_each_camera(capture):
    root, cfg, truth, _ = capture
    board_centre = Board(*cfg.board_pattern, cfg.board_square).centre()
    for name in layout.CAMERAS:
        paths = sorted(layout.checkerboard_dir(root, name).glob("*.jpg"), key=lambda p: int(p.stem))
        cal = calibrate_from_checkerboards(paths, cfg.board_pattern, cfg.board_square)
        t = truth["cameras"][name]
        K, R, tt = np.array(t["K"]), np.array(t["R"]), np.array(t["t"])
        R_est, _ = cv2.Rodrigues(cal.rvec)
        centre, centre_est = -R.T @ tt, -R_est.T @ cal.tvec
        focal = np.abs(cal.K.diagonal()[:2] / K.diagonal()[:2] - 1).max()
        angle = rotation_angle_deg(R_est, R)
        dist = np.linalg.norm(centre_est - centre) / np.linalg.norm(centre - board_centre)
        print(f"\n{name}: focal {focal:.4f}, rotation {angle:.3f} deg, centre {dist:.4f}, rms {cal.rms:.3f} px")
        assert focal < 0.02 and angle < 1.0 and dist < 0.02
        assert cal.rms < 0.5 and cal.dist.shape == (5,)


def test_masks_from_background_recover_the_video_masks(capture):
    root, cfg, _, _ = capture
    ious = []
    for name in layout.CAMERAS:
        plate = _read_rgb(layout.background_plate(root, name))
        for f in range(cfg.n_frames):
            image = _read_rgb(layout.video_frame(root, name, layout.frame_file(f)))
            truth = _read_mask(layout.video_mask(root, name, layout.frame_file(f)))
            m = masks_from_background(image, plate)
            ious.append((m & truth).sum() / (m | truth).sum())
    print(f"\nmasks_from_background: IoU min {min(ious):.3f}, mean {np.mean(ious):.3f} over {len(ious)} frames")
    assert min(ious) >= 0.9
    blank = masks_from_background(plate, plate)
    assert not blank.any()  # the plate against itself: nothing


def test_calibration_errors_name_the_file(capture, tmp_path):
    root, cfg, _, _ = capture
    src = sorted(layout.checkerboard_dir(root, "C0787").glob("*.jpg"), key=lambda p: int(p.stem))
    paths = []
    for p in src[:6]:
        paths.append(tmp_path / p.name)
        shutil.copy(p, paths[-1])
    shutil.copy(layout.background_plate(root, "C0787"), paths[3])  # no board in image 3
    with pytest.raises(CalibrationError, match=str(paths[3]).replace(".", r"\.") + ": no 6x5 checkerboard"):
        calibrate_from_checkerboards(paths, cfg.board_pattern, cfg.board_square)
    cal = calibrate_from_checkerboards(paths, cfg.board_pattern, cfg.board_square, skip_missing=True)
    assert np.isfinite(cal.K).all()
    with pytest.raises(CalibrationError, match="first image"):
        calibrate_from_checkerboards([paths[3], *paths[:3]], cfg.board_pattern, cfg.board_square, skip_missing=True)
    with pytest.raises(CalibrationError, match="only 2 of 2 images show the board"):
        calibrate_from_checkerboards(paths[:2], cfg.board_pattern, cfg.board_square)
    (tmp_path / "broken.jpg").write_bytes(b"not an image")
    with pytest.raises(CalibrationError, match="broken.jpg: cannot be read"):
        calibrate_from_checkerboards([tmp_path / "broken.jpg"], cfg.board_pattern, cfg.board_square)


# ---------------------------------------------------------------------------- the tools alone
def test_colmap_round_trip_is_exact_and_agrees_with_pycolmap(tmp_path, rng):
    import pycolmap

    cameras = {
        1: ColmapCamera("PINHOLE", 4752, 2672, np.array([3712.5, 3713.25, 2376.0, 1336.0])),
        3: ColmapCamera("SIMPLE_RADIAL", 640, 480, np.array([500.125, 320.0, 240.5, -0.01])),
    }
    images = {}
    for i in range(1, 8):
        q = rotmat_to_qvec(random_rotation(rng))
        images[i * 2] = ColmapImage(f"IMG_{i:04d}.JPG", q, rng.normal(size=3), 1 if i % 2 else 3)
    write_colmap(tmp_path, cameras, images)
    (tmp_path / "points3D.bin").unlink()  # the reader needs cameras.bin and images.bin only
    cams, ims = read_colmap(tmp_path)
    assert sorted(cams) == [1, 3] and sorted(ims) == sorted(images)
    for k, c in cameras.items():
        assert (cams[k].model, cams[k].width, cams[k].height) == (c.model, c.width, c.height)
        np.testing.assert_array_equal(cams[k].params, c.params)
    for k, im in images.items():
        assert ims[k].name == im.name and ims[k].camera_id == im.camera_id
        np.testing.assert_array_equal(ims[k].qvec, im.qvec)
        np.testing.assert_array_equal(ims[k].tvec, im.tvec)
    # pycolmap reads the full model it wrote; its poses match ours
    write_colmap(tmp_path / "again", cameras, images)
    rec = pycolmap.Reconstruction(str(tmp_path / "again"))
    for k, im in images.items():
        pose = rec.images[k].cam_from_world()
        np.testing.assert_allclose(pose.rotation.matrix(), qvec_to_rotmat(im.qvec), atol=1e-12)
        np.testing.assert_allclose(pose.translation, im.tvec, atol=1e-12)
    # quaternion <-> rotation
    R = random_rotation(rng)
    np.testing.assert_allclose(qvec_to_rotmat(rotmat_to_qvec(R)), R, atol=1e-12)


def test_cameras_move_between_frames_without_changing_pixels(rng):
    cam = Camera.look_at([1.0, -2.0, 1.5], [0.1, 0.2, 0.0], [0, 0, 1], 50.0, 64, 48, "c")
    A2B = Similarity(0.37, random_rotation(rng), rng.normal(size=3))
    x = rng.uniform(-0.3, 0.3, (50, 3))
    uv_a, z_a = cam.project(x)
    uv_b, z_b = camera_in(cam, A2B).project(A2B.apply(x))
    np.testing.assert_allclose(uv_b, uv_a, atol=1e-9)
    np.testing.assert_allclose(z_b, A2B.s * z_a, rtol=1e-12)  # depths in B's units
    back = A2B.then(A2B.inverse())
    np.testing.assert_allclose(back.apply(x), x, atol=1e-12)


@pytest.mark.parametrize("spin_deg", [0.0, 90.0, 180.0, 270.0])
def test_first_corner_follows_the_board_at_any_in_plane_rotation(spin_deg):
    from scipy.spatial.transform import Rotation

    board = Board(6, 5, 0.02)
    K = Camera.intrinsics_from_fov(45.0, 200, 150)
    cam = Camera(K, np.eye(3), np.zeros(3), 200, 150)
    R = (Rotation.from_euler("x", 20, degrees=True) * Rotation.from_euler("z", spin_deg, degrees=True)).as_matrix()
    t = np.array([0.0, 0.0, 0.3]) - R @ board.centre()
    gray = board_image(cam, R, t, board, 0.9, 0.05, 0.4, 4)
    u8 = np.round(gray * 255).astype(np.uint8)
    found, corners = cv2.findChessboardCorners(u8, board.pattern)
    assert found
    ordered = canonical_order(corners, u8, board) + np.float32(0.5)
    ok, rvec, tvec = cv2.solvePnP(board.object_points(), ordered, K, None)
    assert ok and rotation_angle_deg(cv2.Rodrigues(rvec)[0], R) < 1.0
    np.testing.assert_allclose(tvec.ravel(), t, atol=2e-3)
