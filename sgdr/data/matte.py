"""Object masks from a clean background plate (what PAC-NeRF's released data needs).

PAC-NeRF ships, per view, one image of the empty scene (`r_<view>_-1.png`) and RGB frames of the
object over that background; its code mattes every frame against the plate with a pretrained
BackgroundMattingV2 network, whose weights cannot be downloaded here. sgdr replaces it with a
plain background subtraction, which is exact where the background is static and differs in
colour from the object (the case of rendered data):

    d(p) = max over RGB channels of |I(p) - B(p)|;   object where d > t (t = `threshold`),

cleaned by a 3x3 morphological opening (isolated noise pixels) and closing (pinholes). Pixels
inside the cleaned mask (not on its border) have alpha 1, pixels away from it alpha 0. A pixel
on the border, inside or just outside, is partly covered: its alpha is d over the full
difference of the object next to it (the largest d of interior pixels within 2 pixels), since a
pixel covering a fraction a of the object differs from the plate by a times the object's own
difference.
An object pixel whose colour equals the background's within t is lost, the limit of any
difference matte; a shadow the object casts darker than t counts as object.
"""

from __future__ import annotations

import numpy as np


def matte(image: np.ndarray, plate: np.ndarray, threshold: float = 0.1) -> np.ndarray:
    """image, plate [H, W, 3] float in [0, 1] (straight RGB) -> alpha [H, W] float32 in [0, 1]."""
    import cv2

    image, plate = np.asarray(image, np.float32), np.asarray(plate, np.float32)
    if image.shape != plate.shape:
        raise ValueError(f"matte: image {image.shape} and background plate {plate.shape} differ in shape")
    if not threshold > 0:
        raise ValueError(f"matte: threshold must be positive, got {threshold}")
    d = np.abs(image - plate).max(axis=-1)
    kernel = np.ones((3, 3), np.uint8)
    binary = (d > threshold).astype(np.uint8)
    binary = cv2.morphologyEx(binary, cv2.MORPH_OPEN, kernel)  # isolated noise pixels
    binary = cv2.morphologyEx(binary, cv2.MORPH_CLOSE, kernel)  # pinholes
    interior = cv2.erode(binary, kernel).astype(bool)
    rim = cv2.dilate(binary, kernel).astype(bool) & ~interior
    # coverage of a rim pixel: its difference over the full difference of the object next to it
    full = cv2.dilate(np.where(interior, d, 0.0).astype(np.float32), np.ones((5, 5), np.uint8))
    ratio = np.where(full > threshold, d / np.maximum(full, 1e-6), binary.astype(np.float32))
    alpha = np.where(interior, 1.0, np.where(rim, np.clip(ratio, 0.0, 1.0), 0.0))
    return alpha.astype(np.float32)
