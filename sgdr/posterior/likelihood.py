"""The silhouette likelihood of the posterior: cheap enough to evaluate thousands of times.

What is compared. For every used view v and fit frame f, the observed silhouette (the image's
alpha > 0.5) against the bound Gaussian centres of a parameter sample, projected into that view
(a fixed, seeded subset of `posterior.n_points` centres; the IDW binding is linear, so the subset
is exact, not an approximation of the centres it keeps). Two squared pixel distances, averaged:

    outside  mean over projected centres of dist(centre, silhouette)²  (the mask's distance
             transform, `scipy.ndimage.distance_transform_edt`, bilinear at the centre; 0 inside)
    coverage mean over `posterior.n_mask_points` silhouette pixels of dist(pixel, nearest centre)²

D_vf = outside + coverage is a symmetric 2D Chamfer distance between the silhouette and the
projected object (pixels²). The first term alone is blind to a prediction that shrinks inside the
silhouette or lags behind part of it (every centre inside scores 0); the second term penalises
silhouette that no centre explains, without rendering. Both are exact to evaluate from numbers
(no rasterisation of the samples, no gradients), a few milliseconds per sample on 2 cores.

Only the fit frames after frame 0 are used (frame 0 is the rest state, the same for every
sample); the future frames are kept for checking the posterior predictive. Views are subsampled
evenly (`posterior.n_views`) and frames by `posterior.frame_stride` to bound the cost.

Noise scale and tempering. log L(θ) = -Σ_vf D_vf(θ) / (2 σ² T) with

  σ² = mean_vf D_vf(θ_MAP), floored at `posterior.sigma_floor_px`² : the maximum-likelihood noise
       variance at the run's identified parameters (the MAP residual), so the MAP has
       log L = -n_vf / (2 T), whatever the image size or how well the run fitted;
  T  = `posterior.temperature` (default 1) on top of the per-view-frame normalisation.

The tempering is the per-view-frame normalisation: each view-frame contributes ONE squared
residual (the mean over its points), not one per point. The points of one silhouette are far
from independent (a stiffness change moves them all together, and the model's misfit of the
shape is shared by all of them), so treating the n_points + n_mask_points distances as
independent observations would sharpen the posterior by that factor (hundreds), the
overconfidence of a misspecified model the issue warns about. Counting the view-frames as the
effective independent observations is the same as a power 1/T_pt with T_pt = points per
view-frame. It still treats different frames and views as independent although the trajectory
is smooth; `posterior.temperature` > 1 flattens further (a conservative choice when the MAP
residual is far above the image's quantisation, i.e. when the model clearly misses the shape).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sgdr.observe.silhouette import Observation


@dataclass
class SilhouetteLikelihood:
    """log L(θ) from the discrepancies D [S, V, F] (module docstring): -Σ D / (2 σ² T)."""

    obs: Observation
    sigma2: float  # pixels², from the MAP residual (floored)
    temperature: float = 1.0

    @staticmethod
    def at_map(obs: Observation, map_discrepancy: np.ndarray, sigma_floor_px: float, temperature: float):
        """σ² = mean of the MAP's D_vf, floored at sigma_floor_px² (a perfect fit still has the
        pixel grid's quantisation). map_discrepancy: [V, F] (or [1, V, F])."""
        d = np.asarray(map_discrepancy, float).reshape(-1)
        if not np.all(np.isfinite(d)):
            raise ValueError("posterior: the identified parameters' rollout gives a non-finite silhouette residual")
        return SilhouetteLikelihood(obs, max(float(d.mean()), float(sigma_floor_px) ** 2), float(temperature))

    @property
    def n_terms(self) -> int:
        return int(len(self.obs.cameras) * len(self.obs.frames))

    def log_likelihood(self, d: np.ndarray) -> np.ndarray:
        """[S] from D [S, V, F]; -inf where D is not finite (an unstable rollout)."""
        d = np.asarray(d, float)
        total = d.reshape(d.shape[0], -1).sum(axis=1)
        ll = -total / (2.0 * self.sigma2 * self.temperature)
        return np.where(np.isfinite(ll), ll, -np.inf)
