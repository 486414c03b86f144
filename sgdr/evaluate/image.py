"""Image metrics for evaluation: PSNR and SSIM on [0, 1] RGB (NumPy; not differentiable).

Images are `np.ndarray [H, W, 3]` (an alpha channel, if given as [H, W, 4], is dropped: the
benchmark renders on black, so RGB already carries the silhouette). The differentiable D-SSIM
used as a training loss lives in `sgdr.loss`; evaluation uses scikit-image's
reference SSIM so our scores are comparable with other codebases.
"""

from __future__ import annotations

import numpy as np
from skimage.metrics import structural_similarity

SSIM_SIGMA = 1.5  # Gaussian window σ, pixels; with truncate=3.5 scikit-image uses an 11x11 window


def _rgb(img, name: str) -> np.ndarray:
    a = np.asarray(img, dtype=np.float64)
    if a.ndim != 3 or a.shape[2] not in (3, 4):
        raise ValueError(f"{name}: expected an image [H, W, 3] (or [H, W, 4]), got {a.shape}")
    return a[..., :3]


def psnr(pred, gt) -> float:
    """Peak signal-to-noise ratio, dB, with peak 1: 10 log10(1 / MSE) over all RGB values.

    Identical images give +inf.
    """
    a, b = _rgb(pred, "psnr pred"), _rgb(gt, "psnr gt")
    if a.shape != b.shape:
        raise ValueError(f"psnr: image shapes differ, {a.shape} vs {b.shape}")
    mse = float(np.mean((a - b) ** 2))
    return float("inf") if mse == 0.0 else float(10.0 * np.log10(1.0 / mse))


def ssim(pred, gt) -> float:
    """Mean SSIM over pixels and RGB channels: 11x11 Gaussian window, σ = 1.5, data range 1.

    scikit-image's `structural_similarity(gaussian_weights=True, sigma=1.5,
    use_sample_covariance=False, data_range=1)`, i.e. the settings of Wang et al. (2004).
    """
    a, b = _rgb(pred, "ssim pred"), _rgb(gt, "ssim gt")
    if a.shape != b.shape:
        raise ValueError(f"ssim: image shapes differ, {a.shape} vs {b.shape}")
    return float(
        structural_similarity(
            a,
            b,
            gaussian_weights=True,
            sigma=SSIM_SIGMA,
            use_sample_covariance=False,
            data_range=1.0,
            channel_axis=-1,
        )
    )
