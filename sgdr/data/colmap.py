"""COLMAP sparse models in the binary format: written with pycolmap, read by a small reader.

Writing goes through pycolmap (the COLMAP project's own bindings, pinned in pyproject.toml), so
the files are what COLMAP itself writes: `cameras.bin`, `images.bin`, `points3D.bin`, and, since
COLMAP 3.12, `rigs.bin` and `frames.bin` (one trivial rig per camera, one frame per image; the
official Spring-Gaus loader and older COLMAP readers ignore those two).

Reading is hand-written (`read_colmap`) because the Spring-Gaus loader needs only cameras.bin
and images.bin, and pycolmap's reader wants a complete model (points3D.bin, and rigs/frames);
the format, little-endian (COLMAP `src/colmap/scene/reconstruction_io_binary.cc`):

    cameras.bin   uint64 n; n x [int32 camera_id, int32 model_id, uint64 width, uint64 height,
                  float64 params[num_params(model)]]
    images.bin    uint64 n; n x [int32 image_id, float64 qvec[4] (w, x, y, z), float64 tvec[3],
                  int32 camera_id, name (bytes, NUL-terminated), uint64 n2d,
                  n2d x [float64 x, float64 y, int64 point3D_id]]
    points3D.bin  uint64 n; n x [uint64 id, float64 xyz[3], uint8 rgb[3], float64 error,
                  uint64 track_length, track_length x [int32 image_id, int32 point2D_idx]]

qvec and tvec are COLMAP's world-to-camera pose: x_cam = R(qvec) X + tvec, with OpenCV camera
axes (x right, y down, z forward), the convention of `sgdr.cameras.Camera`.
"""

from __future__ import annotations

import struct
from pathlib import Path
from typing import NamedTuple

import numpy as np
from scipy.spatial.transform import Rotation

# COLMAP's camera models: id -> (name, number of parameters) (src/colmap/sensor/models.h).
CAMERA_MODELS = {
    0: ("SIMPLE_PINHOLE", 3),
    1: ("PINHOLE", 4),
    2: ("SIMPLE_RADIAL", 4),
    3: ("RADIAL", 5),
    4: ("OPENCV", 8),
    5: ("OPENCV_FISHEYE", 8),
    6: ("FULL_OPENCV", 12),
    7: ("FOV", 5),
    8: ("SIMPLE_RADIAL_FISHEYE", 4),
    9: ("RADIAL_FISHEYE", 5),
    10: ("THIN_PRISM_FISHEYE", 12),
}
MODEL_IDS = {name: i for i, (name, _) in CAMERA_MODELS.items()}


class ColmapError(ValueError):
    """A COLMAP model that cannot be read or written; the message names the file."""


class ColmapCamera(NamedTuple):
    model: str  # COLMAP model name, e.g. "PINHOLE"
    width: int  # pixels
    height: int  # pixels
    params: np.ndarray  # [num_params] float64; PINHOLE: fx, fy, cx, cy (pixels)


class ColmapImage(NamedTuple):
    name: str  # image file name, e.g. "IMG_0001.JPG"
    qvec: np.ndarray  # [4] unit quaternion (w, x, y, z) of the world-to-camera rotation
    tvec: np.ndarray  # [3] world-to-camera translation, model units
    camera_id: int


# ---------------------------------------------------------------------------- rotations
def qvec_to_rotmat(qvec) -> np.ndarray:
    """[4] (w, x, y, z) -> [3, 3] rotation (COLMAP's convention)."""
    w, x, y, z = np.asarray(qvec, dtype=np.float64) / np.linalg.norm(qvec)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def rotmat_to_qvec(R) -> np.ndarray:
    """[3, 3] rotation -> [4] unit quaternion (w, x, y, z) with w >= 0."""

    x, y, z, w = Rotation.from_matrix(np.asarray(R, dtype=np.float64)).as_quat()
    q = np.array([w, x, y, z])
    return q if w >= 0 else -q


# ---------------------------------------------------------------------------- writing
def write_colmap(folder, cameras: dict[int, ColmapCamera], images: dict[int, ColmapImage]) -> Path:
    """Write cameras.bin, images.bin, points3D.bin (no points), rigs.bin, frames.bin to folder.

    cameras: camera id -> ColmapCamera; images: image id -> ColmapImage (qvec unit, as read back
    bit for bit). Returns the folder.
    """
    import pycolmap

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    rec = pycolmap.Reconstruction()
    for cam_id, cam in cameras.items():
        if cam.model not in MODEL_IDS or len(cam.params) != CAMERA_MODELS[MODEL_IDS[cam.model]][1]:
            raise ColmapError(f"{folder}: camera {cam_id}: model {cam.model!r} with {len(cam.params)} parameters")
        rec.add_camera_with_trivial_rig(
            pycolmap.Camera(
                model=cam.model,
                width=int(cam.width),
                height=int(cam.height),
                params=np.asarray(cam.params, dtype=np.float64),
                camera_id=int(cam_id),
            )
        )
    for image_id, im in images.items():
        if im.camera_id not in cameras:
            raise ColmapError(f"{folder}: image {im.name!r} names camera {im.camera_id}, which is not written")
        w, x, y, z = np.asarray(im.qvec, dtype=np.float64)
        pose = pycolmap.Rigid3d(pycolmap.Rotation3d(np.array([x, y, z, w])), np.asarray(im.tvec, dtype=np.float64))
        rec.add_image_with_trivial_frame(
            pycolmap.Image(name=im.name, camera_id=int(im.camera_id), image_id=int(image_id)), pose
        )
    rec.write_binary(str(folder))
    return folder


# ---------------------------------------------------------------------------- reading
class _Reader:
    def __init__(self, path: Path):
        self.path = path
        try:
            self.data = path.read_bytes()
        except OSError as e:
            raise ColmapError(f"{path}: cannot be read ({e.strerror or e})") from e
        self.offset = 0

    def read(self, fmt: str):
        size = struct.calcsize("<" + fmt)
        if self.offset + size > len(self.data):
            raise ColmapError(f"{self.path}: truncated at byte {self.offset}")
        out = struct.unpack_from("<" + fmt, self.data, self.offset)
        self.offset += size
        return out

    def read_name(self) -> str:
        end = self.data.find(b"\0", self.offset)
        if end < 0:
            raise ColmapError(f"{self.path}: an image name is not NUL-terminated")
        name = self.data[self.offset : end].decode("utf-8")
        self.offset = end + 1
        return name

    def done(self):
        if self.offset != len(self.data):
            raise ColmapError(f"{self.path}: {len(self.data) - self.offset} bytes after the last record")


def read_cameras_bin(path) -> dict[int, ColmapCamera]:
    r = _Reader(Path(path))
    (n,) = r.read("Q")
    cameras = {}
    for _ in range(n):
        cam_id, model_id, width, height = r.read("iiQQ")
        if model_id not in CAMERA_MODELS:
            raise ColmapError(f"{path}: camera {cam_id} has unknown model id {model_id}")
        name, n_params = CAMERA_MODELS[model_id]
        cameras[cam_id] = ColmapCamera(name, int(width), int(height), np.array(r.read("d" * n_params)))
    r.done()
    return cameras


def read_images_bin(path) -> dict[int, ColmapImage]:
    r = _Reader(Path(path))
    (n,) = r.read("Q")
    images = {}
    for _ in range(n):
        (image_id,) = r.read("i")
        qvec, tvec = np.array(r.read("4d")), np.array(r.read("3d"))
        (camera_id,) = r.read("i")
        name = r.read_name()
        (n2d,) = r.read("Q")
        r.offset += n2d * struct.calcsize("<ddq")  # the 2D points are not needed here
        images[image_id] = ColmapImage(name, qvec, tvec, int(camera_id))
    if r.offset > len(r.data):
        raise ColmapError(f"{path}: truncated in the 2D points")
    r.done()
    return images


def read_points3d_bin(path) -> np.ndarray:
    """[N, 3] float64 point positions of points3D.bin (colours, errors and tracks skipped)."""
    r = _Reader(Path(path))
    (n,) = r.read("Q")
    xyz = np.zeros((n, 3))
    for i in range(n):
        _, *p = r.read("Q3d")
        r.read("3Bd")
        (track,) = r.read("Q")
        r.offset += track * struct.calcsize("<ii")
        xyz[i] = p
    r.done()
    return xyz


def read_colmap(folder) -> tuple[dict[int, ColmapCamera], dict[int, ColmapImage]]:
    """(cameras: id -> (model, width, height, params), images: id -> (name, qvec, tvec, camera_id))
    from folder/cameras.bin and folder/images.bin (points3D.bin is not needed)."""
    folder = Path(folder)
    cameras = read_cameras_bin(folder / "cameras.bin")
    images = read_images_bin(folder / "images.bin")
    for im in images.values():
        if im.camera_id not in cameras:
            raise ColmapError(f"{folder / 'images.bin'}: image {im.name!r} names camera {im.camera_id}, absent")
    return cameras, images
