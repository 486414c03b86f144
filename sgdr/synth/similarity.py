"""Similarity transforms between coordinate frames, and OpenCV cameras carried through them.

A similarity maps points of frame A to frame B: X_B = s R X_A + t (s > 0 a scale, R a
rotation, t a translation in B's units). The simulated capture uses three of them:
- sim -> dynamic: sgdr's simulation frame (unit cube, z up, scene units) to the dynamic frame
  (the world checkerboard's frame, z down into the table, metres);
- static -> dynamic: the registration of the static scan (the truth of `gt/truth.json`);
- their composition sim -> static, through which the static photos' cameras are written.

A camera is invariant under a change of frame: if (R_c, t_c) maps A-points to camera
coordinates, x_c = R_c X_A + t_c, then with X_A = Rᵀ (X_B - t) / s the same pixels come from
x_c' = s x_c = (R_c Rᵀ) X_B + (s t_c - R_c Rᵀ t) (a positive scale of x_c projects alike).
`camera_in` applies this; depths are then in B's units.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from sgdr.cameras import Camera


@dataclass(frozen=True)
class Similarity:
    """X_B = s R X_A + t."""

    s: float  # scale, B units per A unit
    R: np.ndarray  # [3, 3] rotation (det +1)
    t: np.ndarray  # [3] translation, B units

    def __post_init__(self):
        R = np.asarray(self.R, dtype=np.float64)
        if not np.allclose(R @ R.T, np.eye(3), atol=1e-9) or np.linalg.det(R) < 0:
            raise ValueError("Similarity.R is not a rotation")
        if not self.s > 0:
            raise ValueError(f"Similarity.s must be > 0, got {self.s}")
        object.__setattr__(self, "R", R)
        object.__setattr__(self, "t", np.asarray(self.t, dtype=np.float64).reshape(3))
        object.__setattr__(self, "s", float(self.s))

    def apply(self, points) -> np.ndarray:
        """[N, 3] A -> [N, 3] B (float64)."""
        return self.s * np.asarray(points, dtype=np.float64) @ self.R.T + self.t

    def apply_vector(self, v) -> np.ndarray:
        """Directions and velocities ([..., 3]): s R v (no translation)."""
        return self.s * np.asarray(v, dtype=np.float64) @ self.R.T

    def inverse(self) -> Similarity:
        """B -> A: X_A = (1/s) Rᵀ X_B - (1/s) Rᵀ t."""
        return Similarity(1.0 / self.s, self.R.T, -(self.R.T @ self.t) / self.s)

    def then(self, other: Similarity) -> Similarity:
        """`other` after `self` (A -> B -> C)."""
        return Similarity(other.s * self.s, other.R @ self.R, other.s * (other.R @ self.t) + other.t)

    def matrix(self) -> np.ndarray:
        """[4, 4] homogeneous matrix [[s R, t], [0, 1]]."""
        m = np.eye(4)
        m[:3, :3], m[:3, 3] = self.s * self.R, self.t
        return m

    def to_dict(self) -> dict:
        return {"s": self.s, "R": self.R.tolist(), "t": self.t.tolist()}

    @staticmethod
    def from_dict(d: dict) -> Similarity:
        return Similarity(d["s"], d["R"], d["t"])


def camera_in(camera: Camera, A_to_B: Similarity, name: str | None = None) -> Camera:
    """The camera `camera` (given in frame A) as a camera of frame B (module docstring)."""
    R = camera.R @ A_to_B.R.T
    t = A_to_B.s * camera.t - R @ A_to_B.t
    return Camera(camera.K, R, t, camera.width, camera.height, camera.name if name is None else name)


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    """[3, 3] rotation drawn uniformly (a normalised Gaussian quaternion)."""

    q = rng.normal(size=4)
    return Rotation.from_quat(q / np.linalg.norm(q)).as_matrix()


def rotation_angle_deg(R_a, R_b) -> float:
    """The angle of R_a R_bᵀ, degrees: how far apart two rotations are."""
    c = (np.trace(np.asarray(R_a) @ np.asarray(R_b).T) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))
