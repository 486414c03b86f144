"""Twin sequences: an asset simulated by its own spring-mass model with known parameters and
rendered by its own renderer, so the truth lies exactly in the model class (issue 14, §5).

A posterior computed with the same asset on a twin's images must cover the twin's truth; over
many twins with truths drawn from the prior this is simulation-based calibration. Unlike the
benchmark generator (`sgdr.synth`: MLS-MPM + Mitsuba), nothing here is outside the model:
same anchors, springs, skinning, Gaussians, cameras, contact model and substeps.

    twin_sequence("outputs/torus_tiny_s0/asset", "/tmp/twin", {"log10_k_shift": 0.2, "friction": 0.3})

The truth is given relative to the asset's identified values: `log10_k_shift` is added to
every anchor's log10 k_i (the stiffness field keeps its shape); `kappa`, `friction`,
`restitution`, `zeta0` replace the asset's values; `v0` [3] replaces its initial velocity.
Keys left out keep the asset's values. The written sequence (sgdr layout,
`sgdr.data.load_sequence`) has the asset's cameras, frame count, fit split, fps and gravity;
its ground is the asset's contact plane (the plane the anchors touch). Reconstructing a twin
with the pipeline therefore needs `recon.contact_margin=0` to stay in the model class (the
pipeline raises the recorded ground by the Gaussians' median scale otherwise).
`gt/particles_<f>.npy` hold the bound Gaussian centres (what the evaluation scores against),
`gt/params.json` {"twin": true, "asset": ..., "truth": {...}, "values": {...}, "image_noise": σ,
"image_scale": s}.
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np

from sgdr.asset.predict import physical_params, predict
from sgdr.asset.store import load_asset
from sgdr.data import write_sequence
from sgdr.observe.contact import hit_frame
from sgdr.observe.images import upscaled
from sgdr.physics import Ground
from sgdr.posterior.rollouts import SAMPLE_KEYS, sample_values
from sgdr.render.config import RenderConfig


def twin_values(asset, truth: dict) -> dict:
    """The asset's parameter values with `truth` applied (see the module docstring): the same
    mapping the sampler uses for its samples (`sgdr.posterior.rollouts.sample_values`)."""

    unknown = sorted(set(truth) - set(SAMPLE_KEYS))
    if unknown:
        raise ValueError(f"twin truth: unknown keys {unknown}; known: {list(SAMPLE_KEYS)}")
    values = sample_values(asset.values, {k: np.asarray([v], float) for k, v in truth.items()}, 0)
    if not 0.0 <= float(values["restitution"]) <= 1.0:
        raise ValueError(f"twin truth: restitution {values['restitution']} outside [0, 1]")
    return values


def twin_sequence(
    asset_dir,
    out,
    truth: dict,
    render_cfg=None,
    progress: bool = False,
    physics: dict | None = None,
    fields: dict | None = None,
    image_scale: int = 1,
    image_noise: float = 0.0,
    noise_seed: int = 0,
) -> Path:
    """Simulate the asset in `asset_dir` with `truth`, render every camera and frame, write an
    sgdr-layout sequence to `out`; returns `out`. render_cfg: `RenderConfig` (default: its
    defaults). physics: `physics.*` settings that differ from the asset's, e.g. a model extension
    ({"gravity_scale": 0.8}, `sgdr.physics.extensions`): an effect injected into the twin, which
    changes the truth but not what the sequence records (its gravity and ground stay the
    asset's; the effect is in gt/effects.json). fields: identified values replaced outright, e.g.
    {"log10_k": [N_A]} for a stiffness field of another shape (a heterogeneity injected into
    the twin; recorded in gt/effects.json). image_scale: the twin's images s times finer than the
    asset's cameras (`upscaled`; a likelihood that sees more, e.g. a tiny asset's calibration).
    image_noise: the standard deviation of Gaussian noise added to the colour channels (values in
    [0, 1], then clipped; the alpha stays clean), seeded by `noise_seed`: a camera's noise, so that
    a posterior's calibration is measured on data of the kind its likelihood models (recorded in
    gt/params.json)."""

    if image_noise < 0:
        raise ValueError(f"twin image_noise={image_noise}: a standard deviation, >= 0")
    asset = load_asset(asset_dir)
    true_physics = replace(asset.physics, **(physics or {}))
    values = twin_values(asset, truth)
    for key, value in (fields or {}).items():
        if key not in values or np.shape(value) != np.shape(values[key]):
            raise ValueError(
                f"twin fields: {key!r} must replace an identified value of shape {np.shape(values.get(key))}"
            )
        values[key] = np.asarray(value, float)
    cameras = [upscaled(c, int(image_scale)) for c in asset.cameras]
    model, binding = asset.build()
    params = physical_params(model, asset.physics, values)
    ground = Ground(asset.ground_point, asset.ground_normal)
    pred = predict(
        model,
        params,
        binding,
        asset.gaussians,
        ground,
        asset.n_frames,
        asset.fps,
        asset.n_substeps,
        true_physics,
        cameras,
        render_cfg or RenderConfig(),
        True,
        progress,
    )
    images = np.transpose(pred.images.astype(np.float32) / 255.0, (1, 0, 2, 3, 4))  # [V, T, H, W, 4]
    if image_noise > 0:
        rng = np.random.default_rng([int(noise_seed), 7])
        noisy = images[..., :3] + rng.normal(0.0, float(image_noise), images[..., :3].shape).astype(np.float32)
        images[..., :3] = np.clip(noisy, 0.0, 1.0)
    plain = {k: (np.asarray(v).tolist() if np.ndim(v) else float(v)) for k, v in values.items()}
    return write_sequence(
        out,
        cameras=cameras,
        images=images,
        fps=asset.fps,
        n_fit=asset.n_fit,
        hit_frame=hit_frame(pred.anchors, asset.ground_point, asset.ground_normal),
        ground_point=asset.ground_point,
        ground_normal=asset.ground_normal,
        gravity=np.asarray(values["gravity"], float),
        gt_particles=[c.astype(np.float32) for c in pred.centres],
        gt_params={
            "twin": True,
            "asset": str(Path(asset_dir).resolve()),
            "truth": json.loads(json.dumps({k: np.asarray(v).tolist() for k, v in truth.items()})),
            "values": {k: v for k, v in plain.items() if k != "log10_k"},
            "log10_k_mean": float(np.mean(values["log10_k"])),
            "n_substeps": int(pred.n_substeps),
            "image_noise": float(image_noise),
            "image_scale": int(image_scale),
        },
        gt_effects=_effects(physics or {}, fields or {}),
    )


def _effects(physics: dict, fields: dict) -> dict:
    """gt/effects.json of a twin: the injected physics settings and replaced fields ({} without)."""
    if not physics and not fields:
        return {}
    out = {"physics": dict(physics), "active": sorted(physics) + sorted(fields)}
    if fields:
        out["fields"] = {k: np.asarray(v, float).tolist() for k, v in fields.items()}
    return out
