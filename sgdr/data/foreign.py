"""Readers (and fixture writers) for the Spring-Gaus and PAC-NeRF sequence layouts, as released.

Spring-Gaus synthetic (`camera.json`): a JSON list with one entry per camera,
`{"camera": name, "K": [3,3], "c2w": [4,4] Blender/OpenGL}` (as the official loader, only the
focal lengths of K are used: the principal point is the image centre); images `<camera>/<fff>.png`
(RGBA, straight alpha; RGB or grey images are read as opaque, as the official loader's
`convert("RGBA")` does). The image size is read from the images; the frames are every
`<number>.png` of a camera's folder, which must run from 000 without a gap and agree between
cameras (a gap names the missing file).

PAC-NeRF (`all_data.json`): a JSON list with one entry per image,
`{"file_path": "./data/r_<view>_<frame>.png", "c2w": [3,4] Blender/OpenGL, "intrinsic": [3,3],
"time": seconds (optional: the official code never reads it)}`. Frame -1 is the view's clean
background plate: the frames (RGB over that background, as released) are matted against it
(`sgdr.data.matte`, in place of PAC-NeRF's BackgroundMattingV2 network, whose weights cannot be
downloaded). A view without a plate needs RGBA frames (straight alpha). Frame -2 is PAC-NeRF's
ray mask (rays whose alpha > 50 it leaves out of its loss): read, but sgdr's losses use every
pixel, which is said in a warning. Every view needs frames 0..n-1 and one camera for all of them.

The scene (fps, hit frame, ground, gravity; optionally n_fit) is in neither folder. It comes from,
in rising precedence: what the layout itself records (PAC-NeRF's time stamps: fps), a scene file
(`scene_file`: sgdr's `sgdr_scene.json` form, the official Spring-Gaus YAML config or PAC-NeRF
Python config, `sgdr.data.official_config`; without one, `sgdr_scene.json` in the folder), and
keyword overrides of the reader. A missing value is refused with the ways to give it, never
assumed. n_fit defaults to the official configs' fit frames, else every frame.
"""

from __future__ import annotations

import json
import logging
import re
from pathlib import Path

import numpy as np

from sgdr.cameras import Camera, CameraError
from sgdr.data.official_config import read_scene_file
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
    write_straight_rgba,
)
from sgdr.data.sequence import SequenceError
import imageio.v3 as iio

SPRING_GAUS_FILE = "camera.json"
PAC_NERF_FILE = "all_data.json"
SCENE_FILE = "sgdr_scene.json"
SCENE_KEYS = ("fps", "hit_frame", "ground", "gravity")  # required; n_fit is optional
FOREIGN_CHANNELS = (1, 2, 3, 4)  # grey, grey + alpha, RGB, RGBA

log = logging.getLogger(__name__)
_PAC_NAME = re.compile(r"r_(\d+)_(-?\d+)\.png$")
_FRAME_NAME = re.compile(r"^(\d+)\.png$")
_LAYOUT_HINT = {
    "spring_gaus": "the official config (scene_file=<Spring-Gaus repo>/config/mpm_synthetic/<object>.yaml)",
    "pac_nerf": "the official config (scene_file=<PAC-NeRF repo>/configs/<object>.py)",
    "spring_gaus_real": "the official config (scene_file=<Spring-Gaus repo>/config/real_capture/<object>.yaml)",
}


def scene_meta(root: Path, layout: str, n_frames: int, recorded=None, scene_file=None, **overrides):
    """(meta, source, checks): the scene of a foreign layout from (rising precedence) `recorded`
    (what the layout stores), the scene file (`scene_file`, else the folder's sgdr_scene.json) and
    `overrides` (None values ignored). Refuses a missing fps / hit_frame / ground / gravity."""
    meta, origin, checks = {}, {}, {}
    for k, v in (recorded or {}).items():
        meta[k], origin[k] = v, f"{root} ({layout} layout)"
    source = Path(scene_file) if scene_file else root / SCENE_FILE
    if scene_file or source.is_file():
        values, checks, _ = read_scene_file(source)
        for k, v in values.items():
            meta[k], origin[k] = v, str(source)
    for k, v in overrides.items():
        if v is not None:
            meta[k], origin[k] = v, "reader argument"
    missing = [k for k in SCENE_KEYS if k not in meta]
    if missing:
        raise_missing_scene(root, layout, missing)
    if "n_fit" not in meta:
        meta["n_fit"] = n_frames
        origin["n_fit"] = "every frame (no scene value)"
    elif int(meta["n_fit"]) > n_frames:
        log.warning(
            "%s: n_fit=%s (%s) is more than the %d frames on disk; fitting all of them",
            root,
            meta["n_fit"],
            origin["n_fit"],
            n_frames,
        )
        meta["n_fit"] = n_frames
    log.info("%s: scene %s", root, {k: f"{meta[k]} ({origin[k]})" for k in (*SCENE_KEYS, "n_fit")})
    return meta, source if source.is_file() else root, checks


def raise_missing_scene(root: Path, layout: str, missing: list[str]):
    raise SequenceError(
        f"{root}: the {layout} layout does not record the scene and nothing gave {', '.join(missing)}: pass "
        f"{_LAYOUT_HINT.get(layout, 'a scene file (scene_file=...)')}, or write {root / SCENE_FILE} "
        "(keys fps, hit_frame, ground {point, normal}, gravity, optional n_fit; docs/data-formats.md)"
    )


def check_against_config(root: Path, source, checks: dict, cameras: list[Camera]):
    """Refuse data the scene file's own sizes contradict (the official loaders take those sizes
    from the config, so a mismatch means the wrong config or the wrong data)."""
    w, h = cameras[0].width, cameras[0].height
    for name, actual, keys in (("width", w, "DATA.W / W"), ("height", h, "DATA.H / H")):
        if name in checks and checks[name] != actual:
            fail(source, keys, f"the config says {name} {checks[name]}, the images of {root} are {w}x{h}")
    if "n_cameras" in checks and checks["n_cameras"] != len(cameras):
        log.warning(
            "%s: the config says %d cameras (DATA.N_CAM / n_cameras), the data has %d; using all of them",
            source,
            checks["n_cameras"],
            len(cameras),
        )


def finish(root, layout, cameras, paths, n_frames, meta, source, **fields) -> Sequence:
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
        **fields,
    )


def numbered_frames(folder: Path, where: str) -> list[Path]:
    """`<number>.png` files of a folder in order; a gap in the numbering names the missing file."""
    found = {}
    for p in folder.iterdir():
        m = _FRAME_NAME.match(p.name)
        if m:
            found[int(m.group(1))] = p
    if not found:
        fail(folder / "000.png", where, f"{folder} holds no numbered frames (000.png, 001.png, ...)")
    width = len(found[min(found)].stem)
    missing = sorted(set(range(max(found) + 1)) - set(found))
    if missing:
        fail(
            folder / f"{missing[0]:0{width}d}.png",
            where,
            f"frame {missing[0]} is missing (frames {missing} of 0..{max(found)}); frames must run from 0 without gaps",
        )
    return [found[i] for i in range(len(found))]


# ---------------------------------------------------------------------------- Spring-Gaus
def official_centre(K: np.ndarray, width: int, height: int, where: str) -> np.ndarray:
    """K with the principal point at the image centre: the official Spring-Gaus loaders keep only
    the field of view (FovX, FovY from fx, fy and the image size) and its rasteriser centres the
    projection, so a K whose cx, cy say otherwise is read as the official code reads it (warned)."""
    K = np.array(K, dtype=np.float64)
    if abs(K[0, 2] - width / 2) > 1e-6 or abs(K[1, 2] - height / 2) > 1e-6:
        log.warning("%s: principal point (%.3f, %.3f) is not the image centre (%.1f, %.1f); the official loader "
                    "ignores it (field of view only), so does sgdr", where, K[0, 2], K[1, 2], width / 2, height / 2)
    K[0, 2], K[1, 2] = width / 2, height / 2
    return K


def read_spring_gaus(root: Path, scene_file=None, **scene) -> Sequence:
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
        frames = numbered_frames(folder, f"{where}.camera")
        width, height, _ = png_header(frames[0])
        K = official_centre(K, width, height, f"{file} {where}.K")
        try:
            cam = Camera.from_c2w_opengl(c2w, K, width, height, name)
        except CameraError as e_:
            fail(file, where, str(e_))
        for p in frames:
            check_image(p, width, height, f"{where} ({name})", FOREIGN_CHANNELS)
        cameras.append(cam)
        paths.append(frames)
        counts.append(len(frames))
    if len(set(counts)) != 1:
        detail = ", ".join(f"{c.name}: {n}" for c, n in zip(cameras, counts))
        fail(root, "frames", f"cameras have different frame counts ({detail})")
    if any(png_header(p[0])[2] in (1, 3) for p in paths):
        log.warning(
            "%s: images without alpha are opaque (alpha 1, as the official loader reads them): no "
            "silhouette; losses that use the mask see the whole image",
            root,
        )
    meta, source, checks = scene_meta(root, "spring_gaus", counts[0], scene_file=scene_file, **scene)
    check_against_config(root, source, checks, cameras)
    if "n_frames_all" in checks and checks["n_frames_all"] > counts[0]:
        log.warning(
            "%s: the config says %d frames in all (DATA.FRAME_ALL), the data has %d",
            source,
            checks["n_frames_all"],
            counts[0],
        )
    if "obj_name" in checks and checks["obj_name"] != root.name:
        log.warning(
            "%s: the config is for object %r (DATA.OBJ_NAME), the folder is %r", source, checks["obj_name"], root.name
        )
    return finish(root, "spring_gaus", cameras, paths, counts[0], meta, source, alpha_mode="straight")


def write_spring_gaus(root, cameras: list[Camera], images) -> Path:
    """Write the Spring-Gaus layout (fixtures, export). images[view][frame] -> [H, W, 4]
    premultiplied (as `Sequence.image` returns them); the PNGs hold straight alpha."""
    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    entries = []
    for v, cam in enumerate(cameras):
        entries.append({"camera": cam.name, "K": cam.K.tolist(), "c2w": cam.c2w_opengl.tolist()})
        for f, im in enumerate(images[v]):
            write_straight_rgba(root / cam.name / f"{f:03d}.png", im)
    (root / SPRING_GAUS_FILE).write_text(json.dumps(entries, indent=2))
    return root


# ---------------------------------------------------------------------------- PAC-NeRF
def _pac_camera(e: dict, file, where: str):
    c2w = as_array(require(e, "c2w", file), (3, 4), file, f"{where}.c2w")  # PAC-NeRF stores [3, 4] only
    K = as_array(require(e, "intrinsic", file), (3, 3), file, f"{where}.intrinsic")
    return c2w, K


def read_pac_nerf(root: Path, scene_file=None, **scene) -> Sequence:
    file = root / PAC_NERF_FILE
    entries = read_json(file)
    if not isinstance(entries, list) or not entries:
        fail(file, "<root>", "expected a non-empty list of images")
    per_view: dict[int, dict[int, tuple]] = {}
    plates: dict[int, Path] = {}
    ray_masks: dict[int, Path] = {}
    for i, e in enumerate(entries):
        where = f"[{i}]"
        if not isinstance(e, dict):
            fail(file, where, "not a JSON object")
        rel = str(require(e, "file_path", file))
        m = _PAC_NAME.search(rel)
        if m is None:
            fail(file, f"{where}.file_path", f"{rel!r} is not named r_<view>_<frame>.png (frame -1: background)")
        view, frame = int(m.group(1)), int(m.group(2))
        if frame in (-1, -2):
            (plates if frame == -1 else ray_masks)[view] = root / rel
            continue
        if frame < 0:
            fail(file, f"{where}.file_path", f"{rel!r}: frame {frame} (only -1 background and -2 ray mask are known)")
        time = e.get("time")
        if time is not None:
            time = float(time)
        c2w, K = _pac_camera(e, file, where)
        if frame in per_view.setdefault(view, {}):
            fail(file, f"{where}.file_path", f"view {view} frame {frame} listed twice")
        per_view[view][frame] = (root / rel, time, c2w, K, where)
    if not per_view:
        fail(file, "file_path", "lists no frame images (only backgrounds)")
    n_frames = max(len(frames) for frames in per_view.values())
    cameras, paths, backgrounds, times = [], [], [], None
    for view in sorted(per_view):
        frames = per_view[view]
        missing = sorted(set(range(n_frames)) - set(frames))
        if missing:
            fail(file, "file_path", f"view {view} lacks frames {missing} (others have {n_frames})")
        path0, _, c2w0, K0, where0 = frames[0]
        width, height, _ = png_header(path0)
        plate = plates.get(view)
        if plate is not None:
            check_image(plate, width, height, f"background of view {view}", FOREIGN_CHANNELS)
        for f in range(n_frames):
            path, _, c2w, K, where = frames[f]
            if not (np.allclose(c2w, c2w0, atol=1e-6) and np.allclose(K, K0, atol=1e-6)):
                fail(file, f"{where}.c2w", f"view {view}: camera differs between frames 0 and {f}")
            c = check_image(path, width, height, f"{where}.file_path", FOREIGN_CHANNELS)
            if plate is None and c not in (2, 4):
                fail(
                    path,
                    f"{where}.file_path",
                    f"has no alpha and view {view} has no background r_{view}_-1.png "
                    "to matte it against: give RGBA images or the background plate",
                )
        try:
            cameras.append(Camera.from_c2w_opengl(np.vstack([c2w0, [0, 0, 0, 1]]), K0, width, height, f"r_{view}"))
        except CameraError as e_:
            fail(file, where0, str(e_))
        paths.append([frames[f][0] for f in range(n_frames)])
        backgrounds.append(plate)
        view_times = [frames[f][1] for f in range(n_frames)]
        if any(t is None for t in view_times):
            if any(t is not None for t in view_times) or (times is not None and len(times)):
                fail(file, "time", f"view {view}: some entries have a time stamp and others not")
            times = np.array([])
            continue
        view_times = np.array(view_times)
        if times is None:
            times = view_times
        elif not np.allclose(times, view_times, atol=1e-6):
            fail(file, "time", f"view {view} has time stamps different from view {min(per_view)}")
    for view in sorted(set(plates) - set(per_view)):
        log.warning("%s: background r_%d_-1.png of a view without frames is ignored", file, view)
    if ray_masks:
        log.warning(
            "%s: ray masks (r_<view>_-2.png) of views %s are read but not used: sgdr's losses use every "
            "pixel, PAC-NeRF leaves out the rays whose alpha > 50",
            file,
            sorted(ray_masks),
        )
    recorded = {}
    if times is not None and len(times) > 1:
        steps = np.diff(times)
        if np.any(steps <= 0) or not np.allclose(steps, steps[0], rtol=1e-3):
            fail(file, "time", "time stamps must increase by a constant step")
        recorded["fps"] = 1.0 / float(steps[0])
    meta, source, checks = scene_meta(root, "pac_nerf", n_frames, recorded, scene_file=scene_file, **scene)
    check_against_config(root, source, checks, cameras)
    if plates:
        log.info(
            "%s: frames of views %s are matted against their background plates (sgdr.data.matte)",
            root,
            sorted(set(plates) & set(per_view)),
        )
    return finish(
        root,
        "pac_nerf",
        cameras,
        paths,
        n_frames,
        meta,
        source,
        alpha_mode="straight",
        backgrounds=backgrounds if plates else None,
    )


def write_rgb(path: Path, rgb):
    """Write [H, W, 3] float in [0, 1] as an 8-bit RGB PNG."""

    path.parent.mkdir(parents=True, exist_ok=True)
    iio.imwrite(path, np.clip(np.rint(np.asarray(rgb) * 255.0), 0, 255).astype(np.uint8))


def write_pac_nerf(root, cameras: list[Camera], images, fps: float | None, backgrounds=None) -> Path:
    """Write the PAC-NeRF layout (fixtures, export). images[view][frame] -> [H, W, 4] premultiplied
    (the PNGs hold straight alpha); fps None writes no time stamps (as released). With
    backgrounds ([view] -> [H, W, 3] plates), frames are written as released: RGB composited
    over the plate, plus r_<view>_-1.png."""
    root = Path(root)
    entries = []
    for v, cam in enumerate(cameras):
        camera = {"c2w": cam.c2w_opengl[:3].tolist(), "intrinsic": cam.K.tolist()}
        if backgrounds is not None:
            rel = f"./data/r_{v}_-1.png"
            write_rgb(root / rel, backgrounds[v])
            entries.append({"file_path": rel, **camera})
        for f, im in enumerate(images[v]):
            rel = f"./data/r_{v}_{f}.png"
            im = np.asarray(im, dtype=np.float64)
            if backgrounds is not None:  # as released: 3-channel RGB over the background
                write_rgb(root / rel, im[..., :3] + np.asarray(backgrounds[v]) * (1 - im[..., 3:4]))
            else:
                write_straight_rgba(root / rel, im)
            entries.append({"file_path": rel, **({"time": f / float(fps)} if fps else {}), **camera})
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
