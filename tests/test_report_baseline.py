"""Report files (video, plots, PLY) and the physics-free baseline."""

import numpy as np
import pytest

from sgdr.evaluate.baselines import physics_free_predictions
from sgdr.report.media import (
    labelled_pair,
    plot_losses,
    plot_metric_curves,
    plot_stiffness,
    read_points_ply,
    tile,
    write_frame_plys,
    write_points_ply,
    write_video,
)


def test_pair_layout():
    gt, pred = np.full((8, 10, 3), 1.0), np.zeros((8, 10, 4))
    pair = labelled_pair(gt, pred, min_height=24, header=16)  # enlarged 3x, titled
    assert pair.shape == (16 + 24, 2 * 30 + 1, 3) and pair.dtype == np.uint8
    assert pair[20, 0, 0] == 255 and pair[20, 31, 0] == 0  # ground truth left, prediction right
    assert pair[:16].max() > 200  # the titles are drawn in white
    assert tile([np.zeros((4, 4, 3))] * 5).shape == (2 * 4 + 2, 3 * 4 + 2 * 2, 3)


def test_video_roundtrip(tmp_path):
    import imageio.v3 as iio

    frames = [np.full((15, 21, 3), i / 5.0) for i in range(5)]
    path = write_video(tmp_path / "v.mp4", frames, fps=10)
    back = iio.imread(path)
    assert back.shape[0] == 5 and back.shape[1:3] == (16, 22)
    assert abs(float(back[4, :15, :21].mean()) - 0.8 * 255) < 6  # grey levels survive H.264


def test_plots_are_written(tmp_path, rng):
    p = plot_losses(tmp_path / "loss.png", {"dynamic": [1.0, 0.5, 0.25], "v0": [2.0, 1.0]}, {"dynamic": "pass"})
    q = plot_stiffness(tmp_path / "k.png", rng.random((50, 3)), 3 + rng.random(50), (0.0, 7.0))
    per_frame = {"cd": [1.0, 2.0, None], "psnr": [30.0, 25.0, 20.0], "baseline_cd": {"still": [None, None, 1.5]}}
    r = plot_metric_curves(tmp_path / "m.png", per_frame, 2)
    for f in (p, q, r):
        assert f.stat().st_size > 5000 and f.read_bytes()[:4] == b"\x89PNG"
    with pytest.raises(ValueError, match="no per-frame score"):
        plot_metric_curves(tmp_path / "none.png", {"cd": [None], "psnr": []}, 1)


def test_ply_roundtrip(tmp_path, rng):
    pts = rng.random((40, 3))
    write_points_ply(tmp_path / "a.ply", pts, colors=rng.random((40, 3)))
    np.testing.assert_allclose(read_points_ply(tmp_path / "a.ply"), pts, atol=1e-6)
    paths = write_frame_plys(tmp_path / "frames", [pts, pts + 1], "centres")
    assert [p.name for p in paths] == ["centres_000.ply", "centres_001.ply"]
    np.testing.assert_allclose(read_points_ply(paths[1]), pts + 1, atol=1e-6)


def test_baselines_follow_their_definitions():
    last = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 1.2]])
    prev = last - np.array([0.1, 0.0, 0.0])  # moved 0.1 in x over one frame
    dt, g = 0.1, np.array([0.0, 0.0, -9.8])
    out = physics_free_predictions(prev, last, 3, dt, g, np.zeros(3), np.array([0, 0, 1.0]))
    np.testing.assert_allclose(out["still"][2], last)
    np.testing.assert_allclose(out["constant_velocity"][1], last + [0.2, 0, 0])
    t = 0.1
    np.testing.assert_allclose(out["ballistic"][0], last + [0.1, 0, -0.5 * 9.8 * t * t])
    # at t = 0.3 the parabola drops 0.441 and the lowest point (z = 1.0) stays above the ground
    np.testing.assert_allclose(out["ballistic"][2][:, 2], last[:, 2] - 0.5 * 9.8 * 0.09)


def test_baseline_is_kept_above_the_ground():
    last = np.array([[0.0, 0.0, 0.05], [0.0, 0.0, 0.3]])
    out = physics_free_predictions(last, last, 10, 0.1, np.array([0, 0, -9.8]), np.zeros(3), np.array([0, 0, 2.0]))
    assert out["ballistic"][-1][:, 2] == pytest.approx([0.0, 0.25])
