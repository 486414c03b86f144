"""Pipeline stage 6: simulate the identified asset past the fit frames and render every view.

The rollout starts at rest (frame 0, anchors at their rest positions moving with v0) and runs
forward-only (no AD tape) for `n_frames` frames: the fit frames, re-simulated from frame 0
with the identified parameters (this is the "dynamic reconstruction" that evaluation scores),
followed by the future frames. Each frame's Gaussian centres are the IDW binding of the
anchors (Eq. 14); every camera renders every frame.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import drjit as dr
import numpy as np

from sgdr.arrays import array3_to_points, to_numpy
from sgdr.asset.momentum import internal_impulses, momentum_check
from sgdr.backend import ad
from sgdr.physics import PhysParams, SimState, rollout
from sgdr.render.images import posed, render_rgba_numpy


@dataclass
class Prediction:
    anchors: np.ndarray  # [T, N_A, 3] anchor positions per frame, world, scene units
    centres: np.ndarray  # [T, M, 3] Gaussian centres per frame, world, scene units
    images: np.ndarray  # [T, V, H, W, 4] uint8 RGBA renders per frame and view (empty if not rendered)
    velocities: np.ndarray | None = None  # [T, N_A, 3] anchor velocities per frame (None when loaded from disk)
    n_substeps: int = 0  # substeps per frame the rollout used (more than asked after a retry; 0 = unknown)
    momentum: dict | None = None  # the momentum audit of the rollout (`audit_momentum`), when made


def audit_momentum(model, params, ground, gravity, pred: Prediction, dt_frame: float, physics_cfg) -> dict:
    """How much momentum the springs of `pred`'s rollout added on their own (`sgdr.asset.momentum`):
    the numbers of `momentum_check`, per unit mass (scene units / s). The directed springs of the
    official model do not conserve momentum, so an identified stiffness field can push the
    object along the ground with nothing external acting; the report warns about it.
    gravity: [3] the rollout's, scene units / s²."""

    if pred.velocities is None or not pred.n_substeps:
        raise ValueError("audit_momentum needs the rollout's velocities and substeps (a fresh `predict`)")
    n = pred.velocities.shape[0]
    internal = internal_impulses(model, params, ground, n, dt_frame, pred.n_substeps, physics_cfg)
    masses = to_numpy(model.particle_mass).reshape(-1)
    check = momentum_check(
        pred.velocities,
        masses,
        internal,
        np.asarray(gravity, float),
        ground.normal,
        dt_frame,
        physics_cfg.springs,
        float("inf"),
    )
    return {k: v for k, v in check.items() if k not in ("gains_momentum", "warning", "tolerance")}


def physical_params(model, physics_cfg, values: dict):
    """PhysParams from plain values: {"log10_k" [N_A], "kappa", "friction", "restitution",
    "v0" [3], "gravity" [3]} (missing keys keep `PhysParams.init`'s defaults)."""

    t = ad()
    p = PhysParams.init(
        model,
        physics_cfg,
        v0=tuple(map(float, np.asarray(values.get("v0", (0, 0, 0)), float).reshape(3))),
        gravity=tuple(map(float, np.asarray(values.get("gravity", (0, 0, -9.8)), float).reshape(3))),
    )
    fields = {}
    if "log10_k" in values:
        k = np.asarray(values["log10_k"], dtype=np.float32).reshape(-1)
        if k.size == 1:
            k = np.full(int(dr.width(p.log10_k)), float(k[0]), np.float32)
        fields["log10_k"] = t.Float(k)
    for name in ("kappa", "friction", "restitution", "zeta0"):
        if name in values:
            fields[name] = t.Float(float(values[name]))
    p = replace(p, **fields)
    # memory-backed like PhysParams.init's: a literal is baked into the kernels (a recompile
    # per value), and a literal friction of exactly 0 came back 512 wide from a rollout
    dr.make_opaque(p)
    return p


def predict(
    model,
    params,
    binding,
    gaussians,
    ground,
    n_frames: int,
    fps: float,
    n_substeps: int,
    physics_cfg,
    cameras: list,
    render_cfg,
    render_views: bool = True,
    progress: bool = False,
) -> Prediction:
    """Forward rollout of `n_frames` frames from rest with `params` (its v0), bound and rendered.

    Returns anchors [T, N_A, 3], centres [T, M, 3], anchor velocities [T, N_A, 3], the substeps
    per frame used and, if render_views, images [T, V, H, W, 4] uint8 for every camera in
    `cameras`: RGB over black and the accumulated opacity (the report composites a ground behind it).
    """

    with dr.suspend_grad():
        p = params.detach()
        states = rollout(
            model,
            p,
            SimState.at_rest(model, p.v0),
            ground,
            int(n_frames),
            1.0 / float(fps),
            physics_cfg,
            n_substeps=int(n_substeps),
        )
        anchors, centres, velocities, images = [], [], [], []
        frames = range(len(states))
        if progress:
            from tqdm import tqdm

            frames = tqdm(frames, desc="predict", leave=False)
        for f in frames:
            x = states[f].x
            means = binding.apply(x)
            anchors.append(array3_to_points(x))
            velocities.append(array3_to_points(states[f].v))
            centres.append(array3_to_points(means))
            if render_views:
                g = posed(gaussians.detach(), means)
                views = [render_rgba_numpy(g, cam, render_cfg) for cam in cameras]
                images.append((np.stack(views) * 255.0 + 0.5).astype(np.uint8))
    imgs = np.stack(images) if images else np.zeros((0,), np.uint8)
    return Prediction(np.stack(anchors), np.stack(centres), imgs, np.stack(velocities), int(states.n_substeps))
