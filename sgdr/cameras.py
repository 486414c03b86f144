"""Pinhole cameras in the OpenCV convention (x right, y down, z forward).

A camera is data (NumPy float64), shared by the readers, the generator and the renderers:
intrinsics K and world-to-camera [R|t], so a world point X maps to camera coordinates
x_c = R X + t and to pixels (u, v) = (fx x/z + cx, fy y/z + cy). Pixel centres sit at
integer + 0.5 (u = 0 is the left edge of the first pixel column).

Blender and OpenGL store camera-to-world matrices whose camera looks down -z with y up;
`Camera.from_c2w_opengl` converts them by flipping the camera's y and z axes.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

_GL_TO_CV = np.diag([1.0, -1.0, -1.0])


class CameraError(ValueError):
    """An invalid camera description; the message names the field."""


@dataclass(frozen=True)
class Camera:
    K: np.ndarray  # [3, 3] intrinsics, pixels
    R: np.ndarray  # [3, 3] world-to-camera rotation
    t: np.ndarray  # [3] world-to-camera translation, scene units
    width: int  # pixels
    height: int  # pixels
    name: str = field(default="")

    def __post_init__(self):
        K = np.asarray(self.K, dtype=np.float64)
        R = np.asarray(self.R, dtype=np.float64)
        t = np.asarray(self.t, dtype=np.float64).reshape(-1)
        where = f"camera {self.name!r}" if self.name else "camera"
        if K.shape != (3, 3):
            raise CameraError(f"{where}: K must be 3x3, got shape {K.shape}")
        if R.shape != (3, 3):
            raise CameraError(f"{where}: R must be 3x3, got shape {R.shape}")
        if t.shape != (3,):
            raise CameraError(f"{where}: t must have 3 entries, got shape {t.shape}")
        for key, arr in (("K", K), ("R", R), ("t", t)):
            if not np.all(np.isfinite(arr)):
                raise CameraError(f"{where}: {key} has non-finite entries")
        if not np.allclose(R @ R.T, np.eye(3), atol=1e-5) or np.linalg.det(R) < 0:
            raise CameraError(f"{where}: R is not a rotation (orthonormal, det +1)")
        if K[0, 0] <= 0 or K[1, 1] <= 0:
            raise CameraError(f"{where}: focal lengths K[0,0], K[1,1] must be positive")
        if int(self.width) <= 0 or int(self.height) <= 0:
            raise CameraError(f"{where}: width and height must be positive")
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "R", R)
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))

    # ---------------------------------------------------------------- constructors
    @staticmethod
    def from_w2c(w2c, K, width, height, name="") -> Camera:
        """From a 3x4 or 4x4 world-to-camera matrix in the OpenCV convention."""
        w2c = np.asarray(w2c, dtype=np.float64)
        if w2c.shape not in ((3, 4), (4, 4)):
            raise CameraError(f"camera {name!r}: w2c must be 3x4 or 4x4, got {w2c.shape}")
        return Camera(K, w2c[:3, :3], w2c[:3, 3], width, height, name)

    @staticmethod
    def from_c2w_opencv(c2w, K, width, height, name="") -> Camera:
        """From a camera-to-world matrix whose camera axes follow OpenCV."""
        c2w = np.asarray(c2w, dtype=np.float64)
        if c2w.shape not in ((3, 4), (4, 4)):
            raise CameraError(f"camera {name!r}: c2w must be 3x4 or 4x4, got {c2w.shape}")
        R_c2w, centre = c2w[:3, :3], c2w[:3, 3]
        R = R_c2w.T
        return Camera(K, R, -R @ centre, width, height, name)

    @staticmethod
    def from_c2w_opengl(c2w, K, width, height, name="") -> Camera:
        """From a Blender/OpenGL camera-to-world matrix (camera looks down -z, y up)."""
        c2w = np.array(c2w, dtype=np.float64)
        if c2w.shape not in ((3, 4), (4, 4)):
            raise CameraError(f"camera {name!r}: c2w must be 3x4 or 4x4, got {c2w.shape}")
        c2w[:3, :3] = c2w[:3, :3] @ _GL_TO_CV
        return Camera.from_c2w_opencv(c2w, K, width, height, name)

    @staticmethod
    def intrinsics_from_fov(fov_x_deg: float, width: int, height: int) -> np.ndarray:
        """K for a horizontal field of view (degrees), square pixels, centred principal point."""
        if not 0.0 < fov_x_deg < 180.0:
            raise CameraError(f"fov_x_deg must be in (0, 180), got {fov_x_deg}")
        f = 0.5 * width / np.tan(0.5 * np.radians(fov_x_deg))
        return np.array([[f, 0.0, 0.5 * width], [0.0, f, 0.5 * height], [0.0, 0.0, 1.0]])

    @staticmethod
    def look_at(eye, target, up, fov_x_deg, width, height, name="") -> Camera:
        """A camera at `eye` looking at `target`; `up` gives the image's upward direction."""
        eye, target, up = (np.asarray(a, dtype=np.float64) for a in (eye, target, up))
        z = target - eye
        if np.linalg.norm(z) < 1e-12:
            raise CameraError(f"camera {name!r}: eye and target coincide")
        z /= np.linalg.norm(z)
        x = np.cross(z, up)  # image x to the right; y = z × x then points down
        if np.linalg.norm(x) < 1e-9:
            raise CameraError(f"camera {name!r}: up is parallel to the viewing direction")
        x /= np.linalg.norm(x)
        y = np.cross(z, x)
        c2w = np.eye(4)
        c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = x, y, z, eye
        K = Camera.intrinsics_from_fov(fov_x_deg, width, height)
        return Camera.from_c2w_opencv(c2w, K, width, height, name)

    # ---------------------------------------------------------------- accessors
    @property
    def w2c(self) -> np.ndarray:
        """[4, 4] world-to-camera (OpenCV)."""
        m = np.eye(4)
        m[:3, :3], m[:3, 3] = self.R, self.t
        return m

    @property
    def c2w(self) -> np.ndarray:
        """[4, 4] camera-to-world (OpenCV axes)."""
        m = np.eye(4)
        m[:3, :3], m[:3, 3] = self.R.T, self.centre
        return m

    @property
    def c2w_opengl(self) -> np.ndarray:
        """[4, 4] camera-to-world in the Blender/OpenGL convention."""
        m = self.c2w
        m[:3, :3] = m[:3, :3] @ _GL_TO_CV
        return m

    @property
    def centre(self) -> np.ndarray:
        """[3] camera position in world coordinates."""
        return -self.R.T @ self.t

    @property
    def fov_x_deg(self) -> float:
        return float(np.degrees(2.0 * np.arctan(0.5 * self.width / self.K[0, 0])))

    def to_camera(self, points) -> np.ndarray:
        """[N, 3] world -> [N, 3] camera coordinates."""
        return np.asarray(points, dtype=np.float64) @ self.R.T + self.t

    def project(self, points) -> tuple[np.ndarray, np.ndarray]:
        """[N, 3] world points -> ([N, 2] pixel coordinates, [N] depth z). z <= 0 is behind."""
        pc = self.to_camera(points)
        z = pc[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = (pc[:, :2] / z[:, None]) @ self.K[:2, :2].T + self.K[:2, 2]
        return uv, z

    def to_dict(self) -> dict:
        """JSON-ready description (OpenCV K and w2c)."""
        return {
            "name": self.name,
            "width": self.width,
            "height": self.height,
            "K": self.K.tolist(),
            "w2c": self.w2c.tolist(),
        }

    @staticmethod
    def from_dict(d: dict, where: str = "camera") -> Camera:
        for key in ("K", "w2c", "width", "height"):
            if key not in d:
                raise CameraError(f"{where}: missing field {key!r}")
        return Camera.from_w2c(d["w2c"], d["K"], d["width"], d["height"], d.get("name", ""))
