"""The Dr.Jit simulator against its float64 NumPy reference (sgdr/physics/reference.py): forward
equality for every variant combination, and gradients of a rollout loss against central finite
differences of the reference, in both gradient modes."""

import drjit as dr
import numpy as np
import pytest

from sgdr.physics import Ground, PhysicsConfig, PhysParams, SimState, build_spring_model, rollout
from sgdr.physics import reference as R
from tests.physics_variants import CONTACT_MODELS, LAWS, all_variants, spring_variants, variant_ids


def _blob(n=40, seed=3):
    return np.random.default_rng(seed).uniform(0.3, 0.7, (n, 3))


@pytest.mark.parametrize("law,springs,stiffness,contact,normalised", all_variants(), ids=variant_ids())
def test_rollout_matches_numpy_reference(law, springs, stiffness, contact, normalised):
    """200 substeps (2 frames x 100) of a strained, moving blob hitting a tilted ground."""
    rng = np.random.default_rng(7)
    x_rest = _blob()
    cfg = PhysicsConfig(
        spring_law=law,
        springs=springs,
        symmetric_stiffness=stiffness,
        contact=contact,
        soft_vector_normalised=normalised,
        n_c=4,
        log10_k_init=1.5,
        kappa_init=-1.0,
        friction_init=0.5,
        restitution_init=0.5,
    )
    model = build_spring_model(x_rest, 12, cfg)
    params = PhysParams.init(model, cfg, v0=(0.3, 0.1, -2.0), gravity=(0.0, -1.0, -9.8))
    params.log10_k = type(params.log10_k)(rng.uniform(1.2, 1.8, 40).astype(np.float32))
    x0 = x_rest + rng.normal(0.0, 0.01, x_rest.shape)
    v0 = np.tile([0.3, 0.1, -2.0], (40, 1)) + rng.normal(0.0, 0.1, x_rest.shape)
    ground = Ground([0.0, 0.0, 0.28], [0.1, 0.0, 1.0])
    states = rollout(model, params, SimState.from_numpy(x0, v0), ground, 3, 1 / 30, cfg, n_substeps=100)
    ref = R.rollout(
        R.model_numpy(model),
        R.params_numpy(params),
        ground,
        3,
        1 / 30,
        100,
        cfg,
        x0=states[0].numpy()[0],
        v0=states[0].numpy()[1],
    )
    x, v = states[-1].numpy()
    x_ref, v_ref = ref[-1]
    # the scene really exercises contact: without the ground the result is far from this one
    free = R.rollout(
        R.model_numpy(model),
        R.params_numpy(params),
        Ground([0, 0, -10.0], [0, 0, 1]),
        3,
        1 / 30,
        100,
        cfg,
        x0=states[0].numpy()[0],
        v0=states[0].numpy()[1],
    )
    assert np.abs(free[-1][0] - x_ref).max() > 1e-2
    assert np.abs(x - x_ref).max() <= 1e-5 * np.abs(x_ref).max()
    assert np.abs(v - v_ref).max() <= 1e-5 * np.abs(v_ref).max()


# --------------------------------------------------------------------------------------------
# Gradients vs central finite differences of the float64 reference
# --------------------------------------------------------------------------------------------
N_FRAMES, N_SUB, DT = 3, 20, 1 / 30
PARAM_NAMES = ["log10_k", "kappa", "v0", "friction", "restitution", "zeta0", "gravity"]


def _setup(law, springs, stiffness, contact):
    rng = np.random.default_rng(11)
    x_rest = _blob(32, seed=5)
    cfg = PhysicsConfig(
        spring_law=law,
        springs=springs,
        symmetric_stiffness=stiffness,
        contact=contact,
        n_c=2,
        log10_k_init=1.5,
        kappa_init=-1.0,
        restitution_init=0.6,
        zeta0=0.05,
        # "project": tangential factor per substep; "coulomb": small enough to slide
        friction_init=0.3 if contact == "project" else 0.05,
    )
    model = build_spring_model(x_rest, 8, cfg)
    params = PhysParams.init(model, cfg, v0=(0.5, 0.2, -2.5), gravity=(0.0, 0.0, -9.8))
    params.log10_k = type(params.log10_k)(rng.uniform(1.3, 1.7, 32).astype(np.float32))
    ground = Ground([0.0, 0.0, 0.28], [0.0, 0.05, 1.0])
    weights = [rng.normal(size=(32, 3)) for _ in range(N_FRAMES)]  # loss = Σ_f Σ_i w_fi · x_i(f)
    directions = {
        "log10_k": rng.normal(size=32),
        "v0": rng.normal(size=3),
        "gravity": rng.normal(size=3),
        "kappa": 1.0,
        "friction": 1.0,
        "restitution": 1.0,
        "zeta0": 1.0,
    }
    return cfg, model, params, ground, weights, directions


def _perturbed(p: dict, name: str, h: float, direction) -> dict:
    q = dict(p)
    q[name] = p[name] + h * np.asarray(direction) if np.ndim(p[name]) else p[name] + h * float(direction)
    return q


def _reference_fd(m, p, ground, weights, cfg, name, direction, mode, h=1e-6):
    """Directional derivative of the loss by central differences of the reference (float64)."""

    def loss_full(q):
        return sum(
            float(np.sum(w * s[0])) for w, s in zip(weights[1:], R.rollout(m, q, ground, N_FRAMES, DT, N_SUB, cfg)[1:])
        )

    if mode == "full":
        return (loss_full(_perturbed(p, name, h, direction)) - loss_full(_perturbed(p, name, -h, direction))) / (2 * h)
    # truncated: frame f is simulated with perturbed parameters from the unperturbed frame f-1
    # (frame 1 from the perturbed initial state, whose velocity is v0)
    base = R.rollout(m, p, ground, N_FRAMES, DT, N_SUB, cfg)
    total = 0.0
    for f in range(1, N_FRAMES):
        diff = 0.0
        for sign in (1.0, -1.0):
            q = _perturbed(p, name, sign * h, direction)
            x, v = base[f - 1] if f > 1 else (m["x_rest"], np.broadcast_to(q["v0"], m["x_rest"].shape))
            xf, _ = R.simulate_frame(m, q, x, v, ground, DT, N_SUB, cfg)
            diff += sign * float(np.sum(weights[f] * xf))
        total += diff / (2 * h)
    return total


def _drjit_grads(model, params, ground, weights, cfg, mode):
    dr.enable_grad(params)
    states = rollout(
        model, params, SimState.at_rest(model, params.v0), ground, N_FRAMES, DT, cfg, grad_mode=mode, n_substeps=N_SUB
    )
    t = type(params.v0)
    loss = 0.0
    for w, s in zip(weights[1:], states[1:]):
        loss = loss + dr.sum(dr.dot(s.x, t(*w.T.astype(np.float32))))
    dr.backward(loss)
    out = {}
    for name in PARAM_NAMES:
        g = dr.grad(getattr(params, name))
        out[name] = (
            np.stack([np.asarray(g[c].numpy(), np.float64) for c in range(3)], 1)[0]
            if name in ("v0", "gravity")
            else np.asarray(g.numpy(), np.float64)
        )
    return out


@pytest.mark.parametrize("mode", ["full", "truncated"])
@pytest.mark.parametrize("contact", CONTACT_MODELS)
@pytest.mark.parametrize("springs,stiffness", spring_variants())
@pytest.mark.parametrize("law", LAWS)
def test_gradients_match_finite_differences(law, springs, stiffness, contact, mode):
    cfg, model, params, ground, weights, directions = _setup(law, springs, stiffness, contact)
    m, p = R.model_numpy(model), R.params_numpy(params)
    grads = _drjit_grads(model, params, ground, weights, cfg, mode)
    unused = []
    for name in PARAM_NAMES:
        d = directions[name]
        fd = _reference_fd(m, p, ground, weights, cfg, name, d, mode)
        ad = float(np.sum(grads[name] * d)) if np.ndim(d) else float(grads[name][0]) * d
        if fd == 0.0:  # a parameter this variant never reads (the official contact ignores e)
            assert ad == 0.0, (name, ad)
            unused.append(name)
            continue
        assert abs(fd) > 1e-5, (name, fd)  # every parameter it reads matters (float64 FD noise ~1e-9)
        assert np.sign(ad) == np.sign(fd), (name, ad, fd)
        assert abs(ad - fd) <= 1e-3 * abs(fd), (name, ad, fd)  # float32 AD vs float64 FD
    assert set(unused) <= {"restitution"}, unused  # only restitution may be unused (by some contacts)


# the printed (unnormalised) form cuts every spring past n_c at κ >= 0, so it is checked at κ < 0
@pytest.mark.parametrize("kappa,normalised", [(0.0, True), (-1.0, True), (0.7, True), (-1.0, False), (-2.5, False)])
def test_soft_vector_and_its_kappa_gradient(kappa, normalised):
    """η_j (Eq. 15) against the reference, and dη/dκ against central differences, at the default κ = 0
    too (a max/abs softplus has a zero derivative there)."""
    from sgdr.backend import ad
    from sgdr.physics.laws import soft_vector_eta, soft_vector_exponent, softplus

    t = ad()
    n_k, n_c = 24, 6
    k = t.Float(kappa)
    dr.enable_grad(k)
    eta = soft_vector_eta(softplus(k), soft_vector_exponent(dr.arange(t.Float, n_k), n_k, n_c, normalised))
    ref = R.soft_vector(kappa, n_k, n_c, normalised)
    assert np.abs(eta.numpy() - ref).max() < 1e-6
    interior = (ref > 1e-3) & (ref < 1 - 1e-9)  # away from the clamp, where η is smooth in κ
    assert interior.sum() >= 1
    dr.backward(dr.sum(dr.select(t.Bool(interior), eta, 0.0)))
    h = 1e-6
    fd = (
        R.soft_vector(kappa + h, n_k, n_c, normalised)[interior].sum()
        - R.soft_vector(kappa - h, n_k, n_c, normalised)[interior].sum()
    ) / (2 * h)
    assert fd < 0 and abs(dr.grad(k).numpy()[0] - fd) <= 1e-4 * abs(fd) + 1e-6
