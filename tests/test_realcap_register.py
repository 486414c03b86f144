"""Registration of static Gaussians into the dynamic frame: a known similarity is recovered from
masks rendered through it, starting from the kind of rough guess a config gives."""

import numpy as np

from sgdr.cameras import Camera
from sgdr.render.config import RenderConfig


def test_register_recovers_a_known_similarity_from_masks():
    from sgdr.arrays import to_numpy
    from sgdr.gaussians.model import Gaussians
    from sgdr.render.splat import render
    from sgdr.static_fit.register import RegisterConfig, euler_xyz_deg, register

    rng = np.random.default_rng(5)
    # an asymmetric object in the static frame: a bar with a knob at one end and a fin
    bar = rng.uniform([-1.0, -0.25, -0.25], [1.0, 0.25, 0.25], (300, 3))
    knob = rng.normal([1.1, 0.5, 0.0], 0.2, (120, 3))
    fin = rng.uniform([-0.9, -0.1, 0.2], [-0.3, 0.1, 0.9], (100, 3))
    X = np.concatenate([bar, knob, fin]) + np.array([3.0, -2.0, 5.0])
    static = Gaussians.isotropic(X, 0.12, np.full(3, 0.6), 0.95)
    s_true, R_true = 0.08, euler_xyz_deg([70.0, -25.0, 40.0])
    t_true = np.array([0.1, -0.05, -0.12])
    c = X.mean(0)
    X_d = (s_true * (X - c)) @ R_true.T + t_true
    size = s_true * np.linalg.norm(X.max(0) - X.min(0))
    truth = Gaussians.isotropic(X_d, 0.12 * s_true, np.full(3, 0.6), 0.95)
    target = t_true
    cams = [
        Camera.look_at(target + [0.0, -0.6, -0.25], target, [0, 0, -1], 50.0, 64, 48, "C0733"),
        Camera.look_at(target + [0.55, 0.25, -0.25], target, [0, 0, -1], 50.0, 64, 48, "C0787"),
        Camera.look_at(target + [-0.5, 0.3, -0.3], target, [0, 0, -1], 50.0, 64, 48, "C0801"),
    ]
    rc = RenderConfig()
    masks = [(to_numpy(render(truth, cam, rc).alpha, np.float32) > 0.5).astype(np.float32) for cam in cams]
    assert all(m.sum() > 50 for m in masks)
    R0 = euler_xyz_deg([70.0 + 10.0, -25.0 - 8.0, 40.0 + 6.0])
    reg = register(
        static,
        cams,
        masks,
        R0,
        t_true + 0.1 * size * np.array([0.6, -0.8, 0.0]),
        s_true * 1.1,
        RegisterConfig(iterations=300, lr=0.01),
        rc,
    )
    angle = np.degrees(np.arccos(np.clip((np.trace(reg.R.T @ R_true) - 1) / 2, -1, 1)))
    assert angle < 2.0, angle
    assert abs(reg.s / s_true - 1) < 0.02, reg.s
    assert np.linalg.norm(reg.t - t_true) < 0.01 * size, (reg.t, t_true, size)
    assert reg.losses[-1] < 0.5 * reg.losses[0]
    np.testing.assert_allclose(reg.apply(X), X_d, atol=0.02 * size)
