"""The diagnosis candidates' own arithmetic (sgdr/discrepancy/candidates.py): the v0 refitted
with a gravity or drag candidate keeps the base's free fall, the two-stiffness field splits the
anchors at the median, every candidate's null is the base model, and the search finds a known
minimum in one and several values."""

import numpy as np
import pytest

from sgdr.discrepancy.candidates import CANDIDATES, NULL_TOLERANCE, Context, _fall_basis, _search, halves, refit_v0
from sgdr.physics import PhysicsConfig


def _ctx(**physics):
    rng = np.random.default_rng(0)
    anchors = rng.uniform(0.0, 1.0, (50, 3))
    values = {
        "log10_k": np.full(50, 3.0),
        "kappa": 0.0,
        "friction": 0.5,
        "restitution": 0.0,
        "v0": np.array([0.4, -0.2, -1.0]),
        "gravity": np.array([0.0, 0.0, -9.8]),
    }
    return Context(values, PhysicsConfig(**physics), anchors, 1.7, np.arange(1, 6) / 24.0)


def _fall(v0, g, scale, drag, t):
    phi, psi = _fall_basis(drag, t)
    return phi[:, None] * v0 + scale * psi[:, None] * g


def test_the_refitted_v0_keeps_the_base_free_fall():
    ctx = _ctx()
    t = ctx.free_fall_times
    base = _fall(ctx.values["v0"], ctx.values["gravity"], 1.0, 0.0, t)
    np.testing.assert_allclose(refit_v0(ctx, 1.0, 0.0), ctx.values["v0"], atol=1e-12)  # the null changes nothing
    for scale, drag in ((0.8, 0.0), (1.2, 0.0), (1.0, 3.0), (0.9, 1.5)):
        v0 = refit_v0(ctx, scale, drag)
        kept = np.abs(_fall(v0, ctx.values["gravity"], scale, drag, t) - base).max()
        unchanged = np.abs(_fall(ctx.values["v0"], ctx.values["gravity"], scale, drag, t) - base).max()
        assert kept < 0.5 * unchanged, (scale, drag)

        def sse(v, scale=scale, drag=drag):
            return float(((_fall(v, ctx.values["gravity"], scale, drag, t) - base) ** 2).sum())

        for e in np.eye(3) * 1e-3:  # the least-squares optimum
            assert sse(v0) <= min(sse(v0 + e), sse(v0 - e))
        assert v0[2] != pytest.approx(ctx.values["v0"][2])
    # a weaker gravity needs a faster downward start to pass through the same positions
    assert refit_v0(ctx, 0.8, 0.0)[2] < ctx.values["v0"][2]
    np.testing.assert_allclose(refit_v0(ctx, 0.8, 0.0)[:2], ctx.values["v0"][:2], atol=1e-12)  # g is along z only


def test_without_free_fall_frames_v0_is_kept():
    ctx = _ctx()
    ctx.free_fall_times = np.zeros(0)
    np.testing.assert_array_equal(refit_v0(ctx, 0.7, 2.0), ctx.values["v0"])


def test_drag_basis_tends_to_the_drag_free_one():
    t = np.linspace(0.0, 0.5, 11)
    phi, psi = _fall_basis(1e-6, t)
    np.testing.assert_allclose(phi, t, atol=1e-5)
    np.testing.assert_allclose(psi, 0.5 * t * t, atol=1e-5)


def test_halves_split_at_the_median():
    anchors = np.random.default_rng(1).normal(size=(101, 3))
    for axis in range(3):
        h = halves(anchors, axis)
        assert set(np.unique(h)) == {-1.0, 1.0}
        assert abs(int(h.sum())) <= 1
        assert anchors[h > 0, axis].min() > anchors[h < 0, axis].max()


@pytest.mark.parametrize("name", sorted(CANDIDATES))
def test_every_candidate_at_its_null_is_the_base_model(name):
    cand = CANDIDATES.get_named(name)
    ctx = _ctx()
    x = {p.name: p.null for p in cand.params}
    for variant in cand.variants:
        settings, values = cand.apply(ctx, x, variant)
        cfg = PhysicsConfig(**{k: v for k, v in settings.items() if k != "plastic_yield_strain"})
        base = PhysicsConfig()
        for k in ("air_drag", "gravity_scale", "ground_offset", "ground_tilt_deg", "contact_restitution"):
            assert getattr(cfg, k) == pytest.approx(getattr(base, k)), (name, k)
        if "plastic_yield_strain" in settings:  # 10^-0.1 = 0.79: no spring of a drop strains that far
            assert settings["plastic_yield_strain"] > 0.75
        for k, v in values.items():
            np.testing.assert_allclose(v, ctx.values[k], atol=1e-12, err_msg=f"{name}: {k}")
        assert all(p.low <= p.null <= p.high for p in cand.params), name


@pytest.mark.parametrize("name", sorted(CANDIDATES))
def test_a_value_within_the_null_tolerance_is_at_null_and_one_beyond_is_not(name):
    """A candidate fitted at its null value is the base model (run_diagnosis then keeps the base's
    losses): within 1% of each value's box from the null, in object sizes for lengths."""
    cand = CANDIDATES.get_named(name)
    size = 0.4
    null = {p.name: p.null * (size if p.relative else 1.0) for p in cand.params}
    assert cand.at_null(null, size)
    for p in cand.params:
        box = (p.high - p.low) * (size if p.relative else 1.0)
        inward = 1.0 if p.null < p.high else -1.0  # plasticity's null is its box's upper end
        near = {**null, p.name: null[p.name] + inward * 0.5 * NULL_TOLERANCE * box}
        far = {**null, p.name: null[p.name] + inward * 2.0 * NULL_TOLERANCE * box}
        assert cand.at_null(near, size), (name, p.name)
        assert not cand.at_null(far, size), (name, p.name)


def test_the_two_stiffness_field_has_the_ratio_between_halves():
    cand = CANDIDATES.get_named("heterogeneous_stiffness")
    ctx = _ctx()
    _, values = cand.apply(ctx, {"log10_ratio": 0.6}, 2)
    k = values["log10_k"]
    up = halves(ctx.anchors, 2) > 0
    assert k[up].mean() - k[~up].mean() == pytest.approx(0.6)
    assert k.mean() == pytest.approx(3.0, abs=0.01)  # the mean stiffness is kept


def test_the_search_finds_a_known_minimum_in_one_and_three_values():
    calls = []

    def f(x):
        calls.append(x.copy())
        return float(np.sum((x - np.array([0.3, -0.5, 0.1])[: x.size]) ** 2))

    x1 = _search(f, [(-1.0, 1.0)], np.zeros(1), 16)
    assert x1[0] == pytest.approx(0.3, abs=0.01)
    x3 = _search(f, [(-1.0, 1.0)] * 3, np.zeros(3), 16)
    np.testing.assert_allclose(x3, [0.3, -0.5, 0.1], atol=0.02)  # separable: one sweep finds it
    assert len(calls) <= 4 * 16
    tight = _search(f, [(0.5, 1.0)], np.zeros(1), 16)
    assert tight[0] == pytest.approx(0.5, abs=0.01)  # within the bounds


def test_the_ground_tilt_candidate_maps_its_tilt_vector():
    cand = CANDIDATES.get_named("ground_tilt")
    settings, _ = cand.apply(_ctx(), {"tilt_a_deg": 3.0, "tilt_b_deg": 4.0, "offset": 0.01}, None)
    assert settings["ground_tilt_deg"] == pytest.approx(5.0)
    assert settings["ground_tilt_azimuth_deg"] == pytest.approx(np.degrees(np.arctan2(4.0, 3.0)))
    assert settings["ground_offset"] == pytest.approx(0.01)


def test_the_tilt_search_starts_from_the_fitted_offset():
    """Where the object lands, a tilt and an offset both move the ground: from offset 0 the first
    tilt sweep stands in for the offset; started from the offset the plane fitted (starts_from),
    it finds the tilt."""
    from types import SimpleNamespace

    from sgdr.discrepancy.candidates import fit_candidate

    cand = CANDIDATES.get_named("ground_tilt")
    assert cand.starts_from == "ground_plane"
    truth = {"tilt": 5.0, "offset": 0.02}

    def d(settings, _obs, _repl=None):
        tilt = settings.get("ground_tilt_deg", 0.0) * np.cos(np.radians(settings.get("ground_tilt_azimuth_deg", 0.0)))
        off = settings.get("ground_offset", 0.0)
        height = off + 0.004 * tilt  # the ground under the landing point
        return 1e4 * (height - (truth["offset"] + 0.004 * truth["tilt"])) ** 2 + 0.01 * (tilt - truth["tilt"]) ** 2

    ev = SimpleNamespace(d=d, obs_fit="fit", obs_held="held", obs_future=None, obs_time=None)
    cold = fit_candidate(ev, cand, _ctx(), 16)
    warm = fit_candidate(ev, cand, _ctx(), 16, start={"offset": 0.021, "unknown": 1.0})
    assert warm.values["tilt_a_deg"] == pytest.approx(5.0, abs=0.5), warm.values
    assert abs(cold.values["tilt_a_deg"] - 5.0) > 2.0, cold.values  # what the cold start gave
    assert warm.d_fit < cold.d_fit
    assert warm.evaluated[0][1]["offset"] == pytest.approx(0.021)  # the search began there


def test_downscaled_cameras_match_block_means():
    from sgdr.cameras import Camera
    from sgdr.observe.images import block_mean, downscale_factor, downscaled

    cam = Camera.look_at([1.5, -1.0, 1.2], [0.0, 0.0, 0.2], [0, 0, 1], 40.0, 128, 96, "c")
    k = downscale_factor(cam.width, cam.height, 64)
    assert k == 2 and downscale_factor(32, 32, 64) == 1
    small = downscaled(cam, k)
    assert (small.width, small.height) == (64, 48)
    pts = np.random.default_rng(0).normal(0.0, 0.2, (20, 3)) + [0.0, 0.0, 0.2]
    uv, _ = cam.project(pts)
    uv_small, _ = small.project(pts)
    np.testing.assert_allclose(uv_small, uv / k, atol=1e-9)  # a point in block i of the large image is in pixel i
    img = np.random.default_rng(1).uniform(size=(96, 128, 4))
    b = block_mean(img, 2)
    assert b.shape == (48, 64, 4) and b[3, 5, 1] == pytest.approx(img[6:8, 10:12, 1].mean())


def test_the_excess_gain_is_a_share_of_the_room_above_the_floor():
    from sgdr.discrepancy.decision import excess_gain

    assert excess_gain(6.0, 10.0, 2.0) == pytest.approx(0.5)  # half of the 8 above the floor removed
    assert excess_gain(2.0, 10.0, 2.0) == pytest.approx(1.0)
    assert excess_gain(10.0, 10.0, 2.0) == 0.0 and excess_gain(12.0, 10.0, 2.0) < 0
    assert excess_gain(float("inf"), 10.0, 2.0) == -float("inf")
    # a base at its floor: a chance improvement of 0.1% is a small share of the 5% margin
    assert excess_gain(0.999, 1.0, 1.0) == pytest.approx(0.02)
    assert excess_gain(6.0, 10.0, None) == pytest.approx(0.4)  # no floor: the relative gain


def test_the_evaluator_simulates_the_fit_frames_for_a_search_and_the_rest_when_asked():
    """A search's rollouts stop at the last fit frame (fit and held-out views see only those);
    the future frames are simulated once a fit is judged on them, the fit frames then read from
    the longer rollout; an unstable short rollout is not run again longer."""
    from types import SimpleNamespace

    from sgdr.discrepancy.candidates import Evaluator

    calls = []

    def rollout(model, values, samples, ground, n_frames, dt, n_sub, cfg):
        calls.append(n_frames)
        pos = np.zeros((1, n_frames, 2, 3))
        pos[0, :, :, 2] = np.arange(n_frames)[:, None] * cfg.air_drag
        return pos, np.array([cfg.air_drag < 5.0])

    asset = SimpleNamespace(
        values={}, physics=PhysicsConfig(), fps=24.0, n_substeps=10, ground_point=[0, 0, 0], ground_normal=[0, 0, 1]
    )
    asset.build = lambda: (None, None)
    obs = lambda frames: SimpleNamespace(frames=np.asarray(frames))  # noqa: E731
    fit, held, future = obs(range(1, 20)), obs(range(1, 20)), obs(range(20, 30))
    score = lambda o, pos: pos[o.frames, :, 2].sum(axis=1, keepdims=True).T  # noqa: E731
    ev = Evaluator(asset, rollout, fit, held, future, score)
    assert ev.d({"air_drag": 1.0}, fit) == pytest.approx(sum(range(1, 20)) * 2)
    assert ev.d({"air_drag": 1.0}, held) == pytest.approx(sum(range(1, 20)) * 2)
    assert calls == [20]  # one rollout of the fit frames for both views
    assert ev.d({"air_drag": 1.0}, future) == pytest.approx(sum(range(20, 30)) * 2)
    assert calls == [20, 30]
    assert ev.positions({"air_drag": 1.0}).shape[0] == 30 and calls == [20, 30]
    assert ev.d({"air_drag": 6.0}, fit) == float("inf") and ev.d({"air_drag": 6.0}, future) == float("inf")
    assert calls == [20, 30, 20]


def test_the_held_out_time_is_a_share_of_the_fit_frames_with_two_left_to_fit():
    from sgdr.discrepancy.run import held_out_time_frames

    assert held_out_time_frames(20, 0.25, "seq") == 5  # small: frames 15-19 held out, 1-14 fitted
    assert held_out_time_frames(8, 0.25, "seq") == 2  # tiny: 6-7 held out, 1-5 fitted
    assert held_out_time_frames(20, 0.0, "seq") == 0
    assert held_out_time_frames(4, 0.01, "seq") == 1  # at least one frame
    with pytest.raises(ValueError, match="seq.*diagnose.held_out_time=0.5"):
        held_out_time_frames(4, 0.5, "seq")


def test_tied_falls_part_after_more_frames_and_a_sideways_throw_would_part_them():
    """A weaker gravity and drag fitted to the same four frames of fall differ by a fraction of a
    pixel there; a longer fall parts them, later the smaller the images; identical models never
    part; the sideways speed that would show the drag is the one that moves a pixel by the end."""
    from sgdr.cameras import Camera
    from sgdr.discrepancy.candidates import _fall_basis
    from sgdr.discrepancy.separate import separating_frames

    fps, g = 24.0, np.array([0.0, 0.0, -9.8])
    t = np.arange(1, 5) / fps
    c = 2.0  # drag 2 /s; the weaker gravity that fits its first four frames (v0 = 0) in least squares
    phi, psi = _fall_basis(c, t)
    z_drag = psi * -9.8
    basis = np.stack([t, 0.5 * t * t * -9.8], axis=1)  # z = w t + s (-9.8) t²/2
    w, s = np.linalg.lstsq(basis, z_drag, rcond=None)[0]
    models = {"gravity": (s, 0.0, np.array([0.0, 0.0, w])), "air_drag": (1.0, c, np.zeros(3))}
    cams = [Camera.look_at([3.0, 0.0, 0.5], [0.0, 0.0, 0.5], [0.0, 0.0, 1.0], 40.0, w_px, w_px) for w_px in (64, 512)]
    small, large = (separating_frames(models, g, [cam], np.array([0.0, 0.0, 0.5]), fps, 4) for cam in cams)
    assert small["pixels_within_observed"] < 1.0
    assert small["free_flight_frames"] > 4 and large["free_flight_frames"] < small["free_flight_frames"]
    same = separating_frames({"a": models["gravity"], "b": models["gravity"]}, g, cams[:1], np.zeros(3), fps, 4)
    assert same["free_flight_frames"] is None and same["sideways_speed"] is None
    u = small["sideways_speed"]
    lag = 4 / fps - _fall_basis(c, np.array([4 / fps]))[0][0]
    uv = cams[0].project(np.array([[0.0, 0.0, 0.5], [0.0, u * lag, 0.5]]))[0]
    assert np.linalg.norm(uv[1] - uv[0]) == pytest.approx(1.0, rel=0.05)


def test_a_tie_between_free_flight_fits_is_told_what_would_separate_it():
    """`run.separate_mimics` reads each tied fit's gravity scale, drag and v0 as the fit applied them
    (the base's where a fit leaves one unchanged) and the window's last observed frame."""
    from types import SimpleNamespace

    from sgdr.cameras import Camera
    from sgdr.discrepancy.run import separate_mimics

    cam = Camera.look_at([3.0, 0.0, 0.5], [0.0, 0.0, 0.5], [0.0, 0.0, 1.0], 40.0, 256, 256)
    o = SimpleNamespace(
        asset=SimpleNamespace(anchors=np.zeros((4, 3)) + [0.0, 0.0, 0.5], fps=24.0), seq=SimpleNamespace(cameras=[cam])
    )
    ctx = SimpleNamespace(physics=PhysicsConfig())
    refit = ({"v0": np.array([0.5, 0.0, 0.0]), "gravity": np.array([0.0, 0.0, -9.8])}, {}, {})
    applied = {
        "gravity": ("refit", {"gravity_scale": 0.9}, {"v0": np.array([0.5, 0.0, -0.05])}),
        "air_drag": ("refit", {"air_drag": 1.5}, {}),
    }
    out = separate_mimics(["gravity", "air_drag"], applied, refit, ctx, o, {"record": {"frames": [1, 2, 3, 4]}})
    assert out["candidates"] == ["gravity", "air_drag"] and out["observed_frames"] == 4
    assert out["free_flight_frames"] is not None and out["free_flight_frames"] >= 1
    assert out["sideways_speed"] is not None and out["sideways_speed"] > 0
