"""A run's human-readable outputs: side-by-side videos, loss and stiffness plots, PLYs.

Everything here is NumPy + imageio/ffmpeg + matplotlib (Agg, no display) and only writes
files; nothing is differentiable. Images are `np.ndarray [H, W, 3|4]` float in [0, 1] or
uint8; points are `np.ndarray [N, 3]` world, scene units.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np


# ------------------------------------------------------------------------------ images
def to_uint8(img: np.ndarray) -> np.ndarray:
    """[H, W, 3|4] float in [0, 1] (or uint8) -> [H, W, 3] uint8 (alpha dropped)."""
    a = np.asarray(img)
    if a.dtype != np.uint8:
        a = (np.clip(a, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
    return a[..., :3]


def tile(images: Sequence[np.ndarray], cols: int | None = None, pad: int = 2) -> np.ndarray:
    """Tile equally sized [H, W, 3] uint8 images row-major into a grid with `pad` black pixels
    between cells; `cols` defaults to ceil(sqrt(n))."""
    if not images:
        raise ValueError("tile: no images")
    imgs = [to_uint8(i) for i in images]
    h, w = imgs[0].shape[:2]
    if any(i.shape[:2] != (h, w) for i in imgs):
        raise ValueError("tile: images differ in size")
    n = len(imgs)
    cols = cols or math.ceil(math.sqrt(n))
    rows = math.ceil(n / cols)
    out = np.zeros((rows * h + (rows - 1) * pad, cols * w + (cols - 1) * pad, 3), np.uint8)
    for k, img in enumerate(imgs):
        r, c = divmod(k, cols)
        out[r * (h + pad) : r * (h + pad) + h, c * (w + pad) : c * (w + pad) + w] = img
    return out


def side_by_side(
    gt_views: Sequence[np.ndarray], pred_views: Sequence[np.ndarray], cols: int | None = None
) -> np.ndarray:
    """One video frame: every view as a [ground truth | prediction] pair, pairs tiled."""
    if len(gt_views) != len(pred_views):
        raise ValueError(f"side_by_side: {len(gt_views)} ground-truth views vs {len(pred_views)} predicted")
    pairs = [tile([g, p], cols=2, pad=1) for g, p in zip(gt_views, pred_views)]
    return tile(pairs, cols=cols, pad=4)


def write_video(path, frames: Sequence[np.ndarray], fps: float) -> Path:
    """Write frames ([H, W, 3] uint8 or float) as an H.264 mp4 through imageio-ffmpeg.

    Frames are padded with black to even sizes (yuv420p needs them); nothing is rescaled.
    """
    import imageio.v2 as imageio

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with imageio.get_writer(str(path), fps=float(fps), codec="libx264", macro_block_size=1, quality=8) as w:
        for f in frames:
            f = to_uint8(f)
            h, wd = f.shape[:2]
            f = np.pad(f, ((0, h % 2), (0, wd % 2), (0, 0)))
            w.append_data(f)
    return path


# ------------------------------------------------------------------------------ plots


def _save_figure(fig, path) -> Path:
    """Lay out, write (creating the folder) and close a matplotlib figure; return its path."""
    import matplotlib.pyplot as plt

    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def plot_losses(path, curves: Mapping[str, Sequence[float]], title: str = "losses") -> Path:
    """One line per named curve against its step index (log y when all values are > 0)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    positive = True
    for name, ys in curves.items():
        ys = np.asarray(ys, dtype=float)
        if ys.size:
            ax.plot(np.arange(ys.size), ys, label=name)
            positive &= bool(np.all(ys[np.isfinite(ys)] > 0))
    if positive:
        ax.set_yscale("log")
    ax.set_xlabel("step")
    ax.set_ylabel("loss")
    ax.set_title(title)
    ax.legend()
    return _save_figure(fig, path)


def plot_stiffness(path, anchors: np.ndarray, log10_k: np.ndarray, up: np.ndarray | None = None) -> Path:
    """The identified stiffness field: anchors [N_A, 3] coloured by log10 k_i [N_A] in 3D,
    and the histogram of log10 k_i."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    anchors = np.asarray(anchors, float)
    log10_k = np.asarray(log10_k, float).reshape(-1)
    fig = plt.figure(figsize=(10, 4))
    ax = fig.add_subplot(1, 2, 1, projection="3d")
    sc = ax.scatter(anchors[:, 0], anchors[:, 1], anchors[:, 2], c=log10_k, cmap="viridis", s=6)
    fig.colorbar(sc, ax=ax, label="log10 k_i")
    ax.set_title("stiffness field")
    ax2 = fig.add_subplot(1, 2, 2)
    ax2.hist(log10_k, bins=30)
    ax2.set_xlabel("log10 k_i")
    ax2.set_ylabel("anchors")
    return _save_figure(fig, path)


# ------------------------------------------------------------------------------ PLY
def write_points_ply(path, points: np.ndarray, colors: np.ndarray | None = None) -> Path:
    """Binary little-endian PLY point cloud: float32 x, y, z (+ uint8 red, green, blue).

    points [N, 3] scene units; colors [N, 3] in [0, 1] or uint8.
    """
    p = np.asarray(points, dtype="<f4").reshape(-1, 3)
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    header = ["ply", "format binary_little_endian 1.0", f"element vertex {len(p)}"]
    header += ["property float x", "property float y", "property float z"]
    if colors is not None:
        c = to_uint8(np.asarray(colors).reshape(-1, 1, 3)).reshape(-1, 3)
        if len(c) != len(p):
            raise ValueError(f"write_points_ply {path}: {len(c)} colours for {len(p)} points")
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
        header += ["property uchar red", "property uchar green", "property uchar blue"]
    header.append("end_header")
    rec = np.empty(len(p), dtype=fields)
    rec["x"], rec["y"], rec["z"] = p[:, 0], p[:, 1], p[:, 2]
    if colors is not None:
        rec["red"], rec["green"], rec["blue"] = c[:, 0], c[:, 1], c[:, 2]
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as f:
        f.write(("\n".join(header) + "\n").encode("ascii"))
        f.write(rec.tobytes())
    return path


def read_points_ply(path) -> np.ndarray:
    """Read the xyz of a PLY point cloud written by `write_points_ply` (or any PLY trimesh reads)."""
    import trimesh

    cloud = trimesh.load(str(path), process=False)
    return np.asarray(cloud.vertices, dtype=np.float64)


def write_frame_plys(folder, frames: Sequence[np.ndarray], prefix: str, colors: np.ndarray | None = None) -> list[Path]:
    """One PLY per frame: `folder/<prefix>_<frame:03d>.ply` from frames[t] [N, 3]."""
    folder = Path(folder)
    return [write_points_ply(folder / f"{prefix}_{t:03d}.ply", pts, colors) for t, pts in enumerate(frames)]
