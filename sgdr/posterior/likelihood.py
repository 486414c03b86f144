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


class RenderedImages:
    """θ [S, D] -> image losses [S, F, V]: each sample's open-loop rollout of the fit frames from
    rest, rendered on every view and compared with the observed images by the identification's
    own loss ((1-λ) L1 + λ D-SSIM, `recon.lambda_dssim`), through the global search's batched
    `PopulationScorer` (one S x N_A rollout, then `render_batch` over whole frames of all views);
    a sample unstable at the asset's n_t is re-run with n_t doubled as physics.retry_on_nan allows
    (as the posterior's rollouts and the predictive do), so the posterior is not cut off at the
    stability bound the identified level often sits at.
    So the likelihood sees what the identification saw: the rendered images at
    `image_scale` (k x k block means of the targets, intrinsics / k), at the asset's n_t.

    θ's log10_k_shift moves the asset's whole log10 k field (the scorer's level minus the
    field's mean); the other parameters replace the asset's values."""

    def __init__(self, asset, seq, problem, render_cfg, lam: float, image_scale: int, images_per_call: int):
        from sgdr.asset.predict import physical_params
        from sgdr.identify.global_search import PopulationScorer
        from sgdr.observe.targets import frame_targets
        from sgdr.physics import Ground

        n_fit = min(int(asset.n_fit), int(seq.n_fit))
        if n_fit < 2:
            raise ValueError(
                f"{seq.root}: {n_fit} fit frame(s); the rendered likelihood needs fit frames after frame 0"
            )
        model, binding = asset.build()
        base = physical_params(model, asset.physics, asset.values)
        ground = Ground(asset.ground_point, asset.ground_normal)
        targets = [frame_targets(seq, f) for f in range(n_fit)]
        self.problem = problem
        self.scorer = PopulationScorer(model, binding, asset.gaussians, base, ground, targets, seq.cameras,
                                       1.0 / asset.fps, int(asset.n_substeps), asset.physics, render_cfg, float(lam),
                                       int(image_scale), int(images_per_call))  # fmt: skip
        self.frames = np.arange(1, n_fit)
        self.n_views = len(seq.cameras)
        self.calls = 0  # rollouts rendered (the cost)
        self.unstable = 0
        self._memo: dict[bytes, np.ndarray] = {}  # θ -> [F, V]: a θ evaluated twice is rendered once

    def values(self, thetas: np.ndarray) -> dict:
        """The scorer's candidate values of θ [S, D]."""
        out = {}
        for j, name in enumerate(self.problem.names):
            if name == "log10_k_shift":
                out["log10_k"] = self.scorer.base_level + np.asarray(thetas[:, j], float)
            else:
                out[name] = np.asarray(thetas[:, j], float)
        return out

    def __call__(self, thetas: np.ndarray, chunk: int = 32) -> np.ndarray:
        """[S, F, V] losses, NaN rows for unstable rollouts; `chunk` samples per batched call. A θ
        already evaluated is not rendered again (the design is scored once to choose the
        likelihood's reference, `reference_index`, and again by the sampler)."""
        thetas = np.atleast_2d(np.asarray(thetas, float))
        keys = [t.tobytes() for t in thetas]
        todo = list({k: i for i, k in reversed(list(enumerate(keys))) if k not in self._memo}.values())
        new = thetas[todo]
        parts = [self.scorer.per_image(self.values(new[i : i + chunk]), retry=True) for i in range(0, len(new), chunk)]
        for i, row in zip(todo, np.concatenate(parts) if parts else []):
            self._memo[keys[i]] = row
        self.calls += len(new)
        self.unstable += sum(not np.isfinite(self._memo[keys[i]]).all() for i in todo)
        if not keys:
            return np.zeros((0, len(self.frames), self.n_views))
        return np.stack([self._memo[k] for k in keys])


def reference_index(losses: np.ndarray) -> int:
    """The best-fitting of evaluated samples' image losses [S, F, V]: the lowest mean over the
    view-frames among the stable ones. The likelihood's scale is that sample's misfit (the
    maximum-likelihood noise of the evaluated points): on the run's own sequence usually the
    identified parameters themselves; on another sequence (a twin rendered with other parameters)
    the identified parameters' misfit holds the difference of the parameters, not the noise."""
    x = np.asarray(losses, float).reshape(len(losses), -1)
    mean = np.where(np.isfinite(x).all(axis=1), x.mean(axis=1), np.inf)
    if not np.isfinite(mean).any():
        raise ValueError("posterior: every evaluated sample's rollout is unstable")
    return int(np.argmin(mean))


@dataclass
class RenderedLikelihood:
    """log L(θ) = -Σ_f Σ_v ℓ_fv(θ) / (2 s_f T) from the image losses ℓ [S, F, V] (`RenderedImages`).

    One view-frame is one observation (the tempering: the pixels of one image are far from
    independent, so counting them would sharpen the posterior by the pixel count). Its scale
    s_f = noise + discrepancy_f splits the reference's misfit m_f (mean over the views of frame f;
    the reference is the best-fitting evaluated sample, `reference_index`: the identified asset
    on its own sequence) into
      noise          min_f m_f, floored at `floor`: what no physical parameter removes (the
                     appearance fit and the image noise; the frames before the object has moved
                     much show it alone);
      discrepancy_f  m_f - noise made non-decreasing in f (isotonic regression): the model's
                     misfit of the motion, allowed to grow with the horizon where the data say it
                     does and no faster.
    So the MAP scores about -n_vf / (2T) and a sample whose images err by a fraction ε more than
    the MAP's on every frame loses about n_vf ε / 2 nats; later frames, where the model misses
    more, weigh less. T = `posterior.temperature`."""

    noise: float
    discrepancy: np.ndarray  # [F]
    temperature: float = 1.0

    @staticmethod
    def at_map(map_losses: np.ndarray, floor: float, temperature: float) -> RenderedLikelihood:
        """From the MAP's losses [F, V] (or [1, F, V])."""
        from sklearn.isotonic import IsotonicRegression

        m = np.asarray(map_losses, float).reshape(-1, np.shape(map_losses)[-1]).mean(axis=1)  # [F]
        if not np.all(np.isfinite(m)):
            raise ValueError("posterior: the identified parameters' rollout gives non-finite image losses")
        noise = max(float(m.min()), float(floor))
        excess = np.maximum(m - noise, 0.0)
        f = np.arange(m.size, dtype=float)
        disc = IsotonicRegression(increasing=True).fit(f, excess).predict(f) if m.size > 1 else excess
        return RenderedLikelihood(noise, np.maximum(disc, 0.0), float(temperature))

    @property
    def scale(self) -> np.ndarray:
        return self.noise + self.discrepancy

    def log_likelihood(self, losses: np.ndarray) -> np.ndarray:
        """[S] from ℓ [S, F, V]; -inf where any loss is not finite (an unstable rollout)."""
        x = np.asarray(losses, float)
        ll = -np.sum(x / (2.0 * self.scale[None, :, None] * self.temperature), axis=(1, 2))
        return np.where(np.isfinite(ll), ll, -np.inf)
