"""Reader for the Spring-Gaus real-capture layout, as released and as its loader reads it.

```
<root>/                                   (the config's DATA.DATA_ROOT)
  static/colmap/<obj>/cameras.bin         COLMAP cameras of the static scan (points3D.bin not needed)
  static/colmap/<obj>/images.bin          COLMAP poses: qvec, tvec (world-to-camera), camera id, photo name
  static/images/<obj>/<name>.JPG          the photos of the object at rest
  static/masks/<obj>/<name>.png           their masks (name with .JPG -> .png); a photo of another size is
                                          resized to its mask, as the official loader does (which keeps
                                          COLMAP's focal lengths unscaled and centres the principal point)
  dynamic/cameras_calib.json              {camera: {"rvecs": [3], "tvecs": [3], ...}} OpenCV world-to-camera
  dynamic/sequences/<obj>/<seq>.json      {"hit_frame": int, <camera>: [frame file names], ...}
  dynamic/videos_images/<camera>/<frame>.jpg
  dynamic/videos_masks/<camera>/<frame>.png
```

The scene comes from the official YAML config (`scene_file=config/real_capture/<obj>.yaml`, or
the one `*.yaml` in `<root>`; `sgdr.data.official_config`): DATA.OBJ_NAME and DATA.SEQ pick the
object and sequence; DATA.FREQ is the frame rate (120 in the paper), DYNAMIC.G the gravity (+z in
the released captures), DATA.BC the ground; DATA.W x DATA.H the video size; DATA.IMG_IS_MASK makes
the masks the fitting targets (the paper's real captures: "masks as fitting targets"); the
sequence file gives the hit frame. Every frame is a fit frame (a capture has no future to score).

Cameras as the official loader builds them: the dynamic cameras' rotation is
Rodrigues(rvecs), translation tvecs; their intrinsics are the static COLMAP camera's focal
lengths scaled by DATA.W / DATA.W_S and DATA.H / DATA.H_S, with the principal point at the image
centre (`Real_Capture.get_cam_info`), unless cameras_calib.json gives a camera its own "K" (as
`sgdr.data.calibrate` writes it), which is then used and logged. The camera names are the
official three (C0733, C0787, C0801) when all are present, else every camera of
cameras_calib.json that the sequence file lists. Lens distortion is not modelled (the official
code ignores it too); non-zero coefficients are named in a warning.

`read_real_capture` returns the dynamic `Sequence` (layout "spring_gaus_real"); its `extras`
hold the static scan as a one-frame `Sequence` of its own cameras and frame (`extras["static"]`,
no physics: gravity 0), the official initial registration (`extras["registration_init"]`:
INIT_R Euler degrees "XYZ", INIT_T, INIT_S of DATA.REGIST, the official
X_d = R (s (X_s - mean X_s)) + t) and the config's path.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from sgdr.cameras import Camera, CameraError
from sgdr.data.foreign import official_centre
from sgdr.data.official_config import read_spring_gaus_yaml, spring_gaus_scene
from sgdr.data.sequence import (
    Sequence,
    check_split,
    fail,
    png_header,
    read_json,
    require,
    scene_fields,
)
from sgdr.data.calibrate import CalibrationError
from sgdr.data.calibrate import calibrate_from_checkerboards
from sgdr.data.colmap import qvec_to_rotmat
from sgdr.data.colmap import read_colmap
import cv2

MARKER = "dynamic/sequences"
OFFICIAL_CAMERAS = ("C0733", "C0787", "C0801")  # hard-coded by the official loader
IMAGE_CHANNELS = (1, 2, 3, 4)

log = logging.getLogger(__name__)


def find_config(root: Path, scene_file) -> Path:
    if scene_file:
        return Path(scene_file)
    found = sorted(root.glob("*.yaml")) + sorted(root.glob("*.yml"))
    if len(found) == 1:
        log.info("%s: scene from the official config %s", root, found[0])
        return found[0]
    what = "no *.yaml" if not found else f"{len(found)} *.yaml files ({', '.join(p.name for p in found)})"
    fail(
        root,
        "scene_file",
        f"a Spring-Gaus real capture needs its official config (DATA.OBJ_NAME, DATA.SEQ, DATA.FREQ, DATA.BC, "
        f"DYNAMIC.G, ...): {what} in the folder; pass scene_file=<Spring-Gaus repo>/config/real_capture/<obj>.yaml",
    )


def _need(checks: dict, key: str, name: str, file):
    value = checks.get(name)
    if value is None:
        fail(file, key, "missing (the real-capture loader needs it)")
    return value


def colmap_intrinsics(model: str, width: int, height: int, params, where) -> np.ndarray:
    """[3, 3] pinhole K of a COLMAP camera (distortion terms are named in a warning, not modelled)."""
    p = [float(x) for x in params]
    if model in ("SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL", "SIMPLE_RADIAL_FISHEYE", "RADIAL_FISHEYE"):
        fx = fy = p[0]
        cx, cy, dist = p[1], p[2], p[3:]
    elif model in ("PINHOLE", "OPENCV", "OPENCV_FISHEYE", "FULL_OPENCV"):
        fx, fy, cx, cy, dist = p[0], p[1], p[2], p[3], p[4:]
    else:
        fail(where, "model", f"COLMAP camera model {model!r} is not supported (pinhole-like models only)")
    if "FISHEYE" in model:
        fail(where, "model", f"COLMAP camera model {model!r}: fisheye lenses are not supported")
    if any(abs(d) > 1e-9 for d in dist):
        log.warning(
            "%s: COLMAP %s camera has distortion %s; sgdr's cameras are pinholes, it is ignored", where, model, dist
        )
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


def read_static_scan(static_dir: Path, obj: str) -> Sequence:
    """The static scan as a one-frame Sequence: COLMAP cameras, photos composited with their masks."""

    colmap_dir = static_dir / "colmap" / obj
    for name in ("cameras.bin", "images.bin"):
        if not (colmap_dir / name).is_file():
            fail(colmap_dir / name, "<file>", "COLMAP file of the static scan is missing")
    cams, images = read_colmap(colmap_dir)
    if not images:
        fail(colmap_dir / "images.bin", "images", "holds no image")
    cameras, paths, masks = [], [], []
    for image_id in sorted(images):  # the official loader sorts by image id
        name, qvec, tvec, camera_id = images[image_id]
        where = colmap_dir / "images.bin"
        if camera_id not in cams:
            fail(where, f"image {image_id}.camera_id", f"camera {camera_id} is not in cameras.bin")
        model, cw, ch, params = cams[camera_id]
        photo = static_dir / "images" / obj / name
        mask = static_dir / "masks" / obj / name.replace(".JPG", ".png")  # the official loader's mapping
        if not mask.is_file():
            mask = mask.with_suffix(".png")
        if not photo.is_file():
            fail(photo, f"image {image_id}.name", "photo of the static scan is missing")
        if not mask.is_file():
            fail(mask, f"image {image_id}.name", "mask of the static scan photo is missing")
        mw, mh, _ = png_header(mask)
        # as the official loader: FovX, FovY from COLMAP's focal lengths and the mask's size (a photo of another
        # size is resized to its mask), principal point at the centre
        K = official_centre(colmap_intrinsics(model, cw, ch, params, colmap_dir / "cameras.bin"), mw, mh,
                            f"{colmap_dir / 'cameras.bin'} camera {camera_id}")
        if (mw, mh) != (cw, ch) and image_id == min(images):
            log.warning("%s: COLMAP camera %d is %dx%d, the masks %dx%d: as the official loader, its focal lengths are "
                        "used unscaled with the mask's size", colmap_dir, camera_id, cw, ch, mw, mh)
        try:
            cameras.append(
                Camera(K, qvec_to_rotmat(qvec), np.asarray(tvec, dtype=np.float64), mw, mh, Path(name).stem)
            )
        except CameraError as e:
            fail(where, f"image {image_id}", str(e))
        paths.append([photo])
        masks.append([mask])
    return Sequence(
        root=static_dir,
        fps=1.0,
        n_frames=1,
        n_fit=1,
        cameras=cameras,
        ground_point=np.zeros(3),
        ground_normal=np.array([0.0, 0.0, 1.0]),
        gravity=np.zeros(3),  # a static scan: no physics in its frame
        hit_frame=0,
        image_paths=paths,
        layout="spring_gaus_real_static",
        alpha_mode="straight",
        mask_paths=masks,
        resize=True,
        extras={"colmap_cameras": cams},
    )


def read_real_capture(root: Path, scene_file=None, **overrides) -> Sequence:
    root = Path(root)
    config = find_config(root, scene_file)
    cfg = read_spring_gaus_yaml(config)
    scene, checks = spring_gaus_scene(cfg, config)
    obj = _need(checks, "DATA.OBJ_NAME", "obj_name", config)
    seq_name = checks.get("seq", "0")
    width = _need(checks, "DATA.W", "width", config)
    height = _need(checks, "DATA.H", "height", config)
    dyn = root / "dynamic"
    calib_file = dyn / "cameras_calib.json"
    seq_file = dyn / "sequences" / obj / f"{seq_name}.json"
    seq_info = read_json(seq_file)
    if not isinstance(seq_info, dict):
        fail(seq_file, "<root>", "expected an object {hit_frame, <camera>: [frames]}")
    listed = [c for c, v in seq_info.items() if isinstance(v, list)]
    calib = read_calibration(dyn, calib_file, listed)
    names = (
        list(OFFICIAL_CAMERAS)
        if all(c in calib for c in OFFICIAL_CAMERAS)
        else [c for c in calib if isinstance(seq_info.get(c), list)]
    )
    if not names:
        fail(seq_file, "<cameras>", f"lists frames of none of the cameras of {calib_file.name} ({sorted(calib)})")
    static = read_static_scan(root / "static", obj)
    cameras, paths, masks, plates, n_frames = [], [], [], [], None
    for name in names:
        entry = calib[name]
        rvec = np.asarray(require(entry, "rvecs", calib_file), dtype=np.float64).reshape(-1)
        tvec = np.asarray(require(entry, "tvecs", calib_file), dtype=np.float64).reshape(-1)
        if rvec.shape != (3,) or tvec.shape != (3,):
            fail(calib_file, f"{name}.rvecs/tvecs", f"expected 3 numbers each, got {rvec.shape} and {tvec.shape}")
        if "K" in entry:
            K = np.asarray(entry["K"], dtype=np.float64)
            if K.shape != (3, 3):
                fail(calib_file, f"{name}.K", f"expected shape [3, 3], got {list(K.shape)}")
            log.info("%s: camera %s uses its own K from %s", root, name, calib_file.name)
        else:  # the official loader: the static camera's focal, scaled to the video, centred principal point
            w_s = _need(checks, "DATA.W_S", "width_static", config)
            h_s = _need(checks, "DATA.H_S", "height_static", config)
            fx, fy = _colmap_focal(static, root)
            K = np.array([[fx * width / w_s, 0, width / 2], [0, fy * height / h_s, height / 2], [0, 0, 1.0]])
        dist = np.asarray(entry.get("dist", []), dtype=np.float64).reshape(-1)
        if np.any(np.abs(dist) > 1e-9):
            log.warning(
                "%s: camera %s has lens distortion %s; not modelled (the official loader ignores it too)",
                calib_file,
                name,
                dist.tolist(),
            )
        R, _ = cv2.Rodrigues(rvec)
        try:
            cameras.append(Camera(K, R, tvec, width, height, name))
        except CameraError as e:
            fail(calib_file, name, str(e))
        frames = require(seq_info, name, seq_file)
        if not isinstance(frames, list) or not frames:
            fail(seq_file, name, "expected a non-empty list of frame file names")
        if n_frames is None:
            n_frames = len(frames)
        elif len(frames) != n_frames:
            fail(seq_file, name, f"lists {len(frames)} frames, camera {names[0]} {n_frames}")
        view_paths, view_masks = [], []
        plate = dyn / "background" / f"{name}.jpg"
        from_plate = not (dyn / "videos_masks" / name).is_dir() and plate.is_file()
        if from_plate:
            log.info("%s: camera %s has no masks: matted against its background plate %s", root, name, plate)
            check_size(plate, width, height, f"background of {name}")
        for f, frame in enumerate(frames):
            image = dyn / "videos_images" / name / str(frame)
            mask = (dyn / "videos_masks" / name / str(frame).replace(".jpg", ".png")).with_suffix(".png")
            if from_plate:
                if not image.is_file():
                    fail(image, f"{name}[{f}]", "video frame is missing (the masks come from it and the plate)")
                check_size(image, width, height, f"{name}[{f}]")
                view_paths.append(image)
                continue
            if not mask.is_file():
                fail(mask, f"{name}[{f}]", "mask of the video frame is missing")
            if not image.is_file():
                if not checks.get("img_is_mask"):
                    fail(
                        image, f"{name}[{f}]", "video frame is missing (DATA.IMG_IS_MASK is false: images are targets)"
                    )
                image = mask  # masks are the targets; the official loader never opens the frame
            for p in (image, mask):
                check_size(p, width, height, f"{name}[{f}]")
            view_paths.append(image)
            view_masks.append(mask)
        paths.append(view_paths)
        masks.append(None if from_plate else view_masks)
        plates.append(plate if from_plate else None)
    meta = {"n_fit": n_frames, **scene}
    meta["hit_frame"] = require(seq_info, "hit_frame", seq_file)
    meta.update({k: v for k, v in overrides.items() if v is not None})
    for key, what in (("fps", "DATA.FREQ"), ("ground", "DATA.BC"), ("gravity", "DYNAMIC.G")):
        if key not in meta:
            fail(config, what, "missing (the real capture's scene)")
    check_split(n_frames, int(meta["n_fit"]), int(meta["hit_frame"]), seq_file)
    regist = checks.get("regist") or {}
    init = {
        "rotation_euler_xyz_deg": [float(x) for x in regist.get("INIT_R", [0, 0, 0])],
        "translation": [float(x) for x in regist.get("INIT_T", [0, 0, 0])],
        "scale": float(np.asarray(regist.get("INIT_S", [1.0]), dtype=np.float64).reshape(-1)[0]),
        "given": bool(regist),
    }
    return Sequence(
        root=root,
        n_frames=n_frames,
        n_fit=int(meta["n_fit"]),
        cameras=cameras,
        hit_frame=int(meta["hit_frame"]),
        image_paths=paths,
        layout="spring_gaus_real",
        gt_dir=None,
        alpha_mode="straight",
        mask_paths=masks,
        backgrounds=plates if any(p is not None for p in plates) else None,
        mask_only=bool(checks.get("img_is_mask", False)),
        extras={"static": static, "registration_init": init, "config": str(config)},
        **scene_fields(meta, config),
    )


def check_size(path: Path, width: int, height: int, where: str):
    w, h, c = png_header(path)
    if (w, h) != (width, height):
        fail(path, where, f"image is {w}x{h}, the config says DATA.W x DATA.H = {width}x{height}")
    if c not in IMAGE_CHANNELS:
        fail(path, where, f"image has {c} channels")


def read_calibration(dyn: Path, calib_file: Path, cameras: list[str]) -> dict:
    """cameras_calib.json, or, without it, a calibration from the checkerboard images
    (`dynamic/checkerboard/<camera>/<i>.jpg`, image 0 showing the world board, and
    `dynamic/checkerboard/pattern.json` {"pattern": [cols, rows], "square_size"}) with OpenCV
    (`sgdr.data.calibrate`); entries {rvecs, tvecs, K, dist} either way."""
    if calib_file.is_file():
        calib = read_json(calib_file)
        if not isinstance(calib, dict) or not calib:
            fail(calib_file, "<root>", "expected an object {camera: {rvecs, tvecs}}")
        return calib

    pattern_file = dyn / "checkerboard" / "pattern.json"
    if not pattern_file.is_file():
        fail(calib_file, "<file>", f"missing, and no checkerboard images to calibrate from ({pattern_file} is missing)")
    spec = read_json(pattern_file)
    pattern = require(spec, "pattern", pattern_file)
    square = float(require(spec, "square_size", pattern_file))
    calib = {}
    for name in cameras:
        folder = dyn / "checkerboard" / name
        images = sorted(folder.glob("*.jpg"), key=lambda p: (len(p.stem), p.stem)) if folder.is_dir() else []
        if not images:
            fail(folder, name, "no checkerboard images (<i>.jpg) for this camera, and no cameras_calib.json")
        try:
            c = calibrate_from_checkerboards(images, pattern, square)
        except CalibrationError as e:
            fail(folder, name, str(e))
        log.info("%s: camera %s calibrated from %d checkerboard images (rms %.3f px)", dyn, name, len(images), c.rms)
        calib[name] = {"rvecs": c.rvec.tolist(), "tvecs": c.tvec.tolist(), "K": c.K.tolist(), "dist": c.dist.tolist()}
    return calib


def _colmap_focal(static: Sequence, root: Path) -> tuple[float, float]:
    """(fx, fy) of the static scan's COLMAP camera 1 at COLMAP's resolution (the official loader's
    camdata[1]; the lowest camera id when there is no camera 1)."""
    cams = static.extras["colmap_cameras"]
    model, width, height, params = cams[1] if 1 in cams else cams[min(cams)]
    K = colmap_intrinsics(model, width, height, params, root / "static" / "colmap")
    return float(K[0, 0]), float(K[1, 1])
