"""Coarser and finer views of the same cameras: `downscaled` cameras with their `block_mean`
images (the global search, the diagnosis, the PAC-NeRF baseline), `upscaled` cameras (a twin
rendered finer than it is observed)."""

from __future__ import annotations

import numpy as np

from sgdr.cameras import Camera


def upscaled(camera, s: int):
    """The camera whose pixels are s x s sub-pixels of `camera`'s (intrinsics x s, size x s): the
    same view, rendered s times finer (the inverse of `sgdr.observe.images.downscaled`)."""

    if s < 1:
        raise ValueError(f"image_scale={s}: must be a positive integer")
    if s == 1:
        return camera
    K = np.array(camera.K, float)
    K[:2] *= s
    return Camera(K, camera.R, camera.t, camera.width * s, camera.height * s, camera.name)


# ---------------------------------------------------------------------------- coarser views
def downscale_factor(width: int, height: int, max_size: int) -> int:
    """The integer factor that brings the larger image side to at most `max_size` (1: unchanged)."""
    return max(1, int(np.ceil(max(int(width), int(height)) / float(max_size))))


def downscaled(camera, k: int):
    """The camera whose pixels are k x k blocks of `camera`'s (intrinsics / k; the size cropped to
    a multiple of k), matching `block_mean` of its images."""
    if k == 1:
        return camera
    K = np.array(camera.K, float)
    K[:2] /= k
    return Camera(K, camera.R, camera.t, camera.width // k, camera.height // k, camera.name)


def block_mean(image: np.ndarray, k: int) -> np.ndarray:
    """[H, W, C] -> [H // k, W // k, C], each pixel the mean of a k x k block."""
    if k == 1:
        return image
    h, w = image.shape[0] // k, image.shape[1] // k
    return image[: h * k, : w * k].reshape(h, k, w, k, -1).mean(axis=(1, 3))
