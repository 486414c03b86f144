"""A run's human-readable outputs: side-by-side videos, loss, stiffness and metric plots, PLYs.

Everything here is NumPy + OpenCV (text) + imageio/ffmpeg + matplotlib (Agg, no display) and
only writes files; nothing is differentiable. Images are `np.ndarray [H, W, 3|4]` float in
[0, 1] or uint8; points are `np.ndarray [N, 3]` world, scene units. The HTML page that shows
them is `sgdr.report.html`.

Videos are made to be watched: `playback` slows them to a few frames per second, every
frame says which side is the ground truth and which the prediction, its number and whether it
is a fit or a future frame (`video_frame`), and `composite_ground` draws the sequence's ground
plane (a grey checkerboard) behind the object, so contact with the ground is visible.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path

import cv2
import imageio.v2 as imageio
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


def write_video(path, frames: Sequence[np.ndarray], fps: float) -> Path:
    """Write frames ([H, W, 3] uint8 or float) as an H.264 mp4 through imageio-ffmpeg.

    Frames are padded with black to even sizes (yuv420p needs them); nothing is rescaled.
    """

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with imageio.get_writer(str(path), fps=float(fps), codec="libx264", macro_block_size=1, quality=8) as w:
        for f in frames:
            f = to_uint8(f)
            h, wd = f.shape[:2]
            f = np.pad(f, ((0, h % 2), (0, wd % 2), (0, 0)))
            w.append_data(f)
    return path


def playback(n_frames: int, seconds: float = 5.0, lo: float = 2.0, hi: float = 6.0, min_seconds: float = 4.0):
    """(fps, repeat): play `n_frames` at about `seconds` in total (within [lo, hi] fps), each frame
    held `repeat` times so that even a short clip lasts at least `min_seconds`. The sequence's
    own rate (24 fps) shows a 30-frame clip in 1.25 s, too fast to see anything."""
    fps = float(np.clip(n_frames / seconds, lo, hi))
    return fps, max(1, math.ceil(min_seconds * fps / max(n_frames, 1)))


# ------------------------------------------------------------------------------ ground plane
def ground_image(camera, ground_point, ground_normal, square: float | None = None, samples: int = 3) -> np.ndarray:
    """What `camera` sees of the ground plane: [H, W, 3] float in [0, 1].

    A grey checkerboard of `square` scene units (default: 1/16 of the camera's distance to
    `ground_point`) where the ray through a pixel hits the plane in front of the camera, fading
    into the dark with distance; black where it does not (above the horizon, or the camera
    below the plane). Each pixel averages samples x samples rays (against moire far away).
    camera: `sgdr.cameras.Camera` (OpenCV, world-to-camera [R|t]).
    """
    p0 = np.asarray(ground_point, float).reshape(3)
    n = np.asarray(ground_normal, float).reshape(3)
    n = n / np.linalg.norm(n)
    R, t, K = camera.R, camera.t, camera.K
    centre = -R.T @ t
    d0 = float(np.linalg.norm(centre - p0))
    square = float(square) if square else d0 / 16.0
    height = float((centre - p0) @ n)
    e1 = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    offsets = (np.arange(samples) + 0.5) / samples
    grey = np.zeros((camera.height, camera.width))
    for du in offsets:
        for dv in offsets:
            u, v = np.meshgrid(np.arange(camera.width) + du, np.arange(camera.height) + dv)
            dirs = np.stack([u, v, np.ones_like(u)], axis=-1) @ np.linalg.inv(K).T @ R  # world rays R^T K^-1 [u, v, 1]
            denom = dirs @ n
            with np.errstate(divide="ignore", invalid="ignore"):
                s = -height / denom
            hit = (height > 0) & (denom < 0) & np.isfinite(s) & (s > 0)
            s = np.where(hit, s, 0.0)
            X = centre + s[..., None] * dirs - p0  # hit points relative to p0
            checker = (np.floor(X @ e1 / square) + np.floor(X @ e2 / square)) % 2
            tone = np.where(checker > 0, 0.55, 0.40)
            fade = np.exp(-np.linalg.norm(s[..., None] * dirs, axis=-1) / (4.0 * d0))  # far squares fade out
            grey += np.where(hit, 0.08 + (tone - 0.08) * fade, 0.0)
    return np.repeat((grey / samples**2)[..., None], 3, axis=-1)


def over_ground(rgb, alpha, ground: np.ndarray) -> np.ndarray:
    """rgb [H, W, 3] over black (premultiplied; float in [0, 1] or uint8) with its alpha [H, W]
    (float in [0, 1] or uint8) over a background `ground` [H, W, 3] float -> [H, W, 3] uint8."""
    fg = np.asarray(rgb)
    fg = fg.astype(np.float64) / 255.0 if fg.dtype == np.uint8 else fg.astype(np.float64)
    a = np.asarray(alpha)
    a = a.astype(np.float64) / 255.0 if a.dtype == np.uint8 else a.astype(np.float64)
    if fg.shape[:2] != a.shape[:2] or fg.shape[:2] != ground.shape[:2]:
        raise ValueError(
            f"over_ground: image {fg.shape[:2]}, alpha {a.shape[:2]}, ground {ground.shape[:2]} differ in size"
        )
    return to_uint8(fg[..., :3] + (1.0 - np.clip(a.reshape(a.shape[:2] + (1,)), 0.0, 1.0)) * ground)


def composite_ground(rgb, alpha, camera, ground_point, ground_normal, square: float | None = None) -> np.ndarray:
    """The ground plane seen by `camera` (`ground_image`) behind an image (`over_ground`):
    rgb [H, W, 3] over black with its alpha [H, W] -> [H, W, 3] uint8."""
    return over_ground(rgb, alpha, ground_image(camera, ground_point, ground_normal, square))


# ------------------------------------------------------------------------------ labelled video frames
FIT_COLOUR = (60, 180, 75)  # RGB of the "FIT" marker
FUTURE_COLOUR = (245, 130, 48)  # RGB of the "FUTURE" marker


def put_text(img: np.ndarray, text: str, org: tuple[int, int], colour=(255, 255, 255), max_width: int = 0) -> None:
    """Draw `text` with its baseline-left at org (x, y) into the uint8 image, in place; shrunk to
    `max_width` pixels when given."""

    scale = 0.45
    if max_width:
        w = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, 1)[0][0]
        scale = min(scale, scale * max_width / max(w, 1))
    cv2.putText(img, text, org, cv2.FONT_HERSHEY_SIMPLEX, scale, tuple(int(c) for c in colour), 1, cv2.LINE_AA)


def labelled_pair(gt: np.ndarray, pred: np.ndarray, min_height: int = 96, header: int = 16) -> np.ndarray:
    """[ground truth | prediction] of one view, each enlarged (nearest) to at least `min_height`
    pixels and titled in a `header`-pixel strip."""

    g, p = to_uint8(gt), to_uint8(pred)
    k = max(1, math.ceil(min_height / g.shape[0]))
    if k > 1:
        g = cv2.resize(g, (g.shape[1] * k, g.shape[0] * k), interpolation=cv2.INTER_NEAREST)
        p = cv2.resize(p, (p.shape[1] * k, p.shape[0] * k), interpolation=cv2.INTER_NEAREST)
    h, w = g.shape[:2]
    out = np.full((header + h, 2 * w + 1, 3), 30, np.uint8)
    out[header:, :w], out[header:, w + 1 :] = g, p
    put_text(out, "ground truth", (3, header - 4), max_width=w - 6)
    put_text(out, "prediction", (w + 4, header - 4), max_width=w - 6)
    return out


def video_frame(
    gt_views: Sequence[np.ndarray], pred_views: Sequence[np.ndarray], frame: int, n_frames: int, n_fit: int
) -> np.ndarray:
    """One labelled video frame: every view as a titled [ground truth | prediction] pair, pairs
    tiled, under a banner with "frame f/last" and a colour-coded FIT or FUTURE marker."""
    if len(gt_views) != len(pred_views):
        raise ValueError(f"video_frame: {len(gt_views)} ground-truth views vs {len(pred_views)} predicted")
    grid = tile([labelled_pair(g, p) for g, p in zip(gt_views, pred_views)], pad=4)
    banner = np.zeros((26, grid.shape[1], 3), np.uint8)
    put_text(banner, f"frame {frame}/{n_frames - 1}", (6, 18))
    fit = frame < n_fit
    marker = "FIT" if fit else "FUTURE"
    x = 110
    banner[3:23, x - 4 : x + (34 if fit else 64)] = FIT_COLOUR if fit else FUTURE_COLOUR
    put_text(banner, marker, (x, 18), (0, 0, 0))
    put_text(banner, "left: ground truth, right: prediction", (x + 80, 18), max_width=max(grid.shape[1] - x - 86, 1))
    return np.concatenate([banner, grid], axis=0)


# ------------------------------------------------------------------------------ plots


def save_figure(fig, path) -> Path:
    """Lay out, write (creating the folder) and close a matplotlib figure; return its path."""
    import matplotlib.pyplot as plt

    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _values(ys) -> np.ndarray:
    """A list with None entries (strict-JSON gaps) -> float array with NaN gaps."""
    return np.array([np.nan if y is None else float(y) for y in ys], dtype=float)


def plot_losses(path, curves: Mapping[str, Sequence[float]], xlabels: Mapping[str, str] | None = None) -> Path:
    """One panel per named curve, each against its own step index and x label (`xlabels[name]`,
    default "step"): refine steps, v0 steps and dynamic passes are different things. Log y when
    all of a curve's values are > 0."""
    plt = pyplot()
    curves = {k: _values(v) for k, v in curves.items() if len(v)}
    if not curves:
        raise ValueError(f"plot_losses {path}: no curve has any value")
    fig, axes = plt.subplots(1, len(curves), figsize=(4.2 * len(curves), 3.4), squeeze=False)
    for ax, (name, ys) in zip(axes[0], curves.items()):
        ax.plot(np.arange(ys.size), ys, marker="o" if ys.size <= 30 else None, markersize=3)
        finite = ys[np.isfinite(ys)]
        if finite.size and np.all(finite > 0):
            ax.set_yscale("log")
        ax.set_xlabel((xlabels or {}).get(name, "step"))
        ax.set_ylabel("loss")
        ax.set_title(name)
        ax.grid(alpha=0.3)
    return save_figure(fig, path)


def plot_stiffness(path, anchors: np.ndarray, log10_k: np.ndarray, k_range: tuple[float, float] | None = None) -> Path:
    """The identified stiffness field: anchors [N_A, 3] (scene units) coloured by log10 k_i [N_A]
    in 3D, and the histogram of log10 k_i with the allowed range `k_range` (the clamp) marked."""
    plt = pyplot()
    anchors = np.asarray(anchors, float)
    log10_k = np.asarray(log10_k, float).reshape(-1)
    fig = plt.figure(figsize=(11, 4.4))
    ax = fig.add_subplot(1, 2, 1, projection="3d")
    sc = ax.scatter(anchors[:, 0], anchors[:, 1], anchors[:, 2], c=log10_k, cmap="viridis", s=8)
    fig.colorbar(sc, ax=ax, label="log10 k_i (spring stiffness)", shrink=0.8, pad=0.12)
    ax.set_xlabel("x (scene units)")
    ax.set_ylabel("y (scene units)")
    ax.set_zlabel("z (scene units)")
    ax.set_title("stiffness per anchor")
    ax2 = fig.add_subplot(1, 2, 2)
    ax2.hist(log10_k, bins=30, color="tab:blue")
    ax2.set_xlabel("log10 k_i")
    ax2.set_ylabel("number of anchors")
    title = "distribution of log10 k_i"
    if k_range is not None:
        lo, hi = map(float, k_range)
        title += f" (allowed range [{lo:g}, {hi:g}])"
        span = max(float(np.ptp(log10_k)), 0.1)
        for bound in (lo, hi):  # draw a bound when it is near the values (else it squeezes the histogram)
            if log10_k.min() - span <= bound <= log10_k.max() + span:
                ax2.axvline(bound, color="tab:red", linestyle="--", label=f"clamp bound {bound:g}")
        if ax2.get_legend_handles_labels()[0]:
            ax2.legend()
    ax2.set_title(title)
    return save_figure(fig, path)


def plot_search(path, search: dict) -> Path:
    """The global search's landscape: every candidate's rollout loss against each searched
    parameter (one panel each), coloured by CMA-ES generation; the candidates that fit about as
    well as the best (`landscape.equivalent`) ringed. `search`: dynamics.json's "search"."""
    plt = pyplot()
    names = list(search["names"])
    cand = np.asarray(search["candidates"], float).reshape(-1, len(names))
    loss = _values(search["losses"])
    gen = np.asarray(search["generation"], float)
    if cand.shape[0] == 0:
        raise ValueError(f"plot_search {path}: no candidates")
    equivalent = (search.get("landscape") or {}).get("equivalent") or []
    fig, axes = plt.subplots(1, len(names), figsize=(3.8 * len(names), 3.4), squeeze=False)
    for i, (ax, name) in enumerate(zip(axes[0], names)):
        sc = ax.scatter(cand[:, i], loss, c=gen, cmap="viridis", s=14)
        if equivalent:
            ax.scatter(cand[equivalent, i], loss[equivalent], s=80, facecolors="none", edgecolors="tab:red")
        ax.set_xlabel(name)
        ax.set_ylabel("rollout loss (all fit frames, all views)")
        ax.set_yscale("log")
        ax.grid(alpha=0.3)
    fig.colorbar(sc, ax=axes[0][-1], label="generation")
    return save_figure(fig, path)


def plot_metric_curves(path, per_frame: Mapping, n_fit: int) -> Path:
    """Per-frame scores, model against the physics-free baselines, fit | future marked.

    per_frame: `evaluate_prediction`'s lists ("cd", "emd", "psnr", with None where a score
    does not exist) and {"baseline_cd": {variant: [per frame]}}. One panel per score that has
    any value; raises when none has.
    """
    plt = pyplot()
    panels = []
    baselines = per_frame.get("baseline_cd", {})
    if any(y is not None for y in per_frame.get("cd", [])):
        panels.append(("Chamfer distance x1e3 (lower is better)", "cd", baselines))
    if any(y is not None for y in per_frame.get("emd", [])):
        panels.append(("EMD (lower is better)", "emd", {}))
    if any(y is not None for y in per_frame.get("psnr", [])):
        panels.append(("image PSNR, dB (higher is better)", "psnr", {}))
    if not panels:
        raise ValueError(f"plot_metric_curves {path}: no per-frame score has a value")
    fig, axes = plt.subplots(1, len(panels), figsize=(4.6 * len(panels), 3.6), squeeze=False)
    for ax, (title, key, base) in zip(axes[0], panels):
        ys = _values(per_frame[key])
        ax.plot(np.arange(ys.size), ys, marker="o", markersize=3, color="black", label="model")
        for name, vals in base.items():
            b = _values(vals)
            if np.isfinite(b).any():
                ax.plot(np.arange(b.size), b, marker=".", linestyle="--", label=f"baseline: {name.replace('_', ' ')}")
        ax.axvline(n_fit - 0.5, color="grey", linestyle=":")
        ax.text(n_fit - 0.5, 1.0, " fit | future", transform=ax.get_xaxis_transform(), va="top", fontsize=8)
        ax.set_xlabel("frame")
        ax.set_title(title, fontsize=10)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    return save_figure(fig, path)


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
