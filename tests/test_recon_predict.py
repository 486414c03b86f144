"""Parameters rebuilt from plain values (an asset's params.npz, `simulate.py` edits) behave like
`PhysParams.init`'s: a frictionless ground (μ = 0) once made a rollout fail on its second
frame ("PhysParams.friction must hold one value, has N_A") because the value was a literal."""

import drjit as dr
import numpy as np

from sgdr.physics import Ground, PhysicsConfig, SimState, build_spring_model, rollout
from sgdr.recon.predict import physical_params


def test_edited_values_roll_out_on_a_frictionless_ground():
    rng = np.random.default_rng(0)
    x_rest = rng.uniform(0.3, 0.5, (64, 3))
    cfg = PhysicsConfig(contact="coulomb")
    model = build_spring_model(x_rest, 8, cfg)
    values = {"log10_k": np.full(64, 2.0), "kappa": 0.06, "friction": 0.0, "restitution": 0.35,
              "v0": (0.5, 0.0, -1.0), "gravity": (0.0, 0.0, -9.8)}
    params = physical_params(model, cfg, values)
    states = rollout(model, params, SimState.at_rest(model, params.v0), Ground([0.0, 0.0, 0.25], [0.0, 0.0, 1.0]),
                     8, 1 / 24, cfg, grad_mode="full", n_substeps=40)
    assert all(dr.width(getattr(params, f)) == 1 for f in ("kappa", "friction", "restitution", "zeta0"))
    x = states[-1].numpy()[0]
    assert x[:, 2].min() >= 0.25 - 1e-5  # it reached the ground and stayed on it
    assert np.isfinite(x).all()
