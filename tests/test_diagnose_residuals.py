"""The residual diagnostics (sgdr/discrepancy/residuals.py) on synthetic data with a known answer:
triangulation of centroids, the free-fall fits (gravity, drag), bounce and sliding, the simulated
silhouette's calibration, the rest shape and the spatial maps; the strict-JSON record and the
plots on a small synthetic sequence (one view, no future, no hit before the end included).
The same numbers on a tiny run and its twins are checked in tests/test_diagnose.py."""

import json
from types import SimpleNamespace

import numpy as np
import pytest

from sgdr.cameras import Camera
from sgdr.discrepancy import residuals as R

FPS = 24.0
G = np.array([0.0, 0.0, -9.8])


def ring_cameras(n: int, target, size: int = 64):
    """n cameras on a circle around target, slightly above it, z up."""
    target = np.asarray(target, float)
    cams = []
    for i in range(n):
        a = 2 * np.pi * i / n
        eye = target + [2.5 * np.cos(a), 2.5 * np.sin(a), 0.8]
        cams.append(Camera.look_at(eye, target, [0, 0, 1], 40.0, size, size, f"v{i}"))
    return cams


def fall(t, s0, v0, g, c):
    """Distance fallen along gravity with linear drag c (1/s); c = 0 is the parabola."""
    if c == 0:
        return s0 + v0 * t + g * t**2 / 2
    return s0 + (g / c) * t + (v0 - g / c) * (1 - np.exp(-c * t)) / c


def test_triangulation_recovers_a_point_from_its_projections():
    x = np.array([0.3, -0.2, 0.6])
    cams = ring_cameras(5, [0, 0, 0.5])
    uv = np.stack([c.project(x[None])[0][0] for c in cams])
    np.testing.assert_allclose(R.triangulate(cams, uv, np.ones(5, bool)), x, atol=1e-9)
    # rays through noisy centroids: the least-squares point is within the noise's reach
    noisy = uv + np.random.default_rng(0).normal(0, 0.3, uv.shape)
    assert np.linalg.norm(R.triangulate(cams, noisy, np.ones(5, bool)) - x) < 0.02
    # a view left out does not matter; one view alone has no point
    keep = np.array([True, False, True, True, False])
    np.testing.assert_allclose(R.triangulate(cams, uv, keep), x, atol=1e-9)
    assert np.isnan(R.triangulate(cams, uv, np.array([True, False, False, False, False]))).all()


def test_parabola_recovers_gravity_and_the_drag_fit_flags_a_slower_fall():
    t = np.arange(9) / FPS
    x = np.zeros((9, 3))
    x[:, 0] = 0.1 * t  # horizontal motion does not enter the fall
    x[:, 2] = 1.0 - fall(t, 0.0, 0.4, 7.0, 0.0)  # a weaker gravity than the recorded 9.8
    ff = R.free_flight(x, G, FPS, hit_frame=9)
    assert ff["frames"] == 9 and ff["reason"] is None
    assert ff["acceleration"] == pytest.approx(7.0, rel=1e-6) and ff["ratio"] == pytest.approx(7.0 / 9.8, rel=1e-6)
    assert ff["rms_parabola"] < 1e-9
    assert ff["horizontal_drag_per_s"] == pytest.approx(0.0, abs=1e-3)  # a weaker gravity leaves it uniform
    x[:, 2] = 1.0 - fall(t, 0.0, 0.4, 9.8, 3.0)  # the recorded gravity with drag 3/s
    x[:, 0] = fall(t, 0.0, 0.1, 0.0, 3.0)  # that slows the horizontal motion too
    ff = R.free_flight(x, G, FPS, hit_frame=9)
    assert ff["drag_per_s"] == pytest.approx(3.0, rel=1e-3)
    assert ff["horizontal_drag_per_s"] == pytest.approx(3.0, rel=1e-3)
    assert ff["ratio"] < 0.85  # the parabola sees a slower fall
    assert ff["rms_drag"] < 1e-3 * ff["rms_parabola"]  # and only the drag model fits its shape
    # with noise: the 95% intervals hold the truth; a fast sideways motion pins the drag down, a
    # slow one does not
    rng = np.random.default_rng(4)
    for speed, narrow in ((3.0, True), (0.02, False)):
        y = x.copy()
        y[:, 0] = fall(t, 0.0, speed, 0.0, 3.0)
        y = y + rng.normal(0, 1e-4, y.shape)
        ff = R.free_flight(y, G, FPS, hit_frame=9)
        lo, hi = ff["horizontal_drag_interval"]
        assert lo <= 3.0 <= hi and ff["drag_interval"][0] <= 3.0 <= ff["drag_interval"][1], ff
        assert (hi - lo < 2.0) == narrow, ff
    x[:, 2] = 1.0 - fall(t, 0.0, 0.4, 9.8, 0.0)
    assert abs(R.free_flight(x, G, FPS, hit_frame=9)["drag_per_s"]) < 1e-3
    # frames at and after the hit are not free fall; too few frames give a reason, not numbers
    short = R.free_flight(x, G, FPS, hit_frame=2)
    assert short["ratio"] is None and "need 3" in short["reason"]
    x[1:4] = np.nan  # unseen frames are left out
    assert R.free_flight(x, G, FPS, hit_frame=9)["frames"] == 6


def test_contact_measures_the_first_rebound_and_the_slide():
    h = np.array([1.0, 0.7, 0.3, 0.1, 0.05, 0.2, 0.3, 0.25, 0.1, 0.12])
    x = np.zeros((h.size, 3))
    x[:, 2] = h + 0.5  # a ground at z = 0.5
    x[:, 0] = np.concatenate([np.zeros(3), 0.1 * np.arange(1, 8)])  # slides from the hit frame on
    c = R.contact(x, [0, 0, 0.5], [0, 0, 1], hit_frame=3)
    assert c["contact_frame"] == 4 and c["apex_frame"] == 6
    assert c["bounce"] == pytest.approx(0.25) and c["sliding"] == pytest.approx(0.6)
    assert R.contact(x, [0, 0, 0.5], [0, 0, 1], hit_frame=9)["bounce"] is None  # no frame after the hit


def disc(size: int, centre, radius: float, squash: float = 1.0) -> np.ndarray:
    yy, xx = np.mgrid[:size, :size] + 0.5
    return ((xx - centre[0]) ** 2 + ((yy - centre[1]) / squash) ** 2) <= radius**2


def test_simulated_silhouette_matches_the_rest_area_and_the_maps_show_where_they_differ():
    cam = ring_cameras(1, [0, 0, 0.5])[0]
    rng = np.random.default_rng(1)
    ball = rng.normal(size=(4000, 3))
    ball = 0.25 * ball / np.linalg.norm(ball, axis=1, keepdims=True) * rng.uniform(0, 1, (4000, 1)) ** (1 / 3)
    centres = np.stack([ball + [0, 0, 0.5], ball + [0, 0, 0.5] + 0.05 * np.cross([0, 0, 1], cam.R[2])])  # [2, P, 3]
    uv0 = cam.project(centres[0])[0]
    radius = np.sqrt(np.ptp(uv0[:, 0]) * np.ptp(uv0[:, 1]) / np.pi) / 2 * 1.6
    obs = np.stack([disc(64, uv0.mean(0), radius), disc(64, uv0.mean(0), radius)])  # observed: does not move
    sim, levels = R.simulated_masks([cam], centres, [obs])
    assert abs(int(sim[0][0].sum()) - int(obs[0].sum())) <= 0.05 * obs[0].sum()  # calibrated on frame 0
    iou = (sim[0][0] & obs[0]).sum() / (sim[0][0] | obs[0]).sum()
    assert iou > 0.85
    maps, disagree = R.spatial([obs], sim, np.array([1]), grid=64)
    shift = cam.project(centres[1])[0].mean(0) - uv0  # where the simulated object moved in the image
    cols = np.arange(64) + 0.5
    obs_only, sim_only = maps[0][..., 0].sum(0), maps[0][..., 1].sum(0)  # per column
    sign = np.sign(shift.mean(0)[0])
    assert sign * (cols @ sim_only / sim_only.sum() - cols @ obs_only / obs_only.sum()) > 3  # on opposite sides
    assert 0.1 < disagree[0] < 1.0


def test_simulated_silhouette_of_a_receding_object_shrinks_like_the_observed_one():
    cam = ring_cameras(1, [0, 0, 0.5], size=96)[0]
    rng = np.random.default_rng(3)
    ball = rng.normal(size=(300, 3))  # sparse: the smoothing closes the gaps between centres
    ball = 0.3 * ball / np.linalg.norm(ball, axis=1, keepdims=True) * rng.uniform(0, 1, (300, 1)) ** (1 / 3)
    away = cam.R[2]  # the viewing direction
    centres = np.stack([ball + [0, 0, 0.5], ball + [0, 0, 0.5] + 2.0 * away])  # [2, P, 3], depth 2.6 -> 4.6
    dense = rng.normal(size=(20000, 3))
    dense = 0.3 * dense / np.linalg.norm(dense, axis=1, keepdims=True) * rng.uniform(0, 1, (20000, 1)) ** (1 / 3)
    obs = np.zeros((2, 96, 96), bool)
    for f, shift in enumerate([0.0, 2.0]):
        uv = cam.project(dense + [0, 0, 0.5] + shift * away)[0].astype(int)
        obs[f, uv[:, 1], uv[:, 0]] = True
    sim, _ = R.simulated_masks([cam], centres, [obs])
    ratio_obs, ratio_sim = obs[1].sum() / obs[0].sum(), sim[0][1].sum() / sim[0][0].sum()
    assert ratio_obs < 0.4  # the object's image shrank by about (2.6 / 4.6)²
    assert ratio_sim == pytest.approx(ratio_obs, rel=0.1)  # a fixed smoothing and level give 0.46 for 0.34


def test_rest_shape_sees_a_permanent_squash_the_simulation_lacks():
    cam = ring_cameras(1, [0, 0, 0.5])[0]
    centre = cam.project(np.array([[0, 0, 0.5]]))[0][0]
    first = disc(64, centre, 10)
    obs = np.stack([first, disc(64, centre, 10, squash=0.5)])  # half as tall after settling
    sim = np.stack([first, first])
    rs = R.rest_shape([cam], [obs], [sim], np.array([0, 0, 0.5]), [0, 0, 1], 0.1)
    assert rs["height_observed"] == pytest.approx(0.5, abs=0.08) and rs["height_simulated"] == pytest.approx(1.0)
    assert rs["width_observed"] == pytest.approx(1.0, abs=0.05)
    assert rs["height_difference"] == pytest.approx(-0.5, abs=0.08)
    cut = obs.copy()
    cut[1, :, 0] = True  # touches the border: no ratio for that view
    assert R.rest_shape([cam], [cut], [sim], np.array([0, 0, 0.5]), [0, 0, 1], 0.1)["per_view"][0]["observed"] is None


class SyntheticSequence(SimpleNamespace):
    def image(self, v, f):
        rgba = np.zeros(self.masks[v].shape[1:] + (4,))
        rgba[..., 3] = self.masks[v][f]
        return rgba


def synthetic(n_views: int, n_frames: int, n_fit: int, hit_frame: int, empty=()):
    """A sequence of one ball falling at recorded gravity, its silhouettes projected from dense
    points, and an asset whose anchors are those points (every centre bound to itself)."""
    cams = ring_cameras(n_views, [0, 0, 0.5], size=128)  # the ball ~30 px across
    rng = np.random.default_rng(2)
    ball = rng.normal(size=(6000, 3))
    ball = 0.2 * ball / np.linalg.norm(ball, axis=1, keepdims=True) * rng.uniform(0, 1, (6000, 1)) ** (1 / 3)
    t = np.arange(n_frames) / FPS
    z = 0.7 - np.minimum(9.8 * t**2 / 2, 0.4)
    positions = ball[None] + np.stack([np.zeros_like(t), np.zeros_like(t), z], axis=1)[:, None]  # [T, P, 3]
    masks = []
    for v, cam in enumerate(cams):
        m = np.zeros((n_frames, cam.height, cam.width), bool)
        for f in range(n_frames):
            if (v, f) in empty:
                continue
            uv = cam.project(positions[f])[0].astype(int)
            ok = (uv >= 0).all(1) & (uv[:, 0] < cam.width) & (uv[:, 1] < cam.height)
            m[f, uv[ok, 1], uv[ok, 0]] = True
        masks.append(m)
    seq = SyntheticSequence(cameras=cams, masks=masks, n_fit=n_fit, n_frames=n_frames, hit_frame=hit_frame,
                            fps=FPS, gravity=G, ground_point=np.zeros(3), ground_normal=np.array([0, 0, 1.0]))  # fmt: skip
    asset = SimpleNamespace(
        rest_centres=ball + [0, 0, 0.7], anchors=ball + [0, 0, 0.7],
        anchor_cfg=SimpleNamespace(n_b=1, p_b=2.0, binding="official"), ground_point=np.zeros(3),
        ground_normal=np.array([0, 0, 1.0]),
    )  # fmt: skip
    return seq, asset, positions


@pytest.mark.parametrize(
    "n_views, n_frames, n_fit, hit, empty",
    [(4, 10, 7, 6, ()), (1, 8, 8, 7, ()), (3, 9, 8, 7, ((0, 3), (1, 3), (2, 3)))],
    ids=["four-views", "one-view-no-future-hit-at-end", "an-unseen-frame"],
)
def test_record_is_strict_json_and_the_plots_are_written(tmp_path, n_views, n_frames, n_fit, hit, empty):
    from sgdr.discrepancy.report import section, write_plots
    from sgdr.evaluate.score import strict_json

    seq, asset, positions = synthetic(n_views, n_frames, n_fit, hit, empty)
    d = np.random.default_rng(0).uniform(0.5, 2.0, (n_views, n_frames))
    d[:, 0] = np.nan
    record, maps = R.residual_diagnostics(seq, asset, positions, d, grid=16)
    record = strict_json(record)
    json.dumps(record, allow_nan=False)
    json.dumps(strict_json(R.summary(record)), allow_nan=False)
    plots = write_plots(record, maps, tmp_path, n_views=2)
    assert all(p.stat().st_size > 1000 for p in plots.values())
    com = record["com"]
    if n_views == 1:  # one view: nothing to triangulate, but the anchors' numbers are there
        assert all(h is None for h in com["height_observed"]) and record["free_flight"]["observed"]["reason"]
        assert record["d"]["mean_future"] is None and record["contact"]["observed"]["bounce"] is None
        assert record["free_flight"]["anchors"]["ratio"] == pytest.approx(1.0, abs=1e-6)
    else:
        seen = [f for f in range(n_frames) if (0, f) not in empty]
        # the observed ball is the simulated one: the same estimator gives the same numbers
        err = np.array([com["error"][f] for f in seen])
        assert np.all(err < 0.01), err
        ff = record["free_flight"]
        assert ff["observed"]["ratio"] == pytest.approx(ff["simulated"]["ratio"], abs=0.02)
        assert ff["observed"]["ratio"] == pytest.approx(1.0, abs=0.1)
    diagnosis = {"cause": "none", "min_gain": 0.1, "sequence": "synthetic", "candidates": {},
                 "base": {"d_fit": 1.0, "d_held_out": 1.0, "d_future": None},
                 "discrepancy": {"measure": "points", "unit": "pixels²"}}  # fmt: skip
    html = section(diagnosis, record, {k: str(v) for k, v in plots.items()}).body
    assert "data:image/png;base64," in html and "Model discrepancy" not in html  # the title is the report's
    assert "discrepancy-ambiguous" not in html
    mimic = {**diagnosis, "cause": "gravity", "ambiguous_with": ["air_drag"], "mimic_margin": 0.05}
    assert "<b>Ambiguous:</b> air_drag fits the data as well" in section(mimic, None, None).body
    cand = {"changes": "", "values": {}, "gain": 0.6, "future_gain": None}
    settled = {**diagnosis, "cause": "air_drag", "settled_among": ["gravity", "air_drag"], "mimic_window_margin": 0.1,
               "candidates": {"gravity": {**cand, "decision": "rejected", "fit_window_gain": 0.737},
                              "air_drag": {**cand, "decision": "cause", "fit_window_gain": 0.933}}}  # fmt: skip
    body = section(settled, None, None).body
    assert "Mimics told apart:</b> gravity fit the free fall" in body
    assert "air_drag explains the whole fit window better" in body
    assert "0.933 against 0.737" in body and "discrepancy-ambiguous" not in body


def test_first_touch_is_the_first_frame_a_point_reaches_the_ground():
    from sgdr.discrepancy.run import first_touch

    t = np.arange(12) / FPS
    z = 0.5 - fall(t, 0.0, 0.0, 9.8, 0.0)  # the lowest point's height over a ground at z = 0
    cube = np.array([[0, 0, 0], [0.2, 0, 0], [0, 0.2, 0], [0, 0, 0.2]], float)
    pos = cube[None] + np.stack([np.zeros(12), np.zeros(12), np.maximum(z, 0.0)], axis=1)[:, None]
    expected = int(np.flatnonzero(z <= 0)[0])
    assert first_touch(pos, [0, 0, 0], [0, 0, 1]) == expected
    assert first_touch(pos, [0, 0, -0.3], [0, 0, 2]) is None  # a lower ground: not reached here
    assert first_touch(None, [0, 0, 0], [0, 0, 1]) is None  # an unstable rollout
    assert first_touch(pos[:1].repeat(3, 0) * 0, [0, 0, 0], [0, 0, 1]) == 1  # resting from the start: no free flight
