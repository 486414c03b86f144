"""Differentiable image losses in Dr.Jit: L1, SSIM / D-SSIM, the weighted loss and a mask loss.

Images are TensorXf [H, W, C] (a NumPy array is accepted for the target and converted);
masks/alphas are TensorXf [H, W] or [H, W, 1]. All losses are means over pixels (scalars as
TensorXf of shape ()), differentiable w.r.t. both arguments.

SSIM (Wang et al. 2004) with the 3DGS / scikit-image constants: an 11x11 Gaussian window,
σ = 1.5 (scipy's kernel: radius int(3.5 σ + 0.5) = 5, normalised), C1 = (0.01 L)², C2 = (0.03 L)²
with data range L = 1, population (not sample) covariances:

    SSIM = (2 μ_a μ_b + C1)(2 σ_ab + C2) / ((μ_a² + μ_b² + C1)(σ_a² + σ_b² + C2))

`border="valid"` (default) averages the SSIM map over the pixels whose window lies inside the
image, which is exactly what `skimage.metrics.structural_similarity(gaussian_weights=True,
sigma=1.5, use_sample_covariance=False, data_range=1, channel_axis=-1)` reports: it filters
with reflection and then crops 5 pixels from every border before averaging, so the reflected
values never enter the mean; the per-channel means it averages are all over the same pixel
count, so their mean is the mean over every channel. `border="zero"` is the 3DGS training form
(zero-padded convolution, mean over the full image).
"""

from __future__ import annotations

import drjit as dr
import numpy as np

from sgdr.backend import ad

SSIM_SIGMA = 1.5
SSIM_TRUNCATE = 3.5  # scipy/skimage: radius = int(truncate * sigma + 0.5) = 5 -> 11 taps
SSIM_K1, SSIM_K2 = 0.01, 0.03


class LossError(ValueError):
    """Incompatible loss inputs; the message names the argument and both shapes."""


def _tensor(x, name: str):
    t = ad()
    if isinstance(x, t.TensorXf):
        return x
    if isinstance(x, np.ndarray):
        return t.TensorXf(np.ascontiguousarray(x, dtype=np.float32))
    raise LossError(f"{name} must be a TensorXf or a NumPy array, got {type(x).__name__}")


def _as_hwc(x, name: str):
    x = _tensor(x, name)
    if x.ndim == 2:
        return ad().TensorXf(x.array, (x.shape[0], x.shape[1], 1))
    if x.ndim != 3:
        raise LossError(f"{name} must have shape [H, W, C] or [H, W], got {x.shape}")
    return x


def _pair(a, b, names=("pred", "target")):
    a, b = _as_hwc(a, names[0]), _as_hwc(b, names[1])
    if a.shape != b.shape:
        raise LossError(f"image sizes differ: {names[0]} has shape {a.shape}, {names[1]} has shape {b.shape}")
    return a, b


def l1(a, b):
    """Mean absolute difference over all pixels and channels (a TensorXf scalar)."""
    a, b = _pair(a, b)
    return dr.mean(dr.abs(a - b), axis=None)


def gaussian_window(sigma: float = SSIM_SIGMA, truncate: float = SSIM_TRUNCATE) -> np.ndarray:
    """1D Gaussian taps as scipy.ndimage.gaussian_filter builds them (normalised)."""
    radius = int(truncate * sigma + 0.5)
    x = np.arange(-radius, radius + 1, dtype=np.float64)
    w = np.exp(-0.5 * x * x / (sigma * sigma))
    return w / w.sum()


def _filter_valid(x_flat, h, w, c, taps):
    """Separable filter of a flat [h, w, c] array without padding -> [h-2r, w-2r, c] flat."""
    t = ad()
    r = (len(taps) - 1) // 2
    ho, wo = h - 2 * r, w - 2 * r
    n_tmp, n_out = h * wo * c, ho * wo * c
    # sizes as opaque JIT scalars: one compiled kernel serves every image size
    w, wo, c = (dr.opaque(t.UInt32, v) for v in (w, wo, c))
    # horizontal: [h, wo, c]
    i = dr.arange(t.UInt32, n_tmp)
    y, rem = i // (wo * c), i % (wo * c)
    xo, ch = rem // c, rem % c
    base = (y * w + xo) * c + ch
    tmp = dr.zeros(t.Float, n_tmp)
    for k, wk in enumerate(taps):
        tmp += float(wk) * dr.gather(t.Float, x_flat, base + k * c)
    # vertical: [ho, wo, c]
    j = dr.arange(t.UInt32, n_out)
    out = dr.zeros(t.Float, n_out)
    row = wo * c
    for k, wk in enumerate(taps):
        out += float(wk) * dr.gather(t.Float, tmp, j + k * row)
    return out


def _zero_pad(x_flat, h, w, c, r):
    """[h, w, c] -> [h+2r, w+2r, c] with zeros around (flat)."""
    t = ad()
    hp, wp = h + 2 * r, w + 2 * r
    n = hp * wp * c
    h, w, wp, c = (dr.opaque(t.Int32, v) for v in (h, w, wp, c))
    i = t.Int32(dr.arange(t.UInt32, n))
    y, rem = i // (wp * c) - r, i % (wp * c)
    x, ch = rem // c - r, rem % c
    inside = (y >= 0) & (y < h) & (x >= 0) & (x < w)
    src = t.UInt32(dr.select(inside, (y * w + x) * c + ch, 0))
    return dr.gather(t.Float, x_flat, src, inside)


def _filter_valid_adjoint(d_flat, h, w, c, taps):
    """Adjoint of `_filter_valid`: [h-2r, w-2r, c] -> [h, w, c] (a zero-padded 'full' filter;
    the Gaussian taps are symmetric, so no flip is needed)."""
    t = ad()
    r = (len(taps) - 1) // 2
    ho, wo = h - 2 * r, w - 2 * r
    n_tmp, n_out = h * wo * c, h * w * c
    ho_, wo_, w_, c_ = (dr.opaque(t.Int32, v) for v in (ho, wo, w, c))
    # vertical adjoint: tmp[y, xo, ch] = Σ_k w_k d[y - k, xo, ch], 0 <= y - k < ho
    i = t.Int32(dr.arange(t.UInt32, n_tmp))
    y = i // (wo_ * c_)
    tmp = dr.zeros(t.Float, n_tmp)
    for k, wk in enumerate(taps):
        ok = (y - k >= 0) & (y - k < ho_)
        tmp += float(wk) * dr.gather(t.Float, d_flat, t.UInt32(dr.select(ok, i - k * wo_ * c_, 0)), ok)
    # horizontal adjoint: out[y, x, ch] = Σ_k w_k tmp[y, x - k, ch], 0 <= x - k < wo
    j = t.Int32(dr.arange(t.UInt32, n_out))
    yy, rem = j // (w_ * c_), j % (w_ * c_)
    x, ch = rem // c_, rem % c_
    out = dr.zeros(t.Float, n_out)
    for k, wk in enumerate(taps):
        ok = (x - k >= 0) & (x - k < wo_)
        src = (yy * wo_ + x - k) * c_ + ch
        out += float(wk) * dr.gather(t.Float, tmp, t.UInt32(dr.select(ok, src, 0)), ok)
    return out


def _ssim_terms(xa, xb, h, w, c, taps):
    """Filtered moments and the SSIM map (flat, over the valid region)."""
    mu_a, mu_b = _filter_valid(xa, h, w, c, taps), _filter_valid(xb, h, w, c, taps)
    e_aa = _filter_valid(xa * xa, h, w, c, taps)
    e_bb = _filter_valid(xb * xb, h, w, c, taps)
    e_ab = _filter_valid(xa * xb, h, w, c, taps)
    c1, c2 = SSIM_K1**2, SSIM_K2**2  # data range 1
    A1 = 2 * mu_a * mu_b + c1
    A2 = 2 * (e_ab - mu_a * mu_b) + c2
    B1 = mu_a * mu_a + mu_b * mu_b + c1
    B2 = (e_aa - mu_a * mu_a) + (e_bb - mu_b * mu_b) + c2
    return mu_a, mu_b, A1, A2, B1, B2, (A1 * A2) / (B1 * B2)


class _MeanSSIM(dr.CustomOp):
    """mean(SSIM map) with a hand-written adjoint: the per-pixel partial derivatives w.r.t. the
    filtered moments (μ, E[x²], E[xy]) are pulled back through the (linear) Gaussian filter by
    its adjoint, a zero-padded filter; gathers only, no atomic scatters."""

    def eval(self, xa, xb, h, w, c, need_b):
        taps = gaussian_window()
        self.args = (xa, xb, h, w, c, taps, need_b)
        mu_a, mu_b, A1, A2, B1, B2, S = _ssim_terms(xa, xb, h, w, c, taps)
        self.terms = (mu_a, mu_b, A1, A2, B1, B2, S)
        self.n = dr.width(S)
        dr.eval(self.terms)
        return dr.mean(S)

    def backward(self):
        xa, xb, h, w, c, taps, need_b = self.args
        mu_a, mu_b, A1, A2, B1, B2, S = self.terms
        g = self.grad_out() / self.n
        # ∂S/∂E[ab] and ∂S/∂E[aa] (= ∂S/∂E[bb])
        d_ab = _filter_valid_adjoint(2 * S / A2 * g, h, w, c, taps)
        d_sq = _filter_valid_adjoint(-S / B2 * g, h, w, c, taps)

        def d_mu(mu_self, mu_other):
            return S * (2 * mu_other / A1 - 2 * mu_other / A2 - 2 * mu_self / B1 + 2 * mu_self / B2) * g

        ga = _filter_valid_adjoint(d_mu(mu_a, mu_b), h, w, c, taps) + 2 * xa * d_sq + xb * d_ab
        self.set_grad_in("xa", ga)
        if need_b:
            gb = _filter_valid_adjoint(d_mu(mu_b, mu_a), h, w, c, taps) + 2 * xb * d_sq + xa * d_ab
            self.set_grad_in("xb", gb)

    def name(self):
        return "MeanSSIM"


def _prepare(a, b, border):
    a, b = _pair(a, b)
    h, w, c = a.shape
    r = (len(gaussian_window()) - 1) // 2
    xa, xb = a.array, b.array
    if border == "zero":
        xa, xb = _zero_pad(xa, h, w, c, r), _zero_pad(xb, h, w, c, r)
        h, w = h + 2 * r, w + 2 * r
    elif border != "valid":
        raise LossError(f"ssim border must be 'valid' or 'zero', got {border!r}")
    if h <= 2 * r or w <= 2 * r:
        raise LossError(f"SSIM needs images larger than {2 * r + 1}x{2 * r + 1} pixels, got {a.shape}")
    return xa, xb, h, w, c


def ssim_map(a, b, border: str = "valid"):
    """Per-pixel SSIM as a flat Float over the averaged region [h', w', c] and that shape
    (recorded AD; `ssim` uses the faster custom adjoint)."""
    xa, xb, h, w, c = _prepare(a, b, border)
    taps = gaussian_window()
    r = (len(taps) - 1) // 2
    return _ssim_terms(xa, xb, h, w, c, taps)[-1], (h - 2 * r, w - 2 * r, c)


def ssim(a, b, border: str = "valid"):
    """Mean SSIM (a TensorXf scalar); see the module docstring for `border`."""
    xa, xb, h, w, c = _prepare(a, b, border)
    m = dr.custom(_MeanSSIM, xa, xb, h, w, c, bool(dr.grad_enabled(xb)))
    return ad().TensorXf(m, ())


def dssim(a, b, border: str = "valid"):
    """D-SSIM = 1 - SSIM, as in 3DGS (so (1-λ) L1 + λ D-SSIM matches its training loss)."""
    return 1.0 - ssim(a, b, border)


def image_loss(pred, target, lam: float, border: str = "valid"):
    """(1 - λ) L1 + λ D-SSIM (the seed paper's photometric loss, λ = 0.2 in its experiments)."""
    return (1.0 - float(lam)) * l1(pred, target) + float(lam) * dssim(pred, target, border)


def image_losses(pred, target, lam: float):
    """`image_loss` (border 'valid') of each of B image pairs at once: Float [B].

    pred, target: TensorXf [B, H, W, C]. No gradients (the global search's scores). The
    Gaussian filter runs over the B images stacked as one [B H, W, C] image; its 'valid' rows
    that straddle two images are computed and dropped, so every kept SSIM value sees one image
    only and equals the single-image one to float rounding."""
    t = ad()
    a, b = _tensor(pred, "pred"), _tensor(target, "target")
    if a.ndim != 4 or a.shape != b.shape:
        raise LossError(f"image_losses: pred and target must both be [B, H, W, C]; got {a.shape} and {b.shape}")
    n, h, w, c = a.shape
    taps = gaussian_window()
    r = (len(taps) - 1) // 2
    if h <= 2 * r or w <= 2 * r:
        raise LossError(f"SSIM needs images larger than {2 * r + 1}x{2 * r + 1} pixels, got {a.shape[1:]}")
    with dr.suspend_grad():
        xa, xb = a.array, b.array
        per_image = h * w * c
        l1_sum = dr.block_sum(dr.abs(xa - xb), per_image)  # [B]
        *_, S = _ssim_terms(xa, xb, n * h, w, c, taps)  # rows 0 .. n h - 2r - 1 of the stacked image
        ho, wo = h - 2 * r, w - 2 * r
        per_map = ho * wo * c
        k = dr.arange(t.UInt32, n * per_map)
        img, rem = k // per_map, k % per_map  # rem = (y wo + x) c + channel, y < ho: inside image img
        S_valid = dr.gather(t.Float, S, img * dr.opaque(t.UInt32, h * wo * c) + rem)
        ssim_mean = dr.block_sum(S_valid, per_map) / float(per_map)
        return (1.0 - float(lam)) * l1_sum / float(per_image) + float(lam) * (1.0 - ssim_mean)


def mask_loss(alpha, mask):
    """Mean absolute difference between rendered accumulated opacity and a mask, both [H, W]
    (or [H, W, 1]) in [0, 1]."""
    return l1(_as_hwc(alpha, "alpha"), _as_hwc(mask, "mask"))
