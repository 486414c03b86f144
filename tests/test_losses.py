"""Image losses: SSIM against scikit-image, gradients against finite differences, shapes."""

import drjit as dr
import numpy as np
import pytest
from scipy.ndimage import gaussian_filter
from skimage.metrics import structural_similarity

from sgdr.backend import ad
from sgdr.loss import LossError, dssim, image_loss, l1, mask_loss, ssim


def _skimage_ssim(a, b):
    return structural_similarity(
        a, b, gaussian_weights=True, sigma=1.5, use_sample_covariance=False, data_range=1, channel_axis=-1
    )


def _images(rng, h=37, w=45, c=3):
    a = gaussian_filter(rng.uniform(0, 1, (h, w, c)), (2, 2, 0))
    a = (a - a.min()) / (a.max() - a.min())
    b = np.clip(a + 0.1 * rng.normal(size=a.shape) + 0.05, 0, 1)
    return a.astype(np.float32), b.astype(np.float32)


def _val(x):
    return float(np.asarray(x).reshape(-1)[0])


@pytest.mark.parametrize("shape", [(37, 45, 3), (16, 20, 3), (64, 64, 1)])
def test_ssim_matches_skimage(rng, shape):
    a, b = _images(rng, *shape)
    t = ad()
    ours = _val(ssim(t.TensorXf(a), t.TensorXf(b)))
    ref = _skimage_ssim(a.astype(np.float64), b.astype(np.float64))
    assert 0.2 < ref < 0.99
    assert abs(ours - ref) < 1e-4, (ours, ref)


def test_ssim_of_identical_images_is_one(rng):
    a, _ = _images(rng)
    t = ad()
    assert abs(_val(ssim(t.TensorXf(a), t.TensorXf(a))) - 1.0) < 1e-5
    assert abs(_val(dssim(t.TensorXf(a), a))) < 1e-5


def test_zero_border_ssim_matches_numpy(rng):
    """The 3DGS training form: zero-padded Gaussian filtering, mean over the whole image."""
    a, b = (x.astype(np.float64) for x in _images(rng, 24, 30, 3))

    def filt(x):
        return gaussian_filter(x, (1.5, 1.5, 0), mode="constant", cval=0.0, truncate=3.5)

    mu_a, mu_b = filt(a), filt(b)
    va, vb, cab = filt(a * a) - mu_a**2, filt(b * b) - mu_b**2, filt(a * b) - mu_a * mu_b
    c1, c2 = 0.01**2, 0.03**2
    ref = np.mean(((2 * mu_a * mu_b + c1) * (2 * cab + c2)) / ((mu_a**2 + mu_b**2 + c1) * (va + vb + c2)))
    t = ad()
    ours = _val(ssim(t.TensorXf(a.astype(np.float32)), t.TensorXf(b.astype(np.float32)), border="zero"))
    assert abs(ours - ref) < 1e-4, (ours, ref)


def test_ssim_gradient_matches_central_differences_of_skimage(rng):
    a, b = _images(rng, 20, 22, 3)
    t = ad()
    x = t.TensorXf(a)
    dr.enable_grad(x)
    dr.backward(ssim(x, t.TensorXf(b)))
    grad = np.asarray(dr.grad(x))
    eps = 1e-4
    a64, b64 = a.astype(np.float64), b.astype(np.float64)
    for idx in [(10, 11, 0), (5, 7, 2), (14, 9, 1), (0, 0, 0)]:  # (0, 0) is outside the valid region
        hi, lo = a64.copy(), a64.copy()
        hi[idx] += eps
        lo[idx] -= eps
        fd = (_skimage_ssim(hi, b64) - _skimage_ssim(lo, b64)) / (2 * eps)
        assert abs(grad[idx] - fd) < 1e-3 * max(abs(fd), 1e-3) + 2e-7, (idx, grad[idx], fd)
    assert np.abs(grad).max() > 1e-4


def test_l1_image_loss_and_mask_loss(rng):
    a, b = _images(rng)
    t = ad()
    A, B = t.TensorXf(a), t.TensorXf(b)
    assert abs(_val(l1(A, B)) - np.abs(a - b).mean()) < 1e-6
    lam = 0.2
    expect = (1 - lam) * np.abs(a - b).mean() + lam * (1 - _skimage_ssim(a.astype(np.float64), b.astype(np.float64)))
    assert abs(_val(image_loss(A, B, lam)) - expect) < 1e-4
    alpha = rng.uniform(0, 1, (9, 7)).astype(np.float32)
    mask = (rng.uniform(0, 1, (9, 7)) > 0.5).astype(np.float32)
    assert abs(_val(mask_loss(t.TensorXf(alpha), mask)) - np.abs(alpha - mask).mean()) < 1e-6
    # gradients of the weighted loss reach the prediction
    dr.enable_grad(A)
    dr.backward(image_loss(A, B, lam))
    assert np.abs(np.asarray(dr.grad(A))).max() > 0


def test_mismatched_image_sizes_raise(rng):
    t = ad()
    a, _ = _images(rng, 20, 20)
    b, _ = _images(rng, 20, 21)
    with pytest.raises(LossError, match=r"image sizes differ.*\(20, 20, 3\).*\(20, 21, 3\)"):
        image_loss(t.TensorXf(a), t.TensorXf(b), 0.2)
    with pytest.raises(LossError, match="mask"):
        mask_loss(t.TensorXf(a[..., 0]), np.zeros((3, 3, 3, 3), np.float32))
    with pytest.raises(LossError, match="larger than 11x11"):
        ssim(t.TensorXf(a[:8, :8]), t.TensorXf(a[:8, :8]))


@pytest.mark.parametrize("border", ["valid", "zero"])
def test_ssim_custom_adjoint_matches_recorded_ad(rng, border):
    """The hand-written SSIM adjoint equals Dr.Jit's recorded AD of the same map, for
    random cotangents, w.r.t. both images."""
    from sgdr.loss import ssim_map

    a, b = _images(rng, 23, 29, 3)
    t = ad()
    w = float(rng.normal())
    grads = []
    for use_custom in (True, False):
        x, y = t.TensorXf(a), t.TensorXf(b)
        dr.enable_grad(x, y)
        if use_custom:
            value = ssim(x, y, border)
        else:
            s, _ = ssim_map(x, y, border)
            value = dr.mean(t.TensorXf(s), axis=None)
        dr.backward(value * w)
        grads.append((np.asarray(dr.grad(x)), np.asarray(dr.grad(y)), _val(value)))
    (ga, gb, v), (ra, rb, rv) = grads
    assert abs(v - rv) < 1e-6
    for ours, ref in ((ga, ra), (gb, rb)):
        assert np.abs(ref).max() > 1e-5
        np.testing.assert_allclose(ours, ref, atol=1e-4 * np.abs(ref).max())


def test_image_losses_of_a_batch_equal_each_image_loss():
    """The stacked filter drops the rows that straddle two images: each loss is the single one."""
    from sgdr.loss import image_losses

    t = ad()
    rng = np.random.default_rng(3)
    a = rng.random((4, 17, 23, 3)).astype(np.float32)
    b = np.clip(a + 0.2 * rng.normal(size=a.shape), 0, 1).astype(np.float32)
    b[2] = 0.0  # one image far off: a neighbour's window must not borrow from it
    got = np.asarray(image_losses(t.TensorXf(a), t.TensorXf(b), 0.2), dtype=np.float64)
    for i in range(4):
        want = float(np.asarray(image_loss(t.TensorXf(a[i]), t.TensorXf(b[i]), 0.2).array)[0])
        assert got[i] == pytest.approx(want, rel=1e-5)
    with pytest.raises(LossError, match=r"\[B, H, W, C\]"):
        image_losses(t.TensorXf(a[0]), t.TensorXf(b[0]), 0.2)
