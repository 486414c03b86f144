"""sgdr's sequence folder format: one module writes it and reads it.

Layout of a sequence folder (all paths relative to the folder):

```
sequence.json              fps, n_frames, n_fit, hit_frame, ground {point, normal}, gravity,
                           views [{name, K [3,3], w2c [4,4] OpenCV, width, height}]
images/<view>/<fff>.png    RGBA, 8 bit, alpha = object mask, RGB composited on black
gt/particles_<fff>.npy     optional: [P, 3] float32 world particle positions of frame fff
gt/params.json             optional: the generator's true parameters (material, v0, ...)
gt/effects.json            optional: the injected effects and their magnitudes
```

`load_sequence(path)` (`sgdr.data.layouts`) reads this layout and, through `sgdr.data.foreign`
and `sgdr.data.real_capture`, the Spring-Gaus (`camera.json`, real captures) and PAC-NeRF
(`all_data.json`) layouts. Every missing file, missing field, wrong shape, inconsistent image
size or frame count raises `SequenceError` naming the file and the field; nothing is skipped
silently. Image headers are checked at load time (size and channel count), pixels are read on
demand by `Sequence.image`.

One RGBA convention everywhere: `Sequence.image` returns RGB composited on black (premultiplied
by alpha) and alpha = the object's mask, whatever the layout stores. sgdr's own PNGs already hold
RGB on black (`alpha_mode="premultiplied"`); PNGs of the foreign layouts hold straight alpha, as
PNG defines it and as the official loaders read it (they composite rgb x alpha on black):
`alpha_mode="straight"`. Where the mask is not the image's alpha, it comes from a separate mask
file (`mask_paths`: Spring-Gaus real captures) or from matting the image against a clean
background plate of its view (`backgrounds`: PAC-NeRF's `r_<view>_-1.png`; `sgdr.data.matte`).
An image without alpha and without either source is opaque (alpha 1), as the official
Spring-Gaus loader reads a 3-channel PNG.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from sgdr.cameras import Camera, CameraError
from PIL import Image
from tqdm import tqdm
import imageio.v3 as iio

SEQUENCE_FILE = "sequence.json"
FORMAT_NAME = "sgdr-sequence"
FORMAT_VERSION = 1


class SequenceError(ValueError):
    """An invalid or incomplete sequence; the message names the file and the field."""


def fail(file, field_name: str, why: str):
    """Raise a `SequenceError` for `field_name` of `file`."""
    raise SequenceError(f"{file}: field {field_name!r}: {why}")


@dataclass
class Sequence:
    """A multi-view video of one object with its scene data (read through `load_sequence`).

    Frames 0..n_fit-1 are fit frames, n_fit..n_frames-1 the future. Cameras follow OpenCV
    (`sgdr.cameras`); their names are the view folder names. World units are scene units
    (the benchmark lives in a unit cube), time in seconds.
    """

    root: Path  # the sequence folder
    fps: float  # frames per second
    n_frames: int  # frames per view
    n_fit: int  # frames 0..n_fit-1 are for fitting, the rest are the future
    cameras: list[Camera]  # one per view, names = view folder names
    ground_point: np.ndarray  # [3] a point on the ground plane, world
    ground_normal: np.ndarray  # [3] unit normal, pointing up (away from the ground)
    gravity: np.ndarray  # [3] gravitational acceleration, scene units / s²
    hit_frame: int  # first frame in which the object touches the ground
    image_paths: list[list[Path]] = field(repr=False, default_factory=list)  # [view][frame]
    layout: str = "sgdr"  # "sgdr" | "spring_gaus" | "pac_nerf" | "spring_gaus_real"
    gt_dir: Path | None = None  # ground-truth folder (sgdr layout with gt/), else None
    alpha_mode: str = "premultiplied"  # how the files store RGB: "premultiplied" (on black) | "straight"
    mask_paths: list[list[Path] | None] | None = field(repr=False, default=None)  # [view][frame] mask files, else None
    backgrounds: list[Path | None] | None = field(repr=False, default=None)  # [view] clean plates to matte against
    mask_only: bool = False  # the targets are the masks themselves (RGB = mask; Spring-Gaus IMG_IS_MASK)
    resize: bool = False  # an image of another size than its camera is resized to it (the mask's size)
    matte_threshold: float = 0.1  # matting against `backgrounds`: chromaticity distance of the object (sgdr.data.matte)
    extras: dict = field(repr=False, default_factory=dict)  # layout-specific data (e.g. a real capture's static scan)

    @property
    def n_views(self) -> int:
        return len(self.cameras)

    @property
    def dt_frame(self) -> float:
        """Seconds between frames."""
        return 1.0 / self.fps

    def image(self, view_index: int, frame: int) -> np.ndarray:
        """[H, W, 4] float32 in [0, 1]: RGB on black and alpha = mask, of one view and frame."""
        if not 0 <= view_index < self.n_views:
            raise IndexError(f"{self.root}: view {view_index} outside 0..{self.n_views - 1}")
        if not 0 <= frame < self.n_frames:
            raise IndexError(f"{self.root}: frame {frame} outside 0..{self.n_frames - 1}")
        cam = self.cameras[view_index]
        path = self.image_paths[view_index][frame]
        im = read_pixels(path, *((None, None) if self.resize else (cam.width, cam.height)))
        if im.shape[:2] != (cam.height, cam.width):
            import cv2

            im = cv2.resize(im, (cam.width, cam.height), interpolation=cv2.INTER_AREA).reshape(
                cam.height, cam.width, im.shape[2]
            )
        rgb, alpha = split_channels(im)
        straight = self.alpha_mode == "straight"
        if self.mask_paths is not None and self.mask_paths[view_index] is not None:
            alpha, straight = read_mask(self.mask_paths[view_index][frame], cam.width, cam.height), True
        elif self.backgrounds is not None and self.backgrounds[view_index] is not None:
            from sgdr.data.matte import matte

            plate, _ = split_channels(read_pixels(self.backgrounds[view_index], cam.width, cam.height))
            alpha = matte(rgb, plate, self.matte_threshold)
            # the compositing equation I = F + (1 - a) B solved for the premultiplied foreground F
            rgb = np.clip(rgb - (1.0 - alpha[..., None]) * plate, 0.0, alpha[..., None])
        if alpha is None:
            alpha = np.ones(rgb.shape[:2], np.float32)
        if self.mask_only:
            rgb = np.repeat(alpha[..., None], 3, axis=-1)
        elif straight:
            rgb = rgb * alpha[..., None]
        return np.concatenate([rgb, alpha[..., None]], axis=-1).astype(np.float32)

    def check_images(self, progress: bool = False) -> None:
        """Decode every image of every view and frame once (a `SequenceError` naming the first
        file that is missing, corrupt or of the wrong size), so a bad file fails before any work
        instead of inside a stage minutes later. About 3 ms per 128 px image."""

        pairs = [(v, f) for v in range(self.n_views) for f in range(self.n_frames)]
        for v, f in tqdm(pairs, desc="checking images", unit="image", disable=not progress, leave=False):
            self.image(v, f)

    def gt_particles(self, frame: int) -> np.ndarray | None:
        """[P, 3] float32 ground-truth particle positions (world) of `frame`, or None."""
        if self.gt_dir is None:
            return None
        path = self.gt_dir / particles_name(frame)
        if not path.is_file():
            fail(path, "particles", f"missing ground-truth particles of frame {frame}")
        x = np.load(path)
        if x.ndim != 2 or x.shape[1] != 3:
            fail(path, "particles", f"expected shape [P, 3], got {x.shape}")
        return x

    def gt_params(self) -> dict | None:
        """The generator's true parameters (gt/params.json, with `effects` inside), or None."""
        if self.gt_dir is None:
            return None
        return read_json(self.gt_dir / "params.json")

    def gt_effects(self) -> dict | None:
        """The injected effects and their magnitudes (gt/effects.json), or None."""
        if self.gt_dir is None:
            return None
        return read_json(self.gt_dir / "effects.json")


# ---------------------------------------------------------------------------- small IO helpers
def particles_name(frame: int) -> str:
    return f"particles_{frame:03d}.npy"


def image_relpath(view: str, frame: int) -> Path:
    return Path("images") / view / f"{frame:03d}.png"


def read_json(path: Path):
    path = Path(path)
    if not path.is_file():
        fail(path, "<file>", "file is missing")
    try:
        return json.loads(path.read_text())
    except json.JSONDecodeError as e:
        fail(path, "<json>", f"not valid JSON ({e})")


def require(d: dict, key: str, file) -> object:
    if not isinstance(d, dict) or key not in d:
        fail(file, key, "missing field")
    return d[key]


def as_array(value, shape: tuple, file, field_name: str) -> np.ndarray:
    """`value` as float64 array of `shape`, else a SequenceError naming file and field."""
    try:
        a = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        fail(file, field_name, f"not a numeric array of shape {list(shape)}")
    if a.shape != shape:
        fail(file, field_name, f"expected shape {list(shape)}, got {list(a.shape)}")
    if not np.all(np.isfinite(a)):
        fail(file, field_name, "has non-finite entries")
    return a


def png_header(path: Path) -> tuple[int, int, int]:
    """(width, height, channels) of a PNG without decoding its pixels."""

    if not Path(path).is_file():
        fail(path, "<image>", "image file is missing")
    with Image.open(path) as im:
        channels = len(im.getbands())
        return im.width, im.height, channels


def check_image(path: Path, width: int, height: int, view_field: str, channels=(4,)) -> int:
    """Check an image's size and channel count from its header; returns the channel count."""
    w, h, c = png_header(path)
    if (w, h) != (width, height):
        fail(path, view_field, f"image is {w}x{h}, the camera says {width}x{height}")
    if c not in channels:
        want = "RGBA (alpha = mask)" if tuple(channels) == (4,) else f"{' or '.join(map(str, channels))} channels"
        fail(path, view_field, f"image has {c} channels, expected {want}")
    return c


def read_pixels(path: Path, width: int | None = None, height: int | None = None) -> np.ndarray:
    """[H, W, C] float32 in [0, 1] of an 8- or 16-bit image file (C = 1..4), size checked."""

    if not Path(path).is_file():
        fail(path, "<image>", "image file is missing")
    try:
        im = iio.imread(path)
    except Exception as exc:  # noqa: BLE001 - any decoder error: name the file
        fail(path, "<image>", f"cannot be decoded as an image ({type(exc).__name__}: {exc})")
    if im.ndim == 2:
        im = im[..., None]
    if im.ndim != 3 or not 1 <= im.shape[2] <= 4:
        fail(path, "<image>", f"expected [H, W, 1..4] pixels, got shape {list(im.shape)}")
    if width is not None and im.shape[:2] != (height, width):
        fail(path, "<image>", f"image is {im.shape[1]}x{im.shape[0]}, expected {width}x{height}")
    scale = 65535.0 if im.dtype == np.uint16 else 255.0
    return im.astype(np.float32) / np.float32(scale)


def split_channels(im: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """[H, W, C] -> (rgb [H, W, 3], alpha [H, W] or None): grey is repeated, a 2nd/4th channel is alpha."""
    c = im.shape[2]
    rgb = np.repeat(im[..., :1], 3, axis=-1) if c <= 2 else im[..., :3]
    alpha = im[..., c - 1] if c in (2, 4) else None
    return np.ascontiguousarray(rgb), alpha


def read_mask(path: Path, width: int, height: int) -> np.ndarray:
    """[H, W] float32 in [0, 1] of a mask file (grey, or the first channel / alpha of a colour one)."""
    im = read_pixels(path, width, height)
    return np.ascontiguousarray(im[..., 3] if im.shape[2] == 4 else im[..., 0])


def write_straight_rgba(path: Path, rgba: np.ndarray):
    """Write premultiplied [H, W, 4] (RGB on black) as a straight-alpha PNG (foreign layouts)."""
    rgba = np.asarray(rgba, dtype=np.float64)
    a = rgba[..., 3:4]
    rgb = np.where(a > 0, rgba[..., :3] / np.maximum(a, 1e-12), 0.0)
    write_rgba(path, np.concatenate([np.clip(rgb, 0.0, 1.0), a], axis=-1))


def write_rgba(path: Path, rgba: np.ndarray):
    """Write [H, W, 4] float in [0, 1] as an 8-bit RGBA PNG."""

    rgba = np.asarray(rgba)
    if rgba.ndim != 3 or rgba.shape[2] != 4:
        raise SequenceError(f"{path}: image must be [H, W, 4] RGBA, got {list(rgba.shape)}")
    path.parent.mkdir(parents=True, exist_ok=True)
    iio.imwrite(path, np.clip(np.rint(rgba * 255.0), 0, 255).astype(np.uint8))


def scene_fields(meta: dict, file) -> dict:
    """Validate and convert the scene fields shared by every layout's metadata."""
    fps = float(require(meta, "fps", file))
    if not fps > 0:
        fail(file, "fps", f"must be positive, got {fps}")
    ground = require(meta, "ground", file)
    point = as_array(require(ground, "point", file), (3,), file, "ground.point")
    normal = as_array(require(ground, "normal", file), (3,), file, "ground.normal")
    n = np.linalg.norm(normal)
    if n < 1e-9:
        fail(file, "ground.normal", "has zero length")
    gravity = as_array(require(meta, "gravity", file), (3,), file, "gravity")
    return {"fps": fps, "ground_point": point, "ground_normal": normal / n, "gravity": gravity}


def check_split(n_frames: int, n_fit: int, hit_frame: int, file):
    if n_frames <= 0:
        fail(file, "n_frames", f"must be positive, got {n_frames}")
    if not 0 < n_fit <= n_frames:
        fail(file, "n_fit", f"must be in 1..n_frames={n_frames}, got {n_fit}")
    if not 0 <= hit_frame < n_frames:
        fail(file, "hit_frame", f"must be in 0..{n_frames - 1}, got {hit_frame}")


# ---------------------------------------------------------------------------- sgdr layout
def read_sgdr(root: Path) -> Sequence:
    """Read and validate sgdr's own layout (see the module docstring)."""
    file = root / SEQUENCE_FILE
    meta = read_json(file)
    if not isinstance(meta, dict):
        fail(file, "<root>", "expected a JSON object")
    if meta.get("format", FORMAT_NAME) != FORMAT_NAME:
        fail(file, "format", f"expected {FORMAT_NAME!r}, got {meta.get('format')!r}")
    n_frames = int(require(meta, "n_frames", file))
    n_fit = int(require(meta, "n_fit", file))
    hit_frame = int(require(meta, "hit_frame", file))
    check_split(n_frames, n_fit, hit_frame, file)
    scene = scene_fields(meta, file)
    views = require(meta, "views", file)
    if not isinstance(views, list) or not views:
        fail(file, "views", "must be a non-empty list")
    cameras, paths = [], []
    for i, v in enumerate(views):
        where = f"views[{i}]"
        if not isinstance(v, dict):
            fail(file, where, "not a JSON object")
        for key in ("name", "K", "w2c", "width", "height"):
            if key not in v:
                fail(file, f"{where}.{key}", "missing field")
        name = str(v["name"])
        K = as_array(v["K"], (3, 3), file, f"{where}.K")
        w2c = as_array(v["w2c"], (4, 4), file, f"{where}.w2c")
        try:
            cam = Camera.from_w2c(w2c, K, int(v["width"]), int(v["height"]), name)
        except CameraError as e:
            fail(file, where, str(e))
        cameras.append(cam)
        view_paths = []
        for f in range(n_frames):
            p = root / image_relpath(name, f)
            check_image(p, cam.width, cam.height, f"{where} ({name}) frame {f}")
            view_paths.append(p)
        extra = root / image_relpath(name, n_frames)
        if extra.exists():
            fail(extra, "n_frames", f"view {name!r} has more images than n_frames={n_frames}")
        paths.append(view_paths)
    if len({c.name for c in cameras}) != len(cameras):
        fail(file, "views", "view names must be unique")
    gt_dir = root / "gt"
    if gt_dir.is_dir():
        for f in range(n_frames):
            if not (gt_dir / particles_name(f)).is_file():
                fail(gt_dir / particles_name(f), "particles", f"missing for frame {f}")
        for name in ("params.json", "effects.json"):
            read_json(gt_dir / name)
    else:
        gt_dir = None
    return Sequence(
        root=root,
        n_frames=n_frames,
        n_fit=n_fit,
        cameras=cameras,
        hit_frame=hit_frame,
        image_paths=paths,
        layout="sgdr",
        gt_dir=gt_dir,
        **scene,
    )


def write_sequence(
    root,
    *,
    cameras: list[Camera],
    images,
    fps: float,
    n_fit: int,
    hit_frame: int,
    ground_point,
    ground_normal,
    gravity,
    gt_particles=None,
    gt_params: dict | None = None,
    gt_effects: dict | None = None,
) -> Path:
    """Write a sequence in sgdr's layout; `sequence.json` is written last (marks completion).

    images: indexable as images[view][frame] -> [H, W, 4] float in [0, 1] (alpha = mask),
      e.g. an array [V, F, H, W, 4].
    gt_particles: optional list over frames of [P, 3] world positions; with it, gt_params and
      gt_effects (dicts, may be empty) are written to gt/params.json and gt/effects.json.
    Returns the sequence folder.
    """
    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    (root / SEQUENCE_FILE).unlink(missing_ok=True)
    n_views = len(cameras)
    if len(images) != n_views:
        raise SequenceError(f"{root}: images has {len(images)} views, cameras {n_views}")
    n_frames = len(images[0])
    for v, cam in enumerate(cameras):
        if len(images[v]) != n_frames:
            raise SequenceError(f"{root}: view {cam.name!r} has {len(images[v])} frames, not {n_frames}")
        for f in range(n_frames):
            im = np.asarray(images[v][f])
            if im.shape != (cam.height, cam.width, 4):
                raise SequenceError(
                    f"{root}: image of view {cam.name!r} frame {f} has shape {list(im.shape)},"
                    f" camera needs [{cam.height}, {cam.width}, 4]"
                )
            write_rgba(root / image_relpath(cam.name, f), im)
    if gt_particles is not None:
        gt = root / "gt"
        gt.mkdir(exist_ok=True)
        if len(gt_particles) != n_frames:
            raise SequenceError(f"{root}: gt_particles has {len(gt_particles)} frames, not {n_frames}")
        for f, x in enumerate(gt_particles):
            np.save(gt / particles_name(f), np.asarray(x, dtype=np.float32))
        (gt / "params.json").write_text(json.dumps(gt_params or {}, indent=2))
        (gt / "effects.json").write_text(json.dumps(gt_effects or {}, indent=2))
    normal = np.asarray(ground_normal, dtype=np.float64)
    meta = {
        "format": FORMAT_NAME,
        "version": FORMAT_VERSION,
        "fps": float(fps),
        "n_frames": int(n_frames),
        "n_fit": int(n_fit),
        "hit_frame": int(hit_frame),
        "ground": {
            "point": np.asarray(ground_point, dtype=np.float64).tolist(),
            "normal": (normal / np.linalg.norm(normal)).tolist(),
        },
        "gravity": np.asarray(gravity, dtype=np.float64).tolist(),
        "views": [cam.to_dict() for cam in cameras],
    }
    check_split(meta["n_frames"], meta["n_fit"], meta["hit_frame"], root / SEQUENCE_FILE)
    (root / SEQUENCE_FILE).write_text(json.dumps(meta, indent=2))
    return root
