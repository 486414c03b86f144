"""Readers (and fixture writers) for the Spring-Gaus and PAC-NeRF sequence layouts.

Spring-Gaus (`camera.json`): a JSON list with one entry per camera,
`{"camera": name, "K": [3,3], "c2w": [4,4] Blender/OpenGL}`; images `<camera>/<fff>.png`
RGBA. The image size is read from the images; the frame count is the number of consecutive
`000.png, 001.png, ...` files, which must agree between cameras.

PAC-NeRF (`all_data.json`): a JSON list with one entry per (view, frame) image,
`{"file_path": "./data/r_<view>_<frame>.png", "time": seconds, "c2w": [3,4] Blender/OpenGL,
"intrinsic": [3,3]}`. Views and frames are parsed from the file name; every view must have
every frame and the same camera in all of them; fps comes from the time stamps.

Neither layout stores the scene (ground, gravity, fit split, hit frame). They come from an
optional `sgdr_scene.json` in the folder (same keys as in sgdr's `sequence.json`: fps, n_fit,
hit_frame, ground {point, normal}, gravity), else from keyword arguments of the reader, else
from `SCENE_DEFAULTS` (the unit-cube benchmark's conventions).
"""

from __future__ import annotations

import json
import logging
import re
from pathlib import Path

import numpy as np

from sgdr.cameras import Camera, CameraError
from sgdr.data.sequence import (
    Sequence,
    as_array,
    check_image,
    check_split,
    fail,
    png_header,
    read_json,
    require,
    scene_fields,
    write_rgba,
)

SPRING_GAUS_FILE = "camera.json"
PAC_NERF_FILE = "all_data.json"
SCENE_FILE = "sgdr_scene.json"

# The benchmark's scene conventions, used where a foreign layout says nothing (see docstring).
SCENE_DEFAULTS = {
    "fps": 24.0,
    "n_fit": 20,
    "hit_frame": 0,
    "ground": {"point": [0.0, 0.0, 0.0], "normal": [0.0, 0.0, 1.0]},
    "gravity": [0.0, 0.0, -9.8],
}

log = logging.getLogger(__name__)
_PAC_NAME = re.compile(r"r_(\d+)_(\d+)\.png$")


def scene_meta(root: Path, n_frames: int, **overrides) -> tuple[dict, Path]:
    """Scene metadata for a foreign layout: sidecar file > keyword overrides > defaults."""
    meta = dict(SCENE_DEFAULTS)
    meta["n_fit"] = min(int(meta["n_fit"]), n_frames)
    meta.update({k: v for k, v in overrides.items() if v is not None})
    source = root / SCENE_FILE
    if source.is_file():
        sidecar = read_json(source)
        if not isinstance(sidecar, dict):
            fail(source, "<root>", "expected a JSON object")
        meta.update(sidecar)
    else:
        source = root / "<reader defaults>"
        assumed = {k: meta[k] for k in SCENE_DEFAULTS if k not in overrides or overrides[k] is None}
        if assumed:
            log.warning(
                "%s has no %s: assuming the benchmark's scene %s; write the file with your scene's values "
                "(docs/data-formats.md)",
                root,
                SCENE_FILE,
                assumed,
            )
    return meta, source


def finish(root, layout, cameras, paths, n_frames, meta, source) -> Sequence:
    n_fit, hit_frame = int(require(meta, "n_fit", source)), int(require(meta, "hit_frame", source))
    check_split(n_frames, n_fit, hit_frame, source)
    return Sequence(
        root=root,
        n_frames=n_frames,
        n_fit=n_fit,
        cameras=cameras,
        hit_frame=hit_frame,
        image_paths=paths,
        layout=layout,
        gt_dir=None,
        **scene_fields(meta, source),
    )


# ---------------------------------------------------------------------------- Spring-Gaus
def read_spring_gaus(root: Path, **scene) -> Sequence:
    file = root / SPRING_GAUS_FILE
    entries = read_json(file)
    if not isinstance(entries, list) or not entries:
        fail(file, "<root>", "expected a non-empty list of cameras")
    cameras, paths, counts = [], [], []
    for i, e in enumerate(entries):
        where = f"[{i}]"
        if not isinstance(e, dict):
            fail(file, where, "not a JSON object")
        name = str(require(e, "camera", file))
        K = as_array(require(e, "K", file), (3, 3), file, f"{where}.K")
        c2w = as_array(require(e, "c2w", file), (4, 4), file, f"{where}.c2w")
        folder = root / name
        if not folder.is_dir():
            fail(folder, f"{where}.camera", f"image folder of camera {name!r} is missing")
        frames = []
        while (folder / f"{len(frames):03d}.png").is_file():
            frames.append(folder / f"{len(frames):03d}.png")
        if not frames:
            fail(folder / "000.png", f"{where}.camera", f"camera {name!r} has no frame 000")
        width, height, _ = png_header(frames[0])
        try:
            cam = Camera.from_c2w_opengl(c2w, K, width, height, name)
        except CameraError as e_:
            fail(file, where, str(e_))
        for p in frames:
            check_image(p, width, height, f"{where} ({name})")
        cameras.append(cam)
        paths.append(frames)
        counts.append(len(frames))
    if len(set(counts)) != 1:
        detail = ", ".join(f"{c.name}: {n}" for c, n in zip(cameras, counts))
        fail(root, "frames", f"cameras have different frame counts ({detail})")
    meta, source = scene_meta(root, counts[0], **scene)
    return finish(root, "spring_gaus", cameras, paths, counts[0], meta, source)


def write_spring_gaus(root, cameras: list[Camera], images) -> Path:
    """Write the Spring-Gaus layout (fixtures, export). images[view][frame] -> [H, W, 4]."""
    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    entries = []
    for v, cam in enumerate(cameras):
        entries.append({"camera": cam.name, "K": cam.K.tolist(), "c2w": cam.c2w_opengl.tolist()})
        for f, im in enumerate(images[v]):
            write_rgba(root / cam.name / f"{f:03d}.png", im)
    (root / SPRING_GAUS_FILE).write_text(json.dumps(entries, indent=2))
    return root


# ---------------------------------------------------------------------------- PAC-NeRF
def read_pac_nerf(root: Path, **scene) -> Sequence:
    file = root / PAC_NERF_FILE
    entries = read_json(file)
    if not isinstance(entries, list) or not entries:
        fail(file, "<root>", "expected a non-empty list of images")
    per_view: dict[int, dict[int, tuple]] = {}
    for i, e in enumerate(entries):
        where = f"[{i}]"
        if not isinstance(e, dict):
            fail(file, where, "not a JSON object")
        rel = str(require(e, "file_path", file))
        m = _PAC_NAME.search(rel)
        if m is None:
            fail(file, f"{where}.file_path", f"{rel!r} is not named r_<view>_<frame>.png")
        view, frame = int(m.group(1)), int(m.group(2))
        time = float(require(e, "time", file))
        c2w = as_array(require(e, "c2w", file), (3, 4), file, f"{where}.c2w")
        K = as_array(require(e, "intrinsic", file), (3, 3), file, f"{where}.intrinsic")
        if frame in per_view.setdefault(view, {}):
            fail(file, f"{where}.file_path", f"view {view} frame {frame} listed twice")
        per_view[view][frame] = (root / rel, time, c2w, K, where)
    n_frames = max(len(frames) for frames in per_view.values())
    cameras, paths, times = [], [], None
    for view in sorted(per_view):
        frames = per_view[view]
        missing = sorted(set(range(n_frames)) - set(frames))
        if missing:
            fail(file, "file_path", f"view {view} lacks frames {missing} (others have {n_frames})")
        path0, _, c2w0, K0, where0 = frames[0]
        width, height, _ = png_header(path0)
        for f in range(n_frames):
            path, _, c2w, K, where = frames[f]
            if not (np.allclose(c2w, c2w0, atol=1e-6) and np.allclose(K, K0, atol=1e-6)):
                fail(file, f"{where}.c2w", f"view {view}: camera differs between frames 0 and {f}")
            check_image(path, width, height, f"{where}.file_path")
        try:
            cameras.append(Camera.from_c2w_opengl(c2w0, K0, width, height, f"r_{view}"))
        except CameraError as e_:
            fail(file, where0, str(e_))
        paths.append([frames[f][0] for f in range(n_frames)])
        view_times = np.array([frames[f][1] for f in range(n_frames)])
        if times is None:
            times = view_times
        elif not np.allclose(times, view_times, atol=1e-6):
            fail(file, "time", f"view {view} has time stamps different from view {min(per_view)}")
    if n_frames > 1:
        steps = np.diff(times)
        if np.any(steps <= 0) or not np.allclose(steps, steps[0], rtol=1e-3):
            fail(file, "time", "time stamps must increase by a constant step")
        scene = {"fps": 1.0 / float(steps[0]), **scene}
    meta, source = scene_meta(root, n_frames, **scene)
    return finish(root, "pac_nerf", cameras, paths, n_frames, meta, source)


def write_pac_nerf(root, cameras: list[Camera], images, fps: float) -> Path:
    """Write the PAC-NeRF layout (fixtures, export). images[view][frame] -> [H, W, 4]."""
    root = Path(root)
    entries = []
    for v, cam in enumerate(cameras):
        for f, im in enumerate(images[v]):
            rel = f"./data/r_{v}_{f}.png"
            write_rgba(root / rel, im)
            entries.append(
                {
                    "file_path": rel,
                    "time": f / float(fps),
                    "c2w": cam.c2w_opengl[:3].tolist(),
                    "intrinsic": cam.K.tolist(),
                }
            )
    (root / PAC_NERF_FILE).write_text(json.dumps(entries, indent=2))
    return root


def write_scene_sidecar(root, seq: Sequence) -> Path:
    """Write `sgdr_scene.json` carrying `seq`'s scene data next to a foreign layout."""
    path = Path(root) / SCENE_FILE
    path.write_text(
        json.dumps(
            {
                "fps": seq.fps,
                "n_fit": seq.n_fit,
                "hit_frame": seq.hit_frame,
                "ground": {"point": seq.ground_point.tolist(), "normal": seq.ground_normal.tolist()},
                "gravity": seq.gravity.tolist(),
            },
            indent=2,
        )
    )
    return path

