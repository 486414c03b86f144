"""Evaluation (stage "evaluate"): the metrics (Chamfer distance, EMD, PSNR, SSIM, as DESIGN.md
defines them), the physics-free baselines (`baselines`) and the scoring of a prediction against
a sequence's ground truth (`score`). Tables and benchmarks over many runs are `evaluation/` (top level).

Geometry (`geometry.py`): predicted points are Gaussian centres, ground truth is the
generator's particles, both `np.ndarray [N, 3]` in scene units (the benchmark's unit cube).
Images (`image.py`): `np.ndarray [H, W, 3]` RGB in [0, 1].
"""

from sgdr.evaluate.geometry import chamfer_distance, earth_movers_distance, earth_movers_distances, subsample
from sgdr.evaluate.image import psnr, ssim

__all__ = ["chamfer_distance", "earth_movers_distance", "earth_movers_distances", "subsample", "psnr", "ssim"]
