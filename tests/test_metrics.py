"""Evaluation metrics on analytic cases and against independent references."""

import itertools

import numpy as np
import pytest
from skimage.metrics import peak_signal_noise_ratio

from sgdr.evaluate import chamfer_distance, earth_movers_distance, earth_movers_distances, psnr, ssim, subsample


def _grid(n: int, h: float) -> np.ndarray:
    """[n³, 3] points of a cubic grid with spacing h."""
    g = np.arange(n) * h
    return np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)


def test_identical_sets_score_zero(rng):
    p = rng.random((5000, 3))
    assert chamfer_distance(p, p) == 0.0
    assert earth_movers_distance(p[:300], p[:300]) == 0.0


def test_chamfer_of_a_small_shift_is_twice_its_square():
    # Spacing 0.05, shift 0.01 < spacing / 2: every point's nearest neighbour is its twin.
    a = _grid(12, 0.05)
    d = np.array([0.006, -0.008, 0.0])  # |d| = 0.01
    assert chamfer_distance(a, a + d) == pytest.approx(2 * 0.01**2 * 1e3, rel=1e-9)


def test_chamfer_subsamples_8192_points_and_is_seeded(rng):
    a, b = rng.random((20000, 3)), rng.random((15000, 3))
    assert subsample(a, 8192, seed=3).shape == (8192, 3)
    assert chamfer_distance(a, b, seed=3) == chamfer_distance(a, b, seed=3)
    assert chamfer_distance(a, b, seed=3) != chamfer_distance(a, b, seed=4)


def test_emd_of_a_translation_is_its_length(rng):
    # For any permutation σ, Σ|x_i + d - x_σ(i)| >= |Σ(x_i + d - x_σ(i))| = n|d|: identity wins.
    a = rng.random((400, 3))
    d = np.array([0.3, -0.1, 0.2])
    assert earth_movers_distance(a, a + d) == pytest.approx(np.linalg.norm(d), rel=1e-9)


def test_emd_matches_brute_force_over_permutations(rng):
    for _ in range(5):
        a, b = rng.random((6, 3)), rng.random((6, 3))
        cost = np.linalg.norm(a[:, None] - b[None], axis=-1)
        best = min(cost[np.arange(6), list(p)].mean() for p in itertools.permutations(range(6)))
        assert earth_movers_distance(a, b) == pytest.approx(best, rel=1e-12)


def test_emd_by_network_simplex_equals_the_exact_assignment(rng, monkeypatch):
    from scipy.optimize import linear_sum_assignment

    import sgdr.evaluate.geometry as geometry

    def by_scipy(a, b):
        cost = np.linalg.norm(a[:, None] - b[None], axis=-1)
        rows, cols = linear_sum_assignment(cost)
        return cost[rows, cols].mean()

    # uniform, and a deformed copy (near-ties, as consecutive frames of one object give)
    a = rng.random((700, 3))
    cases = [(a, rng.random((700, 3))), (a, a * [1.0, 1.1, 0.8] + 0.01 * rng.standard_normal(a.shape))]
    for x, y in cases:
        assert earth_movers_distance(x, y, n_points=700) == pytest.approx(by_scipy(x, y), rel=1e-9)
    # unequal sizes: the smaller set matched entirely (scipy's partial assignment)
    x, y = rng.random((300, 3)), rng.random((450, 3))
    assert earth_movers_distance(x, y) == pytest.approx(by_scipy(x, y), rel=1e-12)
    # a simplex stopped short of optimal is not trusted: the exact assignment is used
    monkeypatch.setattr(geometry, "EMD_SIMPLEX_MAX_ITERATIONS", 3)
    x, y = cases[0]
    assert earth_movers_distance(x, y, n_points=700) == pytest.approx(by_scipy(x, y), rel=1e-12)


def test_emd_of_many_pairs_on_workers_equals_the_serial_calls(rng):
    # Subsampling included (600 > n_points): the workers must draw the same seeded subsets.
    pairs = [(rng.random((600, 3)), rng.random((500, 3)) + 0.1 * k) for k in range(3)]
    serial = [earth_movers_distance(a, b, n_points=256, seed=2) for a, b in pairs]
    assert earth_movers_distances(pairs, n_points=256, seed=2, workers=2) == serial
    assert earth_movers_distances(pairs, n_points=256, seed=2, workers=1) == serial
    with pytest.raises(ValueError, match="emd gt"):
        earth_movers_distances([(pairs[0][0], np.zeros((0, 3)))], workers=2)


def test_metrics_name_bad_input():
    with pytest.raises(ValueError, match="chamfer pred"):
        chamfer_distance(np.zeros((4, 2)), np.zeros((4, 3)))
    with pytest.raises(ValueError, match="emd gt"):
        earth_movers_distance(np.zeros((4, 3)), np.zeros((0, 3)))


def test_psnr_analytic_and_matches_scikit_image(rng):
    a = rng.random((24, 32, 3))
    assert psnr(np.clip(a, 0, 0.9), np.clip(a, 0, 0.9) + 0.1) == pytest.approx(20.0, abs=1e-9)
    b = np.clip(a + 0.05 * rng.standard_normal(a.shape), 0, 1)
    assert psnr(b, a) == pytest.approx(peak_signal_noise_ratio(a, b, data_range=1.0), rel=1e-12)
    assert psnr(a, a) == float("inf")


def _ssim_reference(a: np.ndarray, b: np.ndarray) -> float:
    """Wang et al. (2004) SSIM written out: 11x11 Gaussian window (σ = 1.5), population
    statistics, C1 = (0.01)², C2 = (0.03)², mean over pixels at least 5 from the border
    (where the window fits) and over channels."""
    r = np.arange(-5, 6)
    g = np.exp(-(r**2) / (2 * 1.5**2))
    w = np.outer(g, g) / np.outer(g, g).sum()  # [11, 11]
    H, W, _ = a.shape
    vals = []
    for c in range(3):
        x, y = a[..., c], b[..., c]
        for i in range(5, H - 5):
            for j in range(5, W - 5):
                px, py = x[i - 5 : i + 6, j - 5 : j + 6], y[i - 5 : i + 6, j - 5 : j + 6]
                mx, my = (w * px).sum(), (w * py).sum()
                vx = (w * px * px).sum() - mx * mx
                vy = (w * py * py).sum() - my * my
                cxy = (w * px * py).sum() - mx * my
                c1, c2 = 0.01**2, 0.03**2
                vals.append(((2 * mx * my + c1) * (2 * cxy + c2)) / ((mx * mx + my * my + c1) * (vx + vy + c2)))
    return float(np.mean(vals))


def test_ssim_matches_written_out_formula(rng):
    a = rng.random((20, 23, 3))
    b = np.clip(0.5 * a + 0.5 * rng.random(a.shape), 0, 1)
    assert ssim(b, a) == pytest.approx(_ssim_reference(b, a), abs=1e-9)
    assert ssim(a, a) == pytest.approx(1.0, abs=1e-12)
    assert ssim(b, a) < 0.9
