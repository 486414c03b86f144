"""How a diagnosis measures a rollout against the images (`diagnose.discrepancy`, `MEASURES`).

- `render` (default): the asset's Gaussians bound to the rollout's anchors are rendered by the
  pipeline's own splatting renderer into every used view and frame, and compared with the
  sequence's images by the absolute difference of premultiplied RGB and alpha (the pipeline's
  image loss, L1), summed over the image and divided by the observed silhouette's area (so an
  object that fills fewer pixels, further away, does not look better fitted). Images larger than
  `diagnose.max_image_size` are compared at a lower resolution (block means, the cameras'
  intrinsics scaled alike): at the small preset 64 instead of 128 pixels, 4x fewer to render. A rollout with the true parameters of a twin scores the
  images' quantisation only, so the fitted value of an extension has no bias from the measure;
  colour sees what a silhouette cannot (a spin about the view axis, where the pattern moves).
- `points`: the posterior's silhouette Chamfer distance between the masks and a subset of the
  projected Gaussian centres (`sgdr.observe.silhouette.discrepancy`, pixels²), about 50 times
  cheaper. Centres are not silhouettes: on twins its minimum lies off the truth (for a
  plasticity twin with yield strain 0.005 at 32 px the points measure preferred 0.002), and its
  floor (the centres' representation error) dilutes the gains.

Each measure is a pair (observation builder, scorer): `observe(seq, views, frames, dc, seed)`
once per view set, then `score(obs, positions [T, N_A, 3]) -> [V, F]` per rollout.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sgdr.backend import ad
from sgdr.observe.images import block_mean, downscale_factor, downscaled
from sgdr.observe.silhouette import CentreMap, discrepancy, observation
from sgdr.registry import Registry
from sgdr.render.images import posed, render_rgba_numpy


@dataclass
class ImageObservation:
    cameras: list  # [V] sgdr.cameras.Camera
    frames: np.ndarray  # [F] frame indices
    images: np.ndarray  # [V, F, H, W, 4] float32: premultiplied RGB and alpha in [0, 1]


@dataclass(frozen=True)
class Measure:
    observe: object  # (seq, views, frames, diagnose cfg, seed) -> observation
    scorer: object  # (asset, diagnose cfg, render cfg, seed) -> (observation, positions) -> [V, F]
    unit: str


def _observe_images(seq, views, frames, dc, seed):
    k = downscale_factor(seq.cameras[views[0]].width, seq.cameras[views[0]].height, dc.max_image_size)
    cams = [downscaled(seq.cameras[v], k) for v in views]
    images = [[block_mean(seq.image(v, int(f)), k) for f in frames] for v in views]
    return ImageObservation(cams, np.asarray(frames, int), np.asarray(images, np.float32))


class RenderScorer:
    """Anchor positions -> renders of the bound Gaussians -> mean |render - image| per view-frame."""

    def __init__(self, asset, render_cfg):
        _, self.binding = asset.build()
        self.gaussians = asset.gaussians.detach()
        self.render_cfg = render_cfg

    def __call__(self, obs: ImageObservation, positions: np.ndarray) -> np.ndarray:
        import drjit as dr

        t = ad()
        out = np.zeros((len(obs.cameras), len(obs.frames)))
        with dr.suspend_grad():
            for j, f in enumerate(obs.frames):
                x = np.asarray(positions[int(f)], np.float32)
                g = posed(self.gaussians, self.binding.apply(t.Array3f(*x.T)))
                for i, cam in enumerate(obs.cameras):
                    diff = np.abs(render_rgba_numpy(g, cam, self.render_cfg) - obs.images[i, j]).sum()
                    out[i, j] = float(diff) / max(float(obs.images[i, j, ..., 3].sum()), 1.0)
        return out


def _render_scorer(asset, dc, render_cfg, seed):
    return RenderScorer(asset, render_cfg)


def _observe_points(seq, views, frames, dc, seed):
    return observation(seq, views, frames, dc.n_mask_points, seed=seed)


def _points_scorer(asset, dc, render_cfg, seed):
    centre_map = CentreMap(asset, dc.n_points, seed)

    def score(obs, positions):
        return discrepancy(obs, centre_map(positions[None, obs.frames]))[0]

    return score


MEASURES = Registry("discrepancy measure", "diagnose.discrepancy", ValueError)
MEASURES["render"] = Measure(_observe_images, _render_scorer, "|RGBA difference| per silhouette pixel")
MEASURES["points"] = Measure(_observe_points, _points_scorer, "pixels² (silhouette Chamfer distance of centres)")
