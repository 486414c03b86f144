"""Calibration of a video camera from checkerboard images (OpenCV), and cameras_calib.json.

`calibrate_from_checkerboards(image_paths, pattern, square_size)`:
1. every image is read and turned grey; `cv2.findChessboardCorners` (adaptive threshold,
   normalised image) finds the pattern's inner corners, `cv2.cornerSubPix` refines them in a
   window of about 0.4 x the smallest corner spacing (2..11 px half-width);
2. `sgdr.data.board.canonical_order` puts them in the board convention (corner (0, 0) next
   to the black outer square, the board's z axis away from the camera), so that the first
   image's board defines the world frame without ambiguity;
3. they are moved to sgdr's pixel convention (pixel centres at integer + 0.5, `sgdr.cameras`;
   OpenCV puts them at integers), so K's principal point is in the same convention as every
   other K of sgdr (the image centre is (W/2, H/2));
4. `cv2.calibrateCamera` fits K, the distortion (k1, k2, p1, p2, k3; by default k3 and the
   tangential p1, p2 are held at 0) and one board pose per image.

Returns `Calibration(K [3, 3], dist [5], rvec [3], tvec [3], rms)`: rvec / tvec are the first
image's board-to-camera pose, i.e. the camera's world-to-camera pose when the first board is
the world (x_cam = Rodrigues(rvec) X + tvec, X in the board's units); rms is the reprojection
error in pixels over all images. Errors name the file: an unreadable image, one of another
size, one without the board (unless `skip_missing`, which drops such images but never the
first), fewer than 3 images with a board.

`write_cameras_calib(path, per_camera)` writes the Spring-Gaus `cameras_calib.json`:
{camera: {"rvecs": [3], "tvecs": [3], "K": [[3 x 3]], "dist": [5]}}; `read_cameras_calib`
reads it back as `sgdr.cameras.Camera`s.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import NamedTuple

import numpy as np

from sgdr.cameras import Camera
from sgdr.data.board import Board, canonical_order
import cv2

log = logging.getLogger(__name__)

MIN_IMAGES = 3  # calibrateCamera needs several views of a planar target for K


class CalibrationError(ValueError):
    """Checkerboard images that cannot calibrate a camera; the message names the file."""


class Calibration(NamedTuple):
    K: np.ndarray  # [3, 3] intrinsics, pixels (sgdr's pixel convention)
    dist: np.ndarray  # [5] OpenCV distortion k1, k2, p1, p2, k3
    rvec: np.ndarray  # [3] Rodrigues vector of the world-to-camera rotation (world = first board)
    tvec: np.ndarray  # [3] world-to-camera translation, board units (the square size's)
    rms: float  # reprojection error over all images, pixels


def find_board(path, board: Board, subpix_iterations: int = 40) -> tuple[np.ndarray, tuple[int, int]] | None:
    """([cols * rows, 1, 2] float32 corners in sgdr's pixel convention, (width, height)) of the
    board in the image at `path`, or None when no board is found (module docstring, 1-3)."""

    image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if image is None:
        raise CalibrationError(f"{path}: cannot be read as an image")
    size = (image.shape[1], image.shape[0])
    flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
    found, corners = cv2.findChessboardCorners(image, board.pattern, flags=flags)
    if not found:
        return None
    grid = corners.reshape(board.rows, board.cols, 2)
    spacing = min(
        np.linalg.norm(np.diff(grid, axis=1), axis=-1).min(), np.linalg.norm(np.diff(grid, axis=0), axis=-1).min()
    )
    half = int(np.clip(np.floor(0.4 * spacing), 2, 11))
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, int(subpix_iterations), 1e-3)
    corners = cv2.cornerSubPix(image, corners, (half, half), (-1, -1), criteria)
    corners = canonical_order(corners, image, board)
    return corners + np.float32(0.5), size


def calibrate_from_checkerboards(
    image_paths,
    pattern,
    square_size: float,
    fix_k3: bool = True,
    zero_tangent: bool = True,
    skip_missing: bool = False,
) -> Calibration:
    """Calibrate one camera from its checkerboard images (module docstring).

    image_paths: the images, the first one showing the world board; pattern: (cols, rows)
    inner corners; square_size: the square's side (sets the world's units, e.g. metres);
    fix_k3, zero_tangent: keep k3 = 0, and p1 = p2 = 0 (a few small images cannot pin these
    terms: on the simulated capture's 160 x 120 boards, freeing p1, p2 moves the principal point
    by up to 3 px and the world pose by up to 0.8°, against 2 px and 0.5° with them fixed);
    skip_missing: drop images without a board (logged) instead of failing.
    """

    paths = [Path(p) for p in image_paths]
    if not paths:
        raise CalibrationError("no checkerboard images given")
    board = Board(int(pattern[0]), int(pattern[1]), float(square_size))
    obj = board.object_points()
    object_points, image_points, used, size = [], [], [], None
    for i, path in enumerate(paths):
        found = find_board(path, board)
        if found is None:
            if i == 0 or not skip_missing:
                what = "the first image (the world board)" if i == 0 else "an image"
                raise CalibrationError(f"{path}: no {board.cols}x{board.rows} checkerboard found in {what}")
            log.warning("%s: no %dx%d checkerboard found, image skipped", path, board.cols, board.rows)
            continue
        corners, image_size = found
        if size is not None and image_size != size:
            raise CalibrationError(f"{path}: size {image_size} differs from the first image's {size}")
        size = image_size
        object_points.append(obj)
        image_points.append(corners)
        used.append(path)
    if len(used) < MIN_IMAGES:
        raise CalibrationError(
            f"only {len(used)} of {len(paths)} images show the board ({', '.join(map(str, used)) or 'none'}); "
            f"calibration needs at least {MIN_IMAGES}"
        )
    flags = (cv2.CALIB_FIX_K3 if fix_k3 else 0) | (cv2.CALIB_ZERO_TANGENT_DIST if zero_tangent else 0)
    rms, K, dist, rvecs, tvecs = cv2.calibrateCamera(object_points, image_points, size, None, None, flags=flags)
    return Calibration(
        np.asarray(K, dtype=np.float64),
        np.asarray(dist, dtype=np.float64).reshape(-1)[:5],
        np.asarray(rvecs[0], dtype=np.float64).reshape(3),
        np.asarray(tvecs[0], dtype=np.float64).reshape(3),
        float(rms),
    )


def write_cameras_calib(path, per_camera: dict) -> Path:
    """Write cameras_calib.json from {camera name: Calibration (or anything with K, dist, rvec, tvec)}."""
    out = {}
    for name, c in per_camera.items():
        dist = np.zeros(5)
        d = np.asarray(c.dist, dtype=np.float64).reshape(-1)
        dist[: min(5, d.size)] = d[:5]
        out[name] = {
            "rvecs": np.asarray(c.rvec, dtype=np.float64).reshape(3).tolist(),
            "tvecs": np.asarray(c.tvec, dtype=np.float64).reshape(3).tolist(),
            "K": np.asarray(c.K, dtype=np.float64).reshape(3, 3).tolist(),
            "dist": dist.tolist(),
        }
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(out, indent=2))
    return path


def read_cameras_calib(path, width: int, height: int) -> dict[str, Camera]:
    """{camera name: Camera} from a cameras_calib.json (its K and pose; the distortion is not
    part of a `Camera` and is dropped)."""

    try:
        calib = json.loads(Path(path).read_text())
    except (OSError, json.JSONDecodeError) as e:
        raise CalibrationError(f"{path}: cannot be read as JSON ({e})") from e
    cams = {}
    for name, c in calib.items():
        missing = [k for k in ("rvecs", "tvecs", "K") if k not in c]
        if missing:
            raise CalibrationError(f"{path}: camera {name!r} lacks {missing}")
        R, _ = cv2.Rodrigues(np.asarray(c["rvecs"], dtype=np.float64).reshape(3, 1))
        cams[name] = Camera(c["K"], R, np.asarray(c["tvecs"], dtype=np.float64).reshape(3), width, height, name)
    return cams
