"""The appearance model: a set of 3D Gaussians (Eq. 1 of the seed paper).

Each Gaussian i has a centre μ_i (world, scene units), a covariance Σ_i = R_i S_i S_iᵀ R_iᵀ
with S_i = diag(exp(log_scales_i)) and R_i the rotation of the unit quaternion
`rotations_i` = (w, x, y, z), a colour c_i = sigmoid(color_logits_i) in [0, 1]³ (RGB, no
spherical harmonics) and an opacity σ_i = sigmoid(opacity_logits_i) in (0, 1).

The paper uses isotropic Gaussians: three equal log-scales and the identity rotation. The
same fields and code path carry fully anisotropic Gaussians.

All fields are Dr.Jit arrays of the active backend (`sgdr.backend.ad()`); any of them may
be AD-attached, including `means` computed upstream (simulation -> IDW skinning -> means).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sgdr.arrays import to_numpy
from sgdr.backend import ad


class GaussiansError(ValueError):
    """Invalid Gaussian data; the message names the field."""


def logit(p: np.ndarray) -> np.ndarray:
    """Inverse of the sigmoid, clipped away from 0 and 1 (NumPy)."""
    p = np.clip(np.asarray(p, dtype=np.float64), 1e-6, 1.0 - 1e-6)
    return np.log(p / (1.0 - p))


def sigmoid(x: np.ndarray) -> np.ndarray:
    return 1.0 / (1.0 + np.exp(-np.asarray(x, dtype=np.float64)))


@dataclass
class Gaussians:
    means: object  # Array3f [M] world, scene units
    log_scales: object  # Array3f [M] natural log of the standard deviations, scene units
    rotations: object  # Array4f [M] quaternion (w, x, y, z), need not be normalised
    color_logits: object  # Array3f [M] colour = sigmoid(color_logits), RGB in [0, 1]
    opacity_logits: object  # Float [M] opacity = sigmoid(opacity_logits)

    @property
    def count(self) -> int:
        """Number of Gaussians M."""
        return dr_width(self.opacity_logits)

    # ---------------------------------------------------------------- NumPy bridge
    @staticmethod
    def from_numpy(
        means: np.ndarray,  # [M, 3]
        log_scales: np.ndarray | float | None = None,  # [M, 3] or [M] (isotropic) or scalar
        rotations: np.ndarray | None = None,  # [M, 4] (w, x, y, z); None = identity
        color_logits: np.ndarray | None = None,  # [M, 3]; None = grey (logit 0)
        opacity_logits: np.ndarray | None = None,  # [M]; None = opacity 0.5
    ) -> Gaussians:
        """Build from NumPy arrays; missing fields get neutral defaults."""
        t = ad()
        means = np.asarray(means, dtype=np.float64).reshape(-1, 3)
        m = means.shape[0]
        if log_scales is None:
            log_scales = np.full((m, 3), np.log(0.01))
        log_scales = np.asarray(log_scales, dtype=np.float64)
        if log_scales.ndim == 0:
            log_scales = np.full((m, 3), float(log_scales))
        elif log_scales.ndim == 1:
            log_scales = np.repeat(log_scales[:, None], 3, axis=1)
        rotations = np.tile([1.0, 0.0, 0.0, 0.0], (m, 1)) if rotations is None else np.asarray(rotations, np.float64)
        color_logits = np.zeros((m, 3)) if color_logits is None else np.asarray(color_logits, np.float64)
        opacity_logits = np.zeros(m) if opacity_logits is None else np.asarray(opacity_logits, np.float64)
        for name, arr, shape in (
            ("log_scales", log_scales, (m, 3)),
            ("rotations", rotations, (m, 4)),
            ("color_logits", color_logits, (m, 3)),
            ("opacity_logits", opacity_logits.reshape(-1), (m,)),
        ):
            if arr.shape != shape:
                raise GaussiansError(f"Gaussians.from_numpy: {name} has shape {arr.shape}, expected {shape}")

        def vec(a):
            return [t.Float(np.ascontiguousarray(a[:, k], dtype=np.float32)) for k in range(a.shape[1])]

        return Gaussians(
            means=t.Array3f(*vec(means)),
            log_scales=t.Array3f(*vec(log_scales)),
            rotations=t.Array4f(*vec(rotations)),
            color_logits=t.Array3f(*vec(color_logits)),
            opacity_logits=t.Float(np.ascontiguousarray(opacity_logits.reshape(-1), dtype=np.float32)),
        )

    @staticmethod
    def isotropic(means: np.ndarray, scale: float | np.ndarray, colors: np.ndarray, opacities) -> Gaussians:
        """Isotropic Gaussians from scales (scene units), RGB colours and opacities in (0, 1)."""
        means = np.asarray(means, dtype=np.float64).reshape(-1, 3)
        scale = np.broadcast_to(np.asarray(scale, dtype=np.float64), (means.shape[0],))
        return Gaussians.from_numpy(
            means,
            np.log(scale),
            None,
            logit(np.broadcast_to(colors, means.shape)),
            logit(np.broadcast_to(opacities, (means.shape[0],))),
        )

    def to_numpy(self) -> dict[str, np.ndarray]:
        """Detached float64 copies: means, log_scales, rotations, color_logits [M, 3|4], opacity_logits [M]."""

        return {
            "means": to_numpy(self.means).T.reshape(-1, 3) if self.count else np.zeros((0, 3)),
            "log_scales": to_numpy(self.log_scales).T.reshape(-1, 3) if self.count else np.zeros((0, 3)),
            "rotations": to_numpy(self.rotations).T.reshape(-1, 4) if self.count else np.zeros((0, 4)),
            "color_logits": to_numpy(self.color_logits).T.reshape(-1, 3) if self.count else np.zeros((0, 3)),
            "opacity_logits": to_numpy(self.opacity_logits).reshape(-1),
        }

    def subset(self, keep: np.ndarray) -> Gaussians:
        """Detached copy holding the Gaussians where the boolean mask `keep` [M] is true."""
        d = self.to_numpy()
        keep = np.asarray(keep, dtype=bool)
        return Gaussians.from_numpy(*(d[k][keep] for k in _FIELDS))

    def detach(self) -> Gaussians:
        import drjit as dr

        return Gaussians(*(dr.detach(getattr(self, k)) for k in _FIELDS))


_FIELDS = ("means", "log_scales", "rotations", "color_logits", "opacity_logits")


def dr_width(x) -> int:
    import drjit as dr

    return int(dr.width(x))
