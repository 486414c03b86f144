"""Alpha mattes from a clean background plate (PAC-NeRF's released data; real captures without masks).

PAC-NeRF ships, per view, one image of the empty scene (`r_<view>_-1.png`) and RGB frames of the
object over that background; its code mattes every frame against the plate with a pretrained
BackgroundMattingV2 network, whose weights cannot be downloaded here. sgdr replaces it with
background subtraction:

1. the object mask is `sgdr.data.masks.masks_from_background` (chromaticity and brightness
   ratio against the plate, robust to shadows, sensor noise and JPEG; cleaned morphologically;
   measured there: IoU >= 0.92 on the simulated capture's noisy JPEG video frames, where a plain
   RGB difference threshold reached 0.65);
2. alpha is 1 inside the mask away from its border and 0 away from it; a border pixel (inside or
   just outside) is partly covered: its alpha is d / the full difference of the object next to
   it (d = max over RGB of |I - B|, the full difference = the largest d of interior pixels within
   2 pixels), since a pixel covering a fraction a of the object differs from the plate by a times
   the object's own difference.

An object pixel of the background's colour and brightness is lost, the limit of any difference
matte.
"""

from __future__ import annotations

import numpy as np
from sgdr.data.masks import masks_from_background
import cv2


def matte(image: np.ndarray, plate: np.ndarray, threshold: float = 0.1) -> np.ndarray:
    """image, plate [H, W, 3] float in [0, 1] (straight RGB) -> alpha [H, W] float32 in [0, 1].
    threshold: the chromaticity distance above which a pixel is object (`masks_from_background`)."""

    image, plate = np.asarray(image, np.float32), np.asarray(plate, np.float32)
    if image.shape != plate.shape:
        raise ValueError(f"matte: image {image.shape} and background plate {plate.shape} differ in shape")
    if not threshold > 0:
        raise ValueError(f"matte: threshold must be positive, got {threshold}")

    d = np.abs(image - plate).max(axis=-1)
    kernel = np.ones((3, 3), np.uint8)
    binary = masks_from_background(image, plate, chroma_threshold=threshold).astype(np.uint8)
    interior = cv2.erode(binary, kernel).astype(bool)
    rim = cv2.dilate(binary, kernel).astype(bool) & ~interior
    # coverage of a rim pixel: its difference over the full difference of the object next to it
    full = cv2.dilate(np.where(interior, d, 0.0).astype(np.float32), np.ones((5, 5), np.uint8))
    ratio = np.where(full > threshold, d / np.maximum(full, 1e-6), binary.astype(np.float32))
    alpha = np.where(interior, 1.0, np.where(rim, np.clip(ratio, 0.0, 1.0), 0.0))
    return alpha.astype(np.float32)
