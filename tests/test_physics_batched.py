"""Batched rollouts (sgdr/physics/batched.py): a batch of S samples equals S single
`sgdr.physics.rollout` calls with the same parameters, for every springs variant and contact
model; unstable samples are flagged without disturbing the others; S = 1 works; the replicated
topology keeps the copies apart; batched Gaussian centres equal `IDWBinding.apply` per frame."""

import drjit as dr
import numpy as np
import pytest
from physics_variants import CONTACT_MODELS, spring_variants

from sgdr.arrays import to_numpy
from sgdr.backend import ad
from sgdr.physics import Ground, PhysicsConfig, PhysicsInputError, PhysParams, SimState, build_spring_model, rollout
from sgdr.physics.batched import batched_centres, batched_rollout, replicate_model
from sgdr.skin import IDWBinding

N_A, N_K, N_FRAMES, N_SUB, DT = 48, 8, 5, 40, 1 / 24
GROUND = Ground([0.0, 0.0, 0.0], [0.0, 0.0, 1.0])
SIZE = 0.2  # the object's extent: tolerances are relative to it


def asset(springs="directed", contact="project", **overrides):
    """48 anchors in a 0.2-wide box 0.02 above the ground, non-uniform log10 k_i around 2."""
    rng = np.random.default_rng(3)
    cfg = PhysicsConfig(springs=springs, contact=contact, n_c=3, retry_on_nan=False, **overrides)
    model = build_spring_model(rng.uniform(0.0, SIZE, (N_A, 3)) + [0.3, 0.3, 0.02], N_K, cfg)
    params = PhysParams.init(model, cfg, v0=(0.3, 0.0, -1.0))
    params.log10_k = ad().Float(rng.uniform(1.7, 2.3, N_A).astype(np.float32))
    dr.make_opaque(params)
    return cfg, model, params


def samples(n):
    rng = np.random.default_rng(5)
    return {
        "dlog10_k": rng.uniform(-0.3, 0.3, n),
        "kappa": rng.uniform(-1.0, 1.0, n),
        "friction": rng.uniform(0.0, 1.0, n),
        "restitution": rng.uniform(0.0, 0.9, n),
        "zeta0": rng.uniform(0.0, 0.3, n),
        "v0": rng.normal(0.0, 1.0, (n, 3)) + [0.0, 0.0, -1.0],
    }


def single(model, base, cfg, values: dict, s: int, n_substeps=N_SUB) -> np.ndarray:
    """The single rollout of sample s: [T, N_A, 3]."""
    t = ad()
    p = base.detach()
    if "dlog10_k" in values:
        p.log10_k = t.Float(to_numpy(base.log10_k, np.float32) + np.float32(values["dlog10_k"][s]))
    for name in ("kappa", "friction", "restitution", "zeta0"):
        if name in values:
            setattr(p, name, t.Float(float(values[name][s])))
    if "v0" in values:
        p.v0 = t.Array3f(*map(float, values["v0"][s]))
    dr.make_opaque(p)
    states = rollout(model, p, SimState.at_rest(model, p.v0), GROUND, N_FRAMES, DT, cfg, n_substeps=n_substeps)
    assert states.n_substeps == n_substeps
    return np.stack([s.numpy()[0] for s in states])


@pytest.mark.parametrize("contact", CONTACT_MODELS)
@pytest.mark.parametrize("springs,rule", spring_variants())
def test_batch_equals_single_rollouts(springs, rule, contact):
    cfg, model, base = asset(springs, contact, symmetric_stiffness=rule)
    values = samples(4)
    out = batched_rollout(model, base, values, GROUND, N_FRAMES, DT, N_SUB, cfg)
    assert out.positions.shape == (4, N_FRAMES, N_A, 3)
    assert out.stable.all() and out.cfl_ok.all() and out.finite.all()
    assert out.n_substeps == N_SUB
    rest = to_numpy(model.x_rest).T
    for s in range(4):
        np.testing.assert_allclose(out.positions[s, 0], rest, atol=1e-7)
        np.testing.assert_allclose(out.positions[s], single(model, base, cfg, values, s), atol=1e-5 * SIZE, rtol=0)
    # the samples differ (the comparison would not notice parameters mixed up between copies)
    # and the object reaches the ground (the contact's μ, e matter)
    last = out.positions[:, -1]
    assert np.min([np.abs(last[a] - last[b]).max() for a in range(4) for b in range(a)]) > 1e-3
    assert out.positions[:, -1, :, 2].min() < 1e-4


def test_unstable_sample_is_flagged_and_others_unchanged():
    cfg, model, base = asset("directed", "project")
    values = samples(4)
    values["dlog10_k"][1] = 5.0  # k ~ 1e7 with 40 substeps per frame: far beyond the bound
    values["kappa"][3] = np.nan  # a NaN parameter is unstable too
    out = batched_rollout(model, base, values, GROUND, N_FRAMES, DT, N_SUB, cfg)
    np.testing.assert_array_equal(out.stable, [True, False, True, False])
    np.testing.assert_array_equal(out.cfl_ok, [True, False, True, False])
    assert np.isnan(out.positions[[1, 3]]).all()
    for s in (0, 2):
        np.testing.assert_allclose(out.positions[s], single(model, base, cfg, values, s), atol=1e-5 * SIZE, rtol=0)


def test_blow_up_past_a_lenient_bound_is_flagged_by_finiteness():
    # cfl_factor 1e3 lets the huge-k sample past the pre-check: it must be caught by NaN/inf
    cfg, model, base = asset("symmetric", "coulomb", cfl_factor=1e3)
    values = samples(3)
    values["dlog10_k"][2] = 6.0
    out = batched_rollout(model, base, values, GROUND, N_FRAMES, DT, N_SUB, cfg)
    np.testing.assert_array_equal(out.cfl_ok, [True, True, True])
    np.testing.assert_array_equal(out.finite, [True, True, False])
    np.testing.assert_array_equal(out.stable, [True, True, False])
    for s in (0, 1):
        np.testing.assert_allclose(out.positions[s], single(model, base, cfg, values, s), atol=1e-5 * SIZE, rtol=0)


def test_frozen_frames_replay_what_the_traced_substeps_compute():
    """The frozen per-frame stepper (the default) against tracing every substep: the first call
    of a width records, the next ones replay the kernels with other parameters, another model of
    the same size and another physics setting (a new recording), all equal to the traced rollouts."""
    from sgdr.physics.batched import _frozen_frame

    before, frames = _frozen_frame.n_recordings, 0
    variants = (("directed", "project", {}), ("directed", "project", {}), ("symmetric", "coulomb", {"air_drag": 0.5}))
    for springs, contact, extra in variants:
        cfg, model, base = asset(springs, contact, **extra)
        for scale in (1.0, 0.5):
            values = samples(3)
            values["dlog10_k"] *= scale
            values["friction"] *= scale
            frozen = batched_rollout(model, base, values, GROUND, N_FRAMES, DT, N_SUB, cfg)
            traced = batched_rollout(model, base, values, GROUND, N_FRAMES, DT, N_SUB, cfg, freeze=False)
            np.testing.assert_allclose(frozen.positions, traced.positions, atol=1e-6 * SIZE, rtol=0)
            frames += N_FRAMES - 1
    assert 1 <= _frozen_frame.n_recordings - before < frames
    # once a model's layout is recorded (its first frame and the rest, literals made opaque: a
    # few calls), calls with other sample values only replay
    counts = []
    for sign in (-1.0, 1.0, -0.5, 0.5, -0.25):
        values = samples(3)
        values["kappa"] *= sign
        frozen = batched_rollout(model, base, values, GROUND, N_FRAMES, DT, N_SUB, cfg)
        counts.append(_frozen_frame.n_recordings)
        traced = batched_rollout(model, base, values, GROUND, N_FRAMES, DT, N_SUB, cfg, freeze=False)
        np.testing.assert_allclose(frozen.positions, traced.positions, atol=1e-6 * SIZE, rtol=0)
    assert counts[-1] == counts[-2] == counts[-3], counts


def test_single_sample_with_base_values():
    cfg, model, base = asset("symmetric", "project")
    values = {"friction": np.array([0.4])}  # everything else from the base parameters
    out = batched_rollout(model, base, values, GROUND, N_FRAMES, DT, None, cfg)
    assert out.positions.shape == (1, N_FRAMES, N_A, 3) and out.stable.all()
    assert out.n_substeps == cfg.n_substeps
    ref = single(model, base, cfg, values, 0, n_substeps=cfg.n_substeps)
    np.testing.assert_allclose(out.positions[0], ref, atol=1e-5 * SIZE, rtol=0)
    assert np.abs(ref[-1] - ref[0]).max() > 1e-2  # it moved


def test_replicated_topology_keeps_copies_apart():
    cfg, model, _ = asset()
    rep = replicate_model(model, 3)
    assert replicate_model(model, 3) is rep  # cached
    j = to_numpy(rep.spring_j, np.int64).reshape(3 * N_A, N_K)
    copy_of_source = np.arange(3 * N_A)[:, None] // N_A
    np.testing.assert_array_equal(j // N_A, np.broadcast_to(copy_of_source, j.shape))
    np.testing.assert_array_equal(j % N_A, np.tile(to_numpy(model.spring_j, np.int64).reshape(N_A, N_K), (3, 1)))
    # the incoming lists: in_spring[in_offset[a]:in_offset[a+1]] are exactly the springs pointing at a
    in_spring, in_offset = to_numpy(rep.in_spring, np.int64), to_numpy(rep.in_offset, np.int64)
    flat = j.reshape(-1)
    for a in (0, N_A - 1, N_A, 2 * N_A + 5, 3 * N_A - 1):
        got = np.sort(in_spring[in_offset[a] : in_offset[a + 1]])
        np.testing.assert_array_equal(got, np.flatnonzero(flat == a))
    assert in_offset[-1] == 3 * N_A * N_K


def test_sample_errors_name_the_field():
    cfg, model, base = asset()
    with pytest.raises(PhysicsInputError, match="unknown field"):
        batched_rollout(model, base, {"mu": np.zeros(2)}, GROUND, 2, DT, N_SUB, cfg)
    with pytest.raises(PhysicsInputError, match=r"samples\['v0'\]"):
        batched_rollout(model, base, {"kappa": np.zeros(2), "v0": np.zeros((3, 3))}, GROUND, 2, DT, N_SUB, cfg)


@pytest.mark.parametrize("form", ["official", "displacement"])
def test_batched_centres_equal_binding_per_frame(form):
    cfg, model, base = asset()
    rng = np.random.default_rng(9)
    rest_anchors = to_numpy(model.x_rest).T
    binding = IDWBinding.build(rng.uniform(0.3, 0.5, (30, 3)), rest_anchors, n_b=4, p_b=2.0, form=form)
    out = batched_rollout(model, base, samples(3), GROUND, 3, DT, N_SUB, cfg)
    centres = batched_centres(binding, out.positions)
    assert centres.shape == (3, 3, 30, 3)
    t = ad()
    for s in range(3):
        for f in range(3):
            x = out.positions[s, f].astype(np.float32)
            ref = to_numpy(binding.apply(t.Array3f(*x.T))).T
            np.testing.assert_allclose(centres[s, f], ref, atol=1e-6, rtol=0)
    assert np.abs(centres[:, -1] - centres[:, 0]).max() > 1e-2


def plain_values(params) -> dict:
    """`asset()`'s parameters as the sampler's rollouts take them (`Asset.values`)."""
    return {
        "log10_k": to_numpy(params.log10_k).astype(float),
        "kappa": 0.0,
        "friction": 0.5,
        "restitution": 0.0,
        "v0": np.array([0.3, 0.0, -1.0]),
        "gravity": np.array([0.0, 0.0, -9.8]),
    }


def test_the_sampler_contract_is_the_same_batched_or_looped():
    """posterior.rollout=batched and =loop return the same positions and stability for the
    sampler's sample dict (log10_k_shift relative to the asset's plain values)."""
    from sgdr.posterior.rollouts import ROLLOUTS

    cfg, model, params = asset(contact="coulomb")
    base = plain_values(params)
    s = samples(5)
    theta = {"log10_k_shift": s["dlog10_k"], "kappa": s["kappa"], "friction": s["friction"]}
    theta["restitution"] = s["restitution"]
    theta["log10_k_shift"][2] = 3.0  # far too stiff for N_SUB substeps: unstable in both
    runs = {name: ROLLOUTS[name](model, base, theta, GROUND, N_FRAMES, DT, N_SUB, cfg) for name in ("batched", "loop")}
    (pb, sb), (pl, sl) = runs["batched"], runs["loop"]
    assert list(sb) == list(sl) == [True, True, False, True, True]
    assert np.nanmax(np.abs(pb[sb] - pl[sl])) < 1e-5 * SIZE


def test_samples_past_the_bound_are_retried_batched_with_doubled_substeps(monkeypatch):
    """posterior.rollout=batched re-runs a sample stiffer than n_t allows in a batch of its own
    with n_t doubled (the single rollout's remedy), not one by one: it equals the loop's
    rollout; one beyond physics.max_substeps and one with a NaN parameter stay unstable."""
    import sgdr.posterior.rollouts as R

    cfg, model, params = asset(contact="coulomb")
    cfg.retry_on_nan, cfg.max_substeps = True, 4 * N_SUB
    base = plain_values(params)
    probe = batched_rollout(model, params, {"dlog10_k": np.array([0.0])}, GROUND, 2, DT, N_SUB, cfg)
    need0 = int(probe.need_substeps[0])
    assert need0 <= N_SUB
    # k scales the bound's n_t by sqrt(10^shift): past n_t, within 2 n_t; past 4 n_t
    mid = 2 * np.log10(1.5 * N_SUB / need0)
    theta = {"log10_k_shift": np.array([0.0, mid, mid + 1.5, 0.1]), "kappa": np.array([0.0, 0.0, 0.0, np.nan])}
    need = batched_rollout(
        model, params, {"dlog10_k": theta["log10_k_shift"][:3]}, GROUND, 2, DT, N_SUB, cfg
    ).need_substeps
    assert N_SUB < need[1] <= 2 * N_SUB and need[2] > 4 * N_SUB, need
    loop = R.loop_rollout(model, base, {k: v[:3] for k, v in theta.items()}, GROUND, N_FRAMES, DT, N_SUB, cfg)
    calls = []
    real = R._batches
    monkeypatch.setattr(R, "loop_rollout", lambda *a, **k: pytest.fail("the batched rollout fell back to the loop"))
    monkeypatch.setattr(R, "_batches", lambda *a, **k: calls.append(a[3]) or real(*a, **k))
    pos, stable = R.ROLLOUTS["batched"](model, base, theta, GROUND, N_FRAMES, DT, N_SUB, cfg)
    assert stable.tolist() == [True, True, False, False] and loop[1].tolist() == [True, True, False]
    assert calls == [N_SUB, 2 * N_SUB]  # the sample beyond max_substeps and the NaN one are not run again
    np.testing.assert_allclose(pos[:2], loop[0][:2], atol=1e-4 * SIZE, rtol=0)  # float32, 2 n_t substeps
    assert np.isnan(pos[~stable]).all()


def test_the_extensions_settings_changed_call_to_call_replay_what_the_loop_computes():
    """The diagnosis's candidates (sgdr.discrepancy, diagnose.rollout=batched) change a physics
    setting from one rollout to the next, read as Python floats inside the frozen frame: each new
    value must give a new recording, never a replay of the last one's constants."""
    from dataclasses import replace

    from sgdr.posterior.rollouts import ROLLOUTS

    cfg, model, params = asset(contact="coulomb")
    base = plain_values(params)
    one = {"log10_k_shift": np.zeros(1)}
    settings = (
        {},
        {"air_drag": 2.0},
        {"air_drag": 1.0},
        {"gravity_scale": 0.85},
        {"ground_offset": 0.01},
        {"ground_tilt_deg": 3.0, "ground_tilt_azimuth_deg": 30.0},
        {"plastic_yield_strain": 0.02},
        {"plastic_yield_strain": 0.05},
        {},
    )
    seen = []
    for s in settings:
        c = replace(cfg, **s)
        (pb, sb), (pl, sl) = (
            ROLLOUTS[n](model, base, one, GROUND, N_FRAMES, DT, N_SUB, c) for n in ("batched", "loop")
        )
        assert sb[0] and sl[0], s
        assert np.abs(pb - pl).max() < 1e-5 * SIZE, s
        seen.append(pb[0, -1])
    # the settings do move the object (else the check above would be empty)
    assert min(np.abs(a - seen[0]).max() for a in seen[1:-1]) > 1e-4 * SIZE
    np.testing.assert_allclose(seen[-1], seen[0], atol=1e-6 * SIZE)
