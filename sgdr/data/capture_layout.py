"""File names of the Spring-Gaus real-capture layout, as the official loader reads them.

    <root>/config.yaml                          official-style YAML (DATA: ..., DYNAMIC: {G})
    <root>/static/colmap/<obj>/cameras.bin      COLMAP binary, one PINHOLE camera (id 1)
    <root>/static/colmap/<obj>/images.bin       one image per photo, name '<name>.JPG'
    <root>/static/colmap/<obj>/points3D.bin     (may hold zero points)
    <root>/static/images/<obj>/<name>.JPG       the photos (RGB JPEG)
    <root>/static/masks/<obj>/<name>.png        8-bit object masks (255 = object)
    <root>/dynamic/cameras_calib.json           {cam: {rvecs, tvecs, K, dist}}, OpenCV world-to-camera
    <root>/dynamic/sync.json                    {cam: frame offset}
    <root>/dynamic/sequences/<obj>/<seq>.json   {"hit_frame": int, cam: [frame file names]}
    <root>/dynamic/videos_images/<cam>/<frame>.jpg
    <root>/dynamic/videos_masks/<cam>/<frame>.png
    <root>/dynamic/background/<cam>.jpg         a clean plate per camera
    <root>/dynamic/checkerboard/<cam>/<i>.jpg   calibration images (image 0: the world board)
    <root>/dynamic/checkerboard/pattern.json    the board: inner corners and square size
    <root>/gt/truth.json, gt/particles_<fff>.npy  ground truth of a simulated capture only

The official loader hard-codes the three camera names (`CAMERAS`) and derives a mask's path
from its image's path ('.JPG' -> '.png', '/images/' -> '/masks/'; '.jpg' -> '.png',
'/videos_images/' -> '/videos_masks/').
"""

from __future__ import annotations

from pathlib import Path

CAMERAS = ("C0733", "C0787", "C0801")  # the official loader's dynamic camera names, in its order
COMPLETE = "COMPLETE.json"  # the completion marker of a simulated capture, written last


def colmap_dir(root, obj: str) -> Path:
    return Path(root) / "static" / "colmap" / obj


def static_image(root, obj: str, name: str) -> Path:
    """The photo `<name>.JPG` (name without extension)."""
    return Path(root) / "static" / "images" / obj / f"{name}.JPG"


def static_mask(root, obj: str, name: str) -> Path:
    return Path(root) / "static" / "masks" / obj / f"{name}.png"


def video_frame(root, cam: str, frame_file: str) -> Path:
    """A video frame, `frame_file` as listed in the sequence file ('000000.jpg')."""
    return Path(root) / "dynamic" / "videos_images" / cam / frame_file


def video_mask(root, cam: str, frame_file: str) -> Path:
    return Path(root) / "dynamic" / "videos_masks" / cam / (Path(frame_file).stem + ".png")


def background_plate(root, cam: str) -> Path:
    return Path(root) / "dynamic" / "background" / f"{cam}.jpg"


def checkerboard_dir(root, cam: str) -> Path:
    return Path(root) / "dynamic" / "checkerboard" / cam


def checkerboard_pattern_file(root) -> Path:
    """{"pattern": [cols, rows] inner corners, "square_size": side in the dynamic frame's units}."""
    return Path(root) / "dynamic" / "checkerboard" / "pattern.json"


def sequence_file(root, obj: str, seq) -> Path:
    return Path(root) / "dynamic" / "sequences" / obj / f"{seq}.json"


def frame_file(frame: int) -> str:
    """The video frame file name of frame number `frame` ('000000.jpg')."""
    return f"{frame:06d}.jpg"
