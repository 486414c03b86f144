"""Parameters rebuilt from plain values (an asset's params.npz, `simulate.py` edits) behave like
`PhysParams.init`'s: a frictionless ground (μ = 0) once made a rollout fail on its second
frame ("PhysParams.friction must hold one value, has N_A") because the value was a literal."""

import drjit as dr
import numpy as np

from sgdr.asset.predict import physical_params
from sgdr.physics import Ground, PhysicsConfig, SimState, build_spring_model, rollout


def test_edited_values_roll_out_on_a_frictionless_ground():
    rng = np.random.default_rng(0)
    x_rest = rng.uniform(0.3, 0.5, (64, 3))
    cfg = PhysicsConfig(contact="coulomb")
    model = build_spring_model(x_rest, 8, cfg)
    values = {
        "log10_k": np.full(64, 2.0),
        "kappa": 0.06,
        "friction": 0.0,
        "restitution": 0.35,
        "v0": (0.5, 0.0, -1.0),
        "gravity": (0.0, 0.0, -9.8),
    }
    params = physical_params(model, cfg, values)
    states = rollout(
        model,
        params,
        SimState.at_rest(model, params.v0),
        Ground([0.0, 0.0, 0.25], [0.0, 0.0, 1.0]),
        8,
        1 / 24,
        cfg,
        grad_mode="full",
        n_substeps=40,
    )
    assert all(dr.width(getattr(params, f)) == 1 for f in ("kappa", "friction", "restitution", "zeta0"))
    x = states[-1].numpy()[0]
    assert x[:, 2].min() >= 0.25 - 1e-5  # it reached the ground and stayed on it
    assert np.isfinite(x).all()


def test_lazy_clamped_parameters_stay_one_value_through_a_rollout():
    """Dr.Jit resizes an unevaluated width-1 array in place when it meets an N_A-wide one; a
    parameter written as dr.maximum(opt["friction"], 0) must still hold one value after a frame
    (it once failed the second frame's input check)."""
    from dataclasses import replace

    from sgdr.backend import ad
    from sgdr.physics import PhysParams

    t = ad()
    rng = np.random.default_rng(1)
    cfg = PhysicsConfig(contact="coulomb")
    model = build_spring_model(rng.uniform(0.3, 0.5, (64, 3)), 8, cfg)
    mu = t.Float(0.5)
    dr.make_opaque(mu)
    dr.enable_grad(mu)
    params = replace(
        PhysParams.init(model, cfg, v0=(0.0, 0.0, -1.0)),
        friction=dr.maximum(mu, 0.0),
        restitution=dr.clip(mu * 0.5, 0.0, 1.0),
    )
    states = rollout(
        model,
        params,
        SimState.at_rest(model, params.v0),
        Ground([0.0, 0.0, 0.25], [0.0, 0.0, 1.0]),
        4,
        1 / 24,
        cfg,
        grad_mode="full",
        n_substeps=40,
    )
    assert dr.width(params.friction) == 1 and dr.width(params.restitution) == 1
    dr.backward(dr.sum(states[-1].x.x))
    assert np.isfinite(dr.grad(mu).numpy()).all()
