"""Anchor sampling (voxel, fps) and the IDW binding (Eq. 14): weights, exactness at rest,
equivariance, gradients against the explicit NumPy weight matrix."""

import drjit as dr
import numpy as np
import pytest

from sgdr.anchors import AnchorInputError, sample_anchors, voxel_downsample
from sgdr.arrays import array3_to_points
from sgdr.skin import IDWBinding, idw_weights


def _cloud(m=3000, seed=0):
    return np.random.default_rng(seed).uniform(0.3, 0.7, (m, 3))


@pytest.mark.parametrize("sampler", ["voxel", "fps"])
def test_sampling_is_seeded_and_inside(sampler):
    pts = _cloud()
    a = sample_anchors(pts, 200, sampler, 0.02, seed=1)
    b = sample_anchors(pts, 200, sampler, 0.02, seed=1)
    c = sample_anchors(pts, 200, sampler, 0.02, seed=2)
    assert a.shape == (200, 3) and np.array_equal(a, b) and not np.array_equal(a, c)
    assert len(np.unique(a, axis=0)) == 200
    assert np.all(a >= pts.min(0) - 1e-12) and np.all(a <= pts.max(0) + 1e-12)


def test_voxel_sampler_returns_voxel_centroids():
    pts = _cloud()
    centres = voxel_downsample(pts, 0.05)
    keys = np.floor(pts / 0.05).astype(int)
    k0 = keys[0]
    assert np.allclose(centres, voxel_downsample(pts[::-1], 0.05))  # order independent
    assert any(np.allclose(c, pts[(keys == k0).all(1)].mean(0)) for c in centres)
    a = sample_anchors(pts, 100, "voxel", 0.05, seed=0)
    assert all(np.isclose(np.abs(centres - x).sum(1), 0).any() for x in a)
    # too few voxels at the asked size: the voxel edge is halved until there are enough
    assert sample_anchors(pts, 1500, "voxel", 0.2, seed=0).shape == (1500, 3)


def test_fps_spreads_better_than_random():
    pts = _cloud()
    fps = sample_anchors(pts, 64, "fps", 0.0, seed=0)
    rand = pts[np.random.default_rng(0).choice(len(pts), 64, replace=False)]

    def min_gap(p):
        d = np.linalg.norm(p[:, None] - p[None], axis=-1)
        return d[~np.eye(len(p), dtype=bool)].min()

    assert min_gap(fps) > 2 * min_gap(rand)


def test_sampling_bad_input():
    with pytest.raises(AnchorInputError, match=r"n_anchors=10 must be in \[1, M=5\]"):
        sample_anchors(_cloud(5), 10, "fps", 0.1, 0)
    with pytest.raises(AnchorInputError, match=r"anchors.sampler='poisson' is not a known anchor sampler"):
        sample_anchors(_cloud(), 10, "poisson", 0.1, 0)
    with pytest.raises(AnchorInputError, match=r"shape \[M, 3\]"):
        sample_anchors(_cloud()[:, :2], 10, "fps", 0.1, 0)


def _binding(form, m=500, n_a=80, n_b=8, p_b=0.5):
    rng = np.random.default_rng(3)
    centres = rng.uniform(0.3, 0.7, (m, 3))
    anchors = sample_anchors(centres, n_a, "fps", 0.0, seed=0)
    return centres, anchors, IDWBinding.build(centres, anchors, n_b, p_b, form)


def _dense_weights(centres, anchors, n_b, p_b):
    idx, w = idw_weights(centres, anchors, n_b, p_b)
    W = np.zeros((len(centres), len(anchors)))
    np.put_along_axis(W, idx, w, axis=1)
    return W


def test_idw_weights_sum_to_one_nearest_heaviest():
    centres, anchors, _ = _binding("official")
    idx, w = idw_weights(centres, anchors, 8, 0.5)
    assert np.allclose(w.sum(1), 1.0) and np.all(w > 0)
    assert np.all(np.diff(w, axis=1) <= 1e-12)  # nearest first, weights 1/d^p_b decrease
    d = np.linalg.norm(centres[:, None] - anchors[idx], axis=-1)
    apart = d[:, 0] > 1e-6
    assert 0 < apart.sum() < len(d)  # some Gaussians sit exactly on an anchor (fps picks centres)
    assert np.allclose(w[apart, 0] / w[apart, -1], (d[apart, -1] / d[apart, 0]) ** 0.5)
    assert np.all(w[~apart, 0] > 0.99)  # distance floored: the coincident anchor takes it all


@pytest.mark.parametrize("form", ["official", "displacement"])
def test_idw_apply_forward(form):
    centres, anchors, binding = _binding(form)
    t = type(binding.rest_centres)
    W = _dense_weights(centres, anchors, 8, 0.5)
    rest = array3_to_points(binding.apply(t(*anchors.T.astype(np.float32))))
    if form == "displacement":
        assert np.abs(rest - centres).max() < 1e-6  # exact at rest
    else:
        assert np.abs(rest - W @ anchors).max() < 1e-6
        assert np.abs(rest - centres).max() > 1e-3  # the official form moves frame 0
    # moved anchors: both forms follow the weighted anchor motion
    moved = anchors + np.random.default_rng(1).normal(0, 0.05, anchors.shape)
    out = array3_to_points(binding.apply(t(*moved.T.astype(np.float32))))
    expect = centres + W @ (moved - anchors) if form == "displacement" else W @ moved
    assert np.abs(out - expect).max() < 1e-5
    shifted = array3_to_points(binding.apply(t(*(moved + [0.1, -0.2, 0.3]).T.astype(np.float32))))
    assert np.abs(shifted - out - [0.1, -0.2, 0.3]).max() < 1e-5  # translation equivariant


@pytest.mark.parametrize("form", ["official", "displacement"])
def test_idw_apply_gradient(form):
    centres, anchors, binding = _binding(form)
    t = type(binding.rest_centres)
    x = t(*anchors.T.astype(np.float32))
    dr.enable_grad(x)
    cot = np.random.default_rng(2).normal(size=centres.shape)
    out = binding.apply(x)
    dr.backward(dr.sum(dr.dot(out, t(*cot.T.astype(np.float32)))))
    grad = array3_to_points(dr.grad(x))
    W = _dense_weights(centres, anchors, 8, 0.5)
    assert np.abs(grad - W.T @ cot).max() < 1e-4 * np.abs(W.T @ cot).max()


def test_idw_bad_input():
    centres, anchors, binding = _binding("official")
    t = type(binding.rest_centres)
    with pytest.raises(AnchorInputError, match=r"anchor_x has 79 entries, binding has N_A=80"):
        binding.apply(t(*anchors[:-1].T.astype(np.float32)))
    with pytest.raises(AnchorInputError, match=r"anchors.binding='nearest' is not a known IDW binding form"):
        IDWBinding.build(centres, anchors, 8, 0.5, "nearest")
    with pytest.raises(AnchorInputError, match=r"n_b=100 must be in \[1, N_A=80\]"):
        IDWBinding.build(centres, anchors, 100, 0.5)
