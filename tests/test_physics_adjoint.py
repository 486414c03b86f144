"""The hand-written gather-only adjoint of the spring sum (sgdr/physics/adjoint.py,
physics.adjoint="gather") against recorded AD of the same loop (physics.adjoint="recorded"):
a random cotangent on every frame's x and v, gradients of every parameter and of the initial
state, for every variant combination of the twin tests."""

import drjit as dr
import numpy as np
import pytest

from sgdr.physics import Ground, PhysicsConfig, PhysParams, SimState, build_spring_model, rollout
from sgdr.physics.simulate import ADJOINTS
from tests.physics_variants import all_variants, variant_ids

REFERENCE = "recorded"  # every other registered adjoint is compared with recorded AD
N, N_K, N_FRAMES, N_SUB = 24, 8, 3, 6


def _gradients(adjoint: str, law, springs, stiffness, contact, normalised, mode):
    rng = np.random.default_rng(3)
    x_rest = rng.uniform(0.3, 0.7, (N, 3))
    cfg = PhysicsConfig(
        spring_law=law,
        springs=springs,
        symmetric_stiffness=stiffness,
        contact=contact,
        soft_vector_normalised=normalised,
        n_c=3,
        log10_k_init=1.5,
        kappa_init=-1.0,
        restitution_init=0.6,
        zeta0=0.05,
        friction_init=0.3 if contact == "project" else 0.05,
        adjoint=adjoint,
    )
    model = build_spring_model(x_rest, N_K, cfg)
    params = PhysParams.init(model, cfg, v0=(0.5, 0.2, -2.5))
    params.log10_k = type(params.log10_k)(rng.uniform(1.3, 1.7, N).astype(np.float32))
    dr.enable_grad(params)
    state0 = SimState.from_numpy(
        x_rest + rng.normal(0.0, 0.01, x_rest.shape), np.array([0.5, 0.2, -2.5]) + rng.normal(0.0, 0.3, x_rest.shape)
    )
    dr.enable_grad(state0.x, state0.v)
    states = rollout(
        model,
        params,
        state0,
        Ground([0.0, 0.0, 0.28], [0.0, 0.05, 1.0]),
        N_FRAMES,
        1 / 30,
        cfg,
        grad_mode=mode,
        n_substeps=N_SUB,
    )
    t = type(params.v0)
    loss = 0.0
    for s in states[1:]:  # random cotangents on x and v of every frame
        loss = loss + dr.sum(dr.dot(s.x, t(*rng.normal(size=(3, N)).astype(np.float32))))
        loss = loss + dr.sum(dr.dot(s.v, t(*rng.normal(size=(3, N)).astype(np.float32))))
    dr.backward(loss)
    out = {f: np.array(dr.grad(getattr(params, f)).numpy(), np.float64).ravel() for f in params.__dataclass_fields__}
    out["x0"] = np.array(dr.grad(state0.x).numpy(), np.float64).ravel()
    out["state0.v"] = np.array(dr.grad(state0.v).numpy(), np.float64).ravel()
    return out


@pytest.mark.parametrize("adjoint", sorted(set(ADJOINTS) - {REFERENCE}))
@pytest.mark.parametrize("law,springs,stiffness,contact,normalised", all_variants(), ids=variant_ids())
def test_adjoint_matches_recorded_ad(adjoint, law, springs, stiffness, contact, normalised):
    mode = "full" if normalised else "truncated"  # both gradient modes, each on half the variants
    recorded = _gradients(REFERENCE, law, springs, stiffness, contact, normalised, mode)
    other = _gradients(adjoint, law, springs, stiffness, contact, normalised, mode)
    for name in ("log10_k", "kappa", "zeta0", "gravity", "friction", "restitution", "x0", "state0.v"):
        scale = np.abs(recorded[name]).max()
        if name == "restitution" and scale == 0.0:  # a contact that never reads e
            assert np.abs(other[name]).max() == 0.0
            continue
        assert scale > 0, name  # the scene makes the parameter matter
        # 1e-4 of the largest: a scalar's gradient (friction, restitution, gravity) is a float32 sum
        # over every anchor and substep, accumulated in another order by each adjoint (the CI
        # machine once gave 1.15e-5 for friction); a wrong adjoint term is off by far more
        assert np.abs(other[name] - recorded[name]).max() <= 1e-4 * scale, (name, other[name], recorded[name])


def test_unknown_adjoint_is_refused_naming_the_setting():
    with pytest.raises(ValueError, match=r"physics.adjoint='nope'"):
        _gradients("nope", "official", "directed", "harmonic", "project", True, "full")
