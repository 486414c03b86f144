"""The model extensions (sgdr/physics/extensions.py: air drag, gravity scale, moved and tilted
ground, spring plasticity): the null values are the base model bit for bit, each matches the float64 twin, each
does what it says on a scene where the answer is known, and the gather adjoint still equals
recorded AD with all of them on."""

from dataclasses import replace

import drjit as dr
import numpy as np
import pytest

from sgdr.physics import Ground, PhysicsConfig, PhysParams, SimState, build_spring_model, rollout
from sgdr.physics import reference as R
from sgdr.physics.extensions import ground_plane, plane_axes

EXTENSIONS = {
    "air_drag": {"air_drag": 3.0},
    "gravity_scale": {"gravity_scale": 0.8},
    "ground_offset": {"ground_offset": 0.04},
    "ground_tilt": {"ground_tilt_deg": 6.0, "ground_tilt_azimuth_deg": 30.0},
    "plasticity": {"plastic_yield_strain": 0.01},
    "rebound": {"contact_restitution": 0.5},
    "all": {
        "air_drag": 1.5,
        "gravity_scale": 1.2,
        "ground_offset": -0.02,
        "ground_tilt_deg": 4.0,
        "contact_restitution": 0.4,
    },
}
GROUND = Ground([0.0, 0.0, 0.28], [0.05, 0.0, 1.0])


def _scene(contact="coulomb", friction=0.5, **extension):
    rng = np.random.default_rng(7)
    x_rest = rng.uniform(0.3, 0.7, (40, 3))
    cfg = PhysicsConfig(
        contact=contact, n_c=4, log10_k_init=1.5, friction_init=friction, restitution_init=0.4, **extension
    )
    model = build_spring_model(x_rest, 12, cfg)
    params = PhysParams.init(model, cfg, v0=(0.3, 0.1, -2.0), gravity=(0.0, -1.0, -9.8))
    x0 = x_rest + rng.normal(0.0, 0.01, x_rest.shape)
    v0 = np.tile([0.3, 0.1, -2.0], (40, 1))
    return model, params, SimState.from_numpy(x0, v0), cfg


def _final(model, params, state0, cfg, n_frames=3, ground=GROUND):
    return rollout(model, params, state0, ground, n_frames, 1 / 30, cfg, n_substeps=100)[-1].numpy()


@pytest.mark.parametrize("contact", ["coulomb", "project"])
@pytest.mark.parametrize("name", sorted(EXTENSIONS))
def test_extension_matches_the_numpy_twin_and_changes_the_motion(name, contact):
    model, params, state0, cfg = _scene(contact, **EXTENSIONS[name])
    x, v = _final(model, params, state0, cfg)
    x0, v0 = state0.numpy()
    x_ref, v_ref = R.rollout(R.model_numpy(model), R.params_numpy(params), GROUND, 3, 1 / 30, 100, cfg, x0=x0, v0=v0)[
        -1
    ]
    assert np.abs(x - x_ref).max() <= 1e-5 * np.abs(x_ref).max()
    assert np.abs(v - v_ref).max() <= 1e-5 * np.abs(v_ref).max()
    base, _ = _final(model, params, state0, replace(cfg, **{k: getattr(PhysicsConfig(), k) for k in EXTENSIONS[name]}))
    if name == "rebound" and contact == "coulomb":  # the coulomb law has its own restitution
        np.testing.assert_array_equal(x, base)
        return
    assert np.abs(x - base).max() > 1e-3  # the extension acts on this scene


def test_null_values_are_the_base_model_exactly():
    model, params, state0, cfg = _scene()
    base = _final(model, params, state0, cfg)
    nulls = replace(
        cfg,
        air_drag=0.0,
        gravity_scale=1.0,
        ground_offset=0.0,
        ground_tilt_deg=0.0,
        ground_tilt_azimuth_deg=77.0,
        plastic_yield_strain=0.0,
        contact_restitution=0.0,
    )
    for a, b in zip(base, _final(model, params, state0, nulls)):
        np.testing.assert_array_equal(a, b)


def test_each_extension_does_what_it_says():
    # free flight (ground far below): gravity scale and drag against their closed forms
    far = Ground([0.0, 0.0, -100.0], [0.0, 0.0, 1.0])
    dt, n_sub, frames = 1 / 30, 100, 4
    model, params, state0, cfg = _scene()
    params.log10_k = type(params.log10_k)(np.full(40, -6.0, np.float32))  # springs negligible: free points
    x0, v0 = state0.numpy()
    g = np.array([0.0, -1.0, -9.8])
    T = (frames - 1) * dt
    h = dt / n_sub
    for scale in (0.5, 1.3):
        x, _ = _final(model, params, state0, replace(cfg, gravity_scale=scale), frames, far)
        # semi-implicit Euler: x_n = x0 + n h v0 + h² n(n+1)/2 a
        n = (frames - 1) * n_sub
        expected = x0 + n * h * v0 + h * h * n * (n + 1) / 2 * scale * g
        np.testing.assert_allclose(x, expected, atol=2e-4)
    c = 2.0
    _, v = _final(model, params, state0, replace(cfg, air_drag=c), frames, far)
    q = 1.0 / (1.0 + c * h)
    n = (frames - 1) * n_sub
    v_expected = q**n * v0 + g * h * q * (1 - q**n) / (1 - q)  # v_k = q (v_{k-1} + h g)
    np.testing.assert_allclose(v, v_expected, atol=2e-4)
    assert np.all(np.linalg.norm(v, axis=1) < np.linalg.norm(v0 + g * T, axis=1))

    # the moved, tilted ground: after landing no anchor is below the extended plane, and the
    # lowest ones rest on it (not on the recorded one)
    _, params, state0, cfg = _scene(contact="project")
    ext = replace(cfg, ground_offset=0.05, ground_tilt_deg=8.0, ground_tilt_azimuth_deg=120.0)
    x, _ = _final(model, params, state0, ext, 12)
    point, normal = ground_plane(GROUND.point, GROUND.normal, ext)
    height = (x - point) @ normal
    assert height.min() > -1e-4 and height.min() < 1e-3
    recorded = (x - GROUND.point) @ GROUND.normal
    assert recorded.min() > 0.03  # above the recorded plane by about the offset
    tilt = np.degrees(np.arccos(np.clip(np.dot(normal, GROUND.normal), -1, 1)))
    assert tilt == pytest.approx(8.0, abs=1e-9)


def test_plane_axes_are_orthonormal_and_right_handed():
    for n in ([0, 0, 1.0], [0, 1.0, 0], [0.3, -0.2, 0.93]):
        n = np.asarray(n) / np.linalg.norm(n)
        a, b = plane_axes(n)
        np.testing.assert_allclose([a @ n, b @ n, a @ b], 0.0, atol=1e-12)
        np.testing.assert_allclose(np.cross(a, b), n, atol=1e-12)


@pytest.mark.parametrize("contact", ["coulomb", "project"])
def test_gather_adjoint_equals_recorded_ad_with_every_extension_on(contact):
    def grads(adjoint):
        # a small Coulomb friction: a large one stops the sliding outright (zero gradient)
        friction = 0.3 if contact == "project" else 0.05
        model, params, state0, cfg = _scene(contact, friction, **EXTENSIONS["all"])
        cfg = replace(cfg, adjoint=adjoint)
        dr.enable_grad(params)
        states = rollout(model, params, state0, GROUND, 3, 1 / 30, cfg, n_substeps=20)
        rng = np.random.default_rng(3)
        t = type(params.v0)
        loss = 0.0
        for s in states[1:]:
            loss = loss + dr.sum(dr.dot(s.x, t(*rng.normal(size=(3, 40)).astype(np.float32))))
        dr.backward(loss)
        return {
            f: np.array(dr.grad(getattr(params, f)).numpy(), np.float64).ravel()
            for f in ("log10_k", "gravity", "friction", "kappa")
        }

    recorded, gather = grads("recorded"), grads("gather")
    for name, ref in recorded.items():
        scale = np.abs(ref).max()
        assert scale > 0, name
        assert np.abs(gather[name] - ref).max() <= 1e-5 * scale, name


def _size(x):
    return float(np.linalg.norm(x - x.mean(0), axis=1).mean())


@pytest.mark.parametrize("springs", ["directed", "symmetric"])
def test_plasticity_keeps_a_compression_beyond_the_yield_strain(springs):
    # no gravity, no ground: an object squeezed to 80% of its size and released springs back
    # when elastic, and keeps 0.8 / (1 - eps) of its size when its springs yield at strain eps
    far = Ground([0.0, 0.0, -100.0], [0.0, 0.0, 1.0])
    rng = np.random.default_rng(2)
    x_rest = rng.uniform(0.3, 0.7, (40, 3))
    cfg = PhysicsConfig(springs=springs, n_c=12, log10_k_init=2.0, zeta0=2.0)
    model = build_spring_model(x_rest, 12, cfg)
    params = PhysParams.init(model, cfg, v0=(0.0, 0.0, 0.0), gravity=(0.0, 0.0, 0.0))
    centre = x_rest.mean(0)
    squeezed = SimState.from_numpy(centre + 0.8 * (x_rest - centre), np.zeros_like(x_rest))
    rest = _size(x_rest)
    elastic = rollout(model, params, squeezed, far, 40, 1 / 30, cfg, n_substeps=50)[-1].numpy()[0]
    assert _size(elastic) / rest == pytest.approx(1.0, abs=0.01)
    eps = 0.05
    states = rollout(model, params, squeezed, far, 40, 1 / 30, replace(cfg, plastic_yield_strain=eps), n_substeps=50)
    plastic = states[-1].numpy()[0]
    assert _size(plastic) / rest == pytest.approx(0.8 / (1 - eps), abs=0.01)
    lengths = np.linalg.norm(plastic[:, None] - plastic[R.model_numpy(model)["spring_j"]], axis=-1)
    final_rest = np.asarray(states[-1].rest.numpy(), np.float64).reshape(lengths.shape)
    assert np.abs(lengths / final_rest - 1).max() <= eps + 1e-4  # no spring strained beyond the yield


def test_plasticity_gradients_recorded_ad_against_finite_differences_and_gather_refuses():
    from sgdr.physics.model import PhysicsInputError

    def loss(log10_k, adjoint="recorded", grad=True):
        model, params, state0, cfg = _scene("project", plastic_yield_strain=0.01)
        cfg = replace(cfg, adjoint=adjoint)
        params.log10_k = type(params.log10_k)(np.full(40, log10_k, np.float32))
        if grad:
            dr.enable_grad(params.log10_k)
        states = rollout(model, params, state0, GROUND, 3, 1 / 30, cfg, n_substeps=20)
        x = states[-1].x
        value = dr.sum(dr.squared_norm(x - dr.mean(x, axis=None)))
        if grad:
            dr.backward(value)
            return float(value[0]), float(dr.sum(dr.grad(params.log10_k))[0])
        return float(value[0])

    _, g = loss(1.5)
    h = 0.02
    fd = (loss(1.5 + h, grad=False) - loss(1.5 - h, grad=False)) / (2 * h)
    assert g == pytest.approx(fd, rel=0.05, abs=1e-6)
    assert abs(fd) > 1e-5  # the stiffness acts on this loss
    with pytest.raises(PhysicsInputError, match="physics.adjoint=recorded"):
        loss(1.5, adjoint="gather")


def test_contact_restitution_makes_a_dropped_body_rebound():
    # a body dropped onto the ground under the official project contact: with the extension its
    # centre of mass rises higher after the impact
    ground = Ground([0.0, 0.0, 0.0], [0.0, 0.0, 1.0])
    rng = np.random.default_rng(4)
    x_rest = rng.uniform(0.0, 0.1, (30, 3)) + [0.0, 0.0, 0.05]
    cfg = PhysicsConfig(contact="project", n_c=8, log10_k_init=3.0, friction_init=0.9, zeta0=0.5)
    model = build_spring_model(x_rest, 8, cfg)
    params = PhysParams.init(model, cfg, v0=(0.0, 0.0, -1.5), gravity=(0.0, 0.0, -9.8))
    state0 = SimState.at_rest(model, params.v0)

    def heights(e):
        states = rollout(model, params, state0, ground, 16, 1 / 60, replace(cfg, contact_restitution=e), n_substeps=100)
        return np.array([s.numpy()[0][:, 2].mean() for s in states])

    def apex(h):  # the highest point after the lowest one (the springs rebound the body too)
        low = int(np.argmin(h))
        return h[low:].max()

    dead, bouncy = heights(0.0), heights(0.6)
    assert apex(bouncy) > apex(dead) + 0.005  # the impact's rebound adds to the springs' own
    assert np.argmin(bouncy) <= np.argmin(dead)  # and turns the fall around no later
