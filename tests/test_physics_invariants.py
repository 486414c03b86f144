"""Physical invariants of the spring-mass simulator (energy, momentum, free fall, rest, a bar
with a stiff and a soft half) and the errors it raises on bad input."""

import drjit as dr
import numpy as np
import pytest

from sgdr.physics import (
    Ground,
    PhysicsConfig,
    PhysicsInputError,
    PhysParams,
    SimState,
    SimulationUnstable,
    build_spring_model,
    rollout,
    simulate_frame,
    stable_substeps,
    with_masses,
)
from sgdr.physics import reference as R
from tests.physics_variants import CONTACT_MODELS, LAWS

FAR = Ground([0.0, 0.0, -100.0], [0.0, 0.0, 1.0])  # a ground nothing reaches


def _lattice(n=(5, 5, 5), h=0.03, origin=(0.4, 0.4, 0.0)):
    axes = [np.arange(k) * h for k in n]
    return np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3) + np.asarray(origin)


def _random_k(params, rng, lo, hi):
    params.log10_k = type(params.log10_k)(rng.uniform(lo, hi, dr.width(params.log10_k)).astype(np.float32))


def _energy(m: dict, p: dict, x, v, cfg):
    """Kinetic + elastic energy of Hookean symmetric springs (p_k = 0): Σ ½ (k_s η / l) Δl²."""
    j, l = m["spring_j"], m["spring_rest_length"]
    k = 10.0 ** p["log10_k"]
    k_s = 2 * k[:, None] * k[j] / (k[:, None] + k[j])
    eta = R.soft_vector(p["kappa"], j.shape[1], m["n_c"], cfg.soft_vector_normalised)[None, :]
    dl = np.linalg.norm(x[:, None, :] - x[j], axis=-1) - l
    return 0.5 * np.sum(m["particle_mass"][:, None] * v * v) + 0.5 * np.sum(k_s * eta / l * dl * dl)


def test_undamped_hookean_conserves_energy():
    rng = np.random.default_rng(0)
    x_rest = rng.uniform(0.3, 0.7, (60, 3))
    cfg = PhysicsConfig(spring_law="paper", p_k=0.0, springs="symmetric", zeta0=0.0, n_c=4)
    model = build_spring_model(x_rest, 10, cfg)
    params = PhysParams.init(model, cfg, gravity=(0.0, 0.0, 0.0))
    _random_k(params, rng, 1.0, 2.0)
    x0 = x_rest + rng.normal(0.0, 0.01, x_rest.shape)
    n_sub = 10 * stable_substeps(model, params, 1 / 30, cfg)  # dt a tenth of the stability bound
    n_sub = max(n_sub, 100)
    states = rollout(model, params, SimState.from_numpy(x0, np.zeros_like(x0)), FAR, 11, 1 / 30, cfg, n_substeps=n_sub)
    m, p = R.model_numpy(model), R.params_numpy(params)
    energies = np.array([_energy(m, p, *s.numpy(), cfg) for s in states])
    kinetic = [0.5 * np.sum(s.numpy()[1] ** 2) for s in states]
    assert 10 * n_sub >= 1000
    assert max(kinetic) > 0.3 * energies[0]  # energy really moves between kinetic and elastic
    assert np.abs(energies - energies[0]).max() < 0.01 * energies[0]


@pytest.mark.parametrize("law", LAWS)
def test_symmetric_springs_conserve_momentum(law):
    rng = np.random.default_rng(1)
    x_rest = rng.uniform(0.3, 0.7, (60, 3))
    masses = rng.uniform(0.5, 2.0, 60)

    def momentum_drift(springs):
        cfg = PhysicsConfig(spring_law=law, springs=springs, zeta0=0.2, n_c=4)
        model = with_masses(build_spring_model(x_rest, 10, cfg), masses)
        params = PhysParams.init(model, cfg, gravity=(0.0, 0.0, 0.0))
        _random_k(params, np.random.default_rng(2), 1.0, 2.5)
        x0 = x_rest + rng.normal(0.0, 0.01, x_rest.shape)
        v0 = rng.normal(0.0, 0.5, x_rest.shape)
        states = rollout(model, params, SimState.from_numpy(x0, v0), FAR, 6, 1 / 30, cfg, n_substeps=100)
        p = np.array([(masses[:, None] * s.numpy()[1]).sum(0) for s in states])
        return np.abs(p - p[0]).max() / np.sum(masses[:, None] * np.abs(v0))

    assert momentum_drift("symmetric") < 1e-5
    assert momentum_drift("directed") > 1e-3  # the official directed springs do not conserve it


def test_dropped_object_falls_as_g_t2_over_2_until_contact():
    x_rest = _lattice(origin=(0.4, 0.4, 0.5))
    cfg = PhysicsConfig(n_c=8)
    model = build_spring_model(x_rest, 16, cfg)
    gravity = np.array([0.0, -2.0, -9.8])
    params = PhysParams.init(model, cfg, gravity=gravity)
    ground = Ground([0.0, 0.0, 0.2], [0.0, 0.0, 1.0])
    fps, n_sub = 30, 50
    states = rollout(model, params, SimState.at_rest(model, params.v0), ground, 12, 1 / fps, cfg, n_substeps=n_sub)
    com0 = x_rest.mean(0)
    t_contact = np.sqrt(2 * 0.3 / 9.8)
    dt = 1 / (fps * n_sub)
    n_checked = 0
    for f, s in enumerate(states):
        t = f / fps
        x = s.numpy()[0]
        if t < t_contact:
            # semi-implicit Euler lags the exact parabola by g t dt / 2 at most
            err = np.abs(x.mean(0) - (com0 + 0.5 * gravity * t * t)).max()
            assert err <= 0.5 * np.linalg.norm(gravity) * t * dt + 1e-5, (f, err)
            n_checked += 1
        else:
            assert x[:, 2].min() >= 0.2 - 1e-6  # the ground stops it
    assert n_checked >= 6 and min(s.numpy()[0][:, 2].min() for s in states) < 0.2 + 1e-3  # it got there


@pytest.mark.parametrize("contact", CONTACT_MODELS)
def test_object_at_rest_on_ground_stays_put(contact):
    """Symmetric springs: after settling under gravity nothing moves or slides. (Directed
    springs drift sideways once sagged, since their internal forces do not cancel.)"""
    x_rest = _lattice()
    cfg = PhysicsConfig(
        springs="symmetric",
        contact=contact,
        zeta0=1.0,
        n_c=8,
        restitution_init=0.5,
        friction_init=0.9 if contact == "project" else 0.5,
    )
    model = build_spring_model(x_rest, 16, cfg)
    params = PhysParams.init(model, cfg)
    states = rollout(
        model, params, SimState.at_rest(model, params.v0), Ground([0, 0, 0], [0, 0, 1]), 31, 1 / 30, cfg, n_substeps=40
    )
    xs = [s.numpy()[0] for s in states]
    com = np.array([x.mean(0) for x in xs])
    assert np.abs(com[:, :2] - com[0, :2]).max() < 1e-4  # no sideways drift
    assert np.abs(xs[-1] - xs[20]).max() < 1e-5  # settled: no jitter
    assert min(x[:, 2].min() for x in xs) >= -1e-6  # never below the ground
    assert 0 < com[0, 2] - com[-1, 2] < 0.01  # it sags a little under its weight


def test_stiffer_half_of_a_bar_strains_less():
    """A bar standing on the ground: the load on each half depends only on the weight above, so
    swapping which half is stiff compares the two halves under the same load.

    Symmetric springs only: with the official directed springs the invariant does not hold
    (where stiff and soft anchors meet, the stiff ones push harder than the soft ones push back,
    an unbalanced internal force that compresses the stiff half more; see docs/physics-variants.md, "Findings")."""
    x_rest = _lattice(n=(3, 3, 12), h=0.03, origin=(0.5, 0.5, 0.0))
    cfg = PhysicsConfig(springs="symmetric", zeta0=3.0, n_c=12)
    model = build_spring_model(x_rest, 16, cfg)
    z = x_rest[:, 2]
    bottom = z < z.max() / 2
    mid = np.unique(z)[6]

    def layer(x, level):
        return x[np.isclose(z, level), 2].mean()

    def strains(log10_k):
        params = PhysParams.init(model, cfg, gravity=(0.0, 0.0, -2.0))
        params.log10_k = type(params.log10_k)(log10_k.astype(np.float32))
        x = rollout(
            model,
            params,
            SimState.at_rest(model, params.v0),
            Ground([0, 0, 0], [0, 0, 1]),
            20,
            1 / 30,
            cfg,
            n_substeps=120,
        )[-1].numpy()[0]
        low = 1 - (layer(x, mid) - layer(x, 0.0)) / mid
        high = 1 - (layer(x, z.max()) - layer(x, mid)) / (z.max() - mid)
        return low, high

    stiff_bottom = strains(np.where(bottom, 3.5, 2.5))
    stiff_top = strains(np.where(bottom, 2.5, 3.5))
    assert min(stiff_bottom + stiff_top) > 0  # every half is compressed
    assert stiff_bottom[0] < 0.5 * stiff_top[0]  # bottom half: stiff strains less than soft
    assert stiff_top[1] < 0.5 * stiff_bottom[1]  # top half: likewise


# --------------------------------------------------------------------------------------------
# Stability: the bound checked before running, and the official retry
# --------------------------------------------------------------------------------------------


def _small(cfg):
    x_rest = np.random.default_rng(4).uniform(0.3, 0.7, (40, 3))
    model = build_spring_model(x_rest, 8, cfg)
    return model, PhysParams.init(model, cfg)


def test_too_large_dt_is_refused_naming_the_setting():
    cfg = PhysicsConfig(log10_k_init=4.0, retry_on_nan=False, n_c=4)
    model, params = _small(cfg)
    need = stable_substeps(model, params, 1 / 30, cfg)
    assert need > 2
    with pytest.raises(SimulationUnstable, match=r"n_substeps"):
        simulate_frame(model, params, SimState.at_rest(model, params.v0), FAR, 1 / 30, need - 1, cfg)
    with pytest.raises(SimulationUnstable, match=r"n_substeps"):
        rollout(model, params, SimState.at_rest(model, params.v0), FAR, 3, 1 / 30, cfg, n_substeps=need - 1)
    # with the official remedy the rollout raises the substep count itself
    cfg.retry_on_nan = True
    cfg.max_substeps = 8 * need
    states = rollout(model, params, SimState.at_rest(model, params.v0), FAR, 3, 1 / 30, cfg, n_substeps=need - 1)
    assert np.all(np.isfinite(states[-1].numpy()[0]))


def test_nan_triggers_retry_with_more_substeps():
    # a bound loose enough to let a blow-up through: NaN/inf must be caught after the frame
    cfg = PhysicsConfig(log10_k_init=4.0, cfl_factor=1e4, retry_on_nan=False, n_c=4)
    model, params = _small(cfg)
    x0 = model.numpy()["x_rest"] * 1.05
    start = SimState.from_numpy(x0, np.zeros_like(x0))
    with pytest.raises(SimulationUnstable, match=r"NaN/inf"):
        rollout(model, params, start, FAR, 4, 1 / 30, cfg, n_substeps=16)
    cfg.retry_on_nan, cfg.max_substeps = True, 1024
    states = rollout(model, params, start, FAR, 4, 1 / 30, cfg, n_substeps=16)
    assert all(np.all(np.isfinite(s.numpy()[0])) for s in states)


# --------------------------------------------------------------------------------------------
# Bad input
# --------------------------------------------------------------------------------------------


def test_bad_input_raises_clear_errors():
    cfg = PhysicsConfig(n_c=4)
    x_rest = np.random.default_rng(5).uniform(0.3, 0.7, (20, 3))
    with pytest.raises(PhysicsInputError, match=r"n_k=20 must be smaller than the number of anchors N_A=20"):
        build_spring_model(x_rest, 20, cfg)
    with pytest.raises(PhysicsInputError, match=r"x_rest must have shape \[N, 3\]"):
        build_spring_model(x_rest[:, :2], 4, cfg)
    bad = x_rest.copy()
    bad[3, 1] = np.nan
    with pytest.raises(PhysicsInputError, match=r"x_rest contains NaN"):
        build_spring_model(bad, 4, cfg)
    with pytest.raises(PhysicsInputError, match=r"coincides"):
        build_spring_model(np.vstack([x_rest, x_rest[:1]]), 4, cfg)
    with pytest.raises(PhysicsInputError, match=r"physics.m0=0.0 must be positive"):
        build_spring_model(x_rest, 4, PhysicsConfig(m0=0.0))
    model = build_spring_model(x_rest, 4, cfg)
    with pytest.raises(PhysicsInputError, match=r"masses must be finite and positive"):
        with_masses(model, -np.ones(20))
    with pytest.raises(PhysicsInputError, match=r"masses has 19 entries, expected N_A=20"):
        with_masses(model, np.ones(19))
    params = PhysParams.init(model, cfg)
    state = SimState.at_rest(model, params.v0)

    wrong = PhysParams.init(build_spring_model(x_rest[:10], 4, cfg), cfg)
    with pytest.raises(PhysicsInputError, match=r"PhysParams.log10_k has 10 entries, expected N_A=20"):
        simulate_frame(model, wrong, state, FAR, 1 / 30, 10, cfg)
    small_state = SimState.from_numpy(x_rest[:10], np.zeros((10, 3)))
    with pytest.raises(PhysicsInputError, match=r"SimState.x has 10 entries, expected N_A=20"):
        simulate_frame(model, params, small_state, FAR, 1 / 30, 10, cfg)
    with pytest.raises(PhysicsInputError, match=r"SimState.v has 19 rows, expected 20"):
        SimState.from_numpy(x_rest, np.zeros((19, 3)))
    nan_x = x_rest.copy()
    nan_x[0, 0] = np.inf
    t = type(params.v0)
    with pytest.raises(PhysicsInputError, match=r"SimState.x contains NaN/inf"):
        simulate_frame(model, params, SimState(x=t(*nan_x.T.astype(np.float32)), v=state.v), FAR, 1 / 30, 10, cfg)
    params.kappa = type(params.kappa)(float("nan"))
    with pytest.raises(PhysicsInputError, match=r"PhysParams.kappa contains NaN"):
        simulate_frame(model, params, state, FAR, 1 / 30, 10, cfg)
    params = PhysParams.init(model, cfg)
    with pytest.raises(PhysicsInputError, match=r"dt_frame=-0.1 must be a positive"):
        simulate_frame(model, params, state, FAR, -0.1, 10, cfg)
    with pytest.raises(PhysicsInputError, match=r"physics.contact='bounce' is not a known contact model"):
        simulate_frame(model, params, state, FAR, 1 / 30, 10, PhysicsConfig(contact="bounce", n_c=4))
    with pytest.raises(PhysicsInputError, match=r"Ground.normal has zero length"):
        Ground([0, 0, 0], [0, 0, 0])
