"""Evaluation metrics: Chamfer distance, EMD, PSNR, SSIM (as DESIGN.md defines them).

Geometry (`geometry.py`): predicted points are Gaussian centres, ground truth is the
generator's particles, both `np.ndarray [N, 3]` in scene units (the benchmark's unit cube).
Images (`image.py`): `np.ndarray [H, W, 3]` RGB in [0, 1].
"""

from sgdr.metrics.geometry import chamfer_distance, earth_movers_distance, earth_movers_distances, subsample
from sgdr.metrics.image import psnr, ssim

__all__ = ["chamfer_distance", "earth_movers_distance", "earth_movers_distances", "subsample", "psnr", "ssim"]
