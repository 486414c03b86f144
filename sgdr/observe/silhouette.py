"""Silhouettes against projected points: the observed silhouettes' distance maps (`Observation`,
`observation`), the distance of projected Gaussian centres to them (`discrepancy`) and the
projection of anchors to centres (`CentreMap`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import distance_transform_edt, map_coordinates

from sgdr.skin.binding import idw_weights


@dataclass
class Observation:
    """The silhouettes a likelihood compares with, per used view and frame."""

    cameras: list  # [V] sgdr.cameras.Camera of the used views
    frames: np.ndarray  # [F] frame indices used
    dist_out: np.ndarray  # [V, F, H, W] float32 distance to the silhouette (0 inside), pixels
    mask_points: list  # [V][F] -> [K, 2] float (u, v) pixel coordinates of sampled silhouette pixels


def observation(seq, views, frames, n_mask_points: int, seed: int = 0) -> Observation:
    """Distance transforms and sampled silhouette pixels of `seq`'s views x frames (alpha > 0.5).
    Raises ValueError naming the view and frame of an empty silhouette."""

    rng = np.random.default_rng(seed)
    cams = [seq.cameras[v] for v in views]
    h, w = cams[0].height, cams[0].width
    if any((c.height, c.width) != (h, w) for c in cams):
        raise ValueError("posterior: the used views must share one image size")
    dist = np.zeros((len(views), len(frames), h, w), np.float32)
    points = []
    for i, v in enumerate(views):
        row = []
        for j, f in enumerate(frames):
            mask = seq.image(v, int(f))[..., 3] > 0.5
            if not mask.any():
                raise ValueError(f"{seq.root}: view {seq.cameras[v].name} frame {f} has an empty silhouette")
            dist[i, j] = distance_transform_edt(~mask)
            rr, cc = np.nonzero(mask)
            pick = rng.choice(rr.size, size=min(int(n_mask_points), rr.size), replace=False)
            row.append(np.stack([cc[pick] + 0.5, rr[pick] + 0.5], axis=1).astype(float))  # pixel centres
        points.append(row)
    return Observation(cams, np.asarray(frames, int), dist, points)


def _bilinear(img: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """img [H, W] at pixel coordinates (u, v) (pixel centres at integer + 0.5), clamped to the image."""

    return map_coordinates(img, [v.ravel() - 0.5, u.ravel() - 0.5], order=1, mode="nearest").reshape(u.shape)


def discrepancy(obs: Observation, centres: np.ndarray) -> np.ndarray:
    """D [S, V, F] pixels²: the symmetric silhouette Chamfer distance of each sample's projected
    centres. centres: [S, F, P, 3] world positions at `obs.frames` (NaN rows give NaN)."""
    s, nf, p, _ = centres.shape
    if nf != len(obs.frames):
        raise ValueError(f"discrepancy: centres have {nf} frames, the observation {len(obs.frames)}")
    out = np.zeros((s, len(obs.cameras), nf))
    for i, cam in enumerate(obs.cameras):
        uv, z = cam.project(centres.reshape(-1, 3))
        uv = uv.reshape(s, nf, p, 2)
        behind = (z <= 0).reshape(s, nf, p)
        for j in range(nf):
            d_out = _bilinear(obs.dist_out[i, j], uv[:, j, :, 0], uv[:, j, :, 1])
            # off the image the clamped transform underestimates: add the distance to the border
            off = np.maximum(0.0, -uv[:, j]) + np.maximum(0.0, uv[:, j] - [cam.width, cam.height])
            d_out = d_out + np.linalg.norm(off, axis=-1)
            d_out = np.where(behind[:, j], np.inf, d_out)
            outside = np.mean(d_out**2, axis=1)
            mp = obs.mask_points[i][j]  # [K, 2]
            d2 = ((mp[None, :, None, :] - uv[:, j, None, :, :]) ** 2).sum(-1)  # [S, K, P]
            coverage = np.mean(np.min(d2, axis=2), axis=1)
            out[:, i, j] = outside + coverage
    return out


class CentreMap:
    """Anchor positions -> a fixed subset of bound Gaussian centres (the asset's IDW binding in
    NumPy; linear in the anchors, so the subset is exact)."""

    def __init__(self, asset, n_points: int, seed: int = 0):
        cfg = asset.anchor_cfg
        rest = np.asarray(asset.rest_centres, float)
        idx = np.arange(rest.shape[0])
        if 0 < n_points < rest.shape[0]:
            idx = np.sort(np.random.default_rng(seed).choice(rest.shape[0], size=int(n_points), replace=False))
        self.rest = rest[idx]
        self.index, self.weight = idw_weights(self.rest, np.asarray(asset.anchors, float), cfg.n_b, cfg.p_b)
        self.anchors_rest = np.asarray(asset.anchors, float)
        if cfg.binding not in ("official", "displacement"):
            raise ValueError(f"posterior: anchors.binding={cfg.binding!r} has no NumPy form here")
        self.form = cfg.binding

    def __call__(self, positions: np.ndarray) -> np.ndarray:
        """[..., N_A, 3] -> [..., P, 3]."""
        x = positions if self.form == "official" else positions - self.anchors_rest
        c = np.einsum("pb,...pbk->...pk", self.weight, x[..., self.index, :])
        return c if self.form == "official" else c + self.rest
