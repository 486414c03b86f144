"""The calibration checkerboard: its geometry, its colour convention and analytic images of it.

Board frame (the world frame of the dynamic capture when the board lies in its first pose):
inner corner (i, j), i = 0..cols-1 along a row, j = 0..rows-1 down the columns, sits at
(i a, j a, 0) for the square size a (metres); z = x × y. Square (p, q), p = 0..cols,
q = 0..rows, covers [(p-1) a, p a] x [(q-1) a, q a] and is black when p + q is even, so the
outer square next to corner (0, 0) is black; with cols + rows odd the outer square at the far
corner (cols-1, rows-1) is white, which tells the board's two 180°-rotated readings apart
(`canonical_order`). A white margin of `margin` squares surrounds the squares.

`board_image` draws what a pinhole camera sees of the board (no distortion): every pixel is
supersampled s x s, each sample's ray is cut with the board's plane z = 0, and the sample
takes the colour of the square, the margin or the background it lands on. It is the
simulated capture's "photo" of the board (`sgdr.synth.capture`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sgdr.cameras import Camera
import cv2


class BoardError(ValueError):
    """A board pattern or pose that cannot work; the message says which."""


@dataclass(frozen=True)
class Board:
    cols: int  # inner corners along a row (OpenCV patternSize[0])
    rows: int  # inner corners down a column (patternSize[1])
    square: float  # square side, metres (world units)
    margin: float = 1.0  # white margin around the squares, in squares

    def __post_init__(self):
        if self.cols < 2 or self.rows < 2:
            raise BoardError(f"board pattern ({self.cols}, {self.rows}): at least 2 x 2 inner corners")
        if (self.cols + self.rows) % 2 == 0:
            raise BoardError(
                f"board pattern ({self.cols}, {self.rows}): cols + rows must be odd, or the board looks the same "
                "turned by 180° and its first corner is ambiguous"
            )

    @property
    def pattern(self) -> tuple[int, int]:
        return (self.cols, self.rows)

    def object_points(self) -> np.ndarray:
        """[cols * rows, 3] float32 inner corners in the board frame, row by row (OpenCV order)."""
        j, i = np.mgrid[0 : self.rows, 0 : self.cols]
        return np.stack([i.ravel(), j.ravel(), np.zeros(i.size)], -1).astype(np.float32) * np.float32(self.square)

    def outline(self) -> np.ndarray:
        """[4, 3] corners of the board (margin included) in the board frame."""
        lo = -(1.0 + self.margin) * self.square
        hi_x, hi_y = (self.cols + self.margin) * self.square, (self.rows + self.margin) * self.square
        return np.array([[lo, lo, 0.0], [hi_x, lo, 0.0], [hi_x, hi_y, 0.0], [lo, hi_y, 0.0]])

    def centre(self) -> np.ndarray:
        """[3] the centre of the inner corners, board frame."""
        return np.array([0.5 * (self.cols - 1) * self.square, 0.5 * (self.rows - 1) * self.square, 0.0])

    def reflectance(self, x, y) -> np.ndarray:
        """Reflectance at board points (x, y) ([N] each): 1 on white, 0 on black, NaN off the board."""
        a = self.square
        p, q = np.floor(x / a) + 1, np.floor(y / a) + 1
        on_squares = (p >= 0) & (p <= self.cols) & (q >= 0) & (q <= self.rows)
        lo = -(1.0 + self.margin) * a
        on_board = (x >= lo) & (y >= lo) & (x <= (self.cols + self.margin) * a) & (y <= (self.rows + self.margin) * a)
        black = on_squares & ((p + q) % 2 == 0)
        return np.where(on_board, np.where(black, 0.0, 1.0), np.nan)


def board_image(
    camera: Camera, R_bc, t_bc, board: Board, white: float, black: float, background, supersample: int
) -> np.ndarray:
    """[H, W] (or [H, W, C]) float64 linear intensity of the board seen by `camera` (module docstring).

    R_bc [3, 3], t_bc [3]: board-to-camera pose, x_cam = R_bc X_board + t_bc. white / black:
    linear intensities of the white and black squares; background: scalar, [H, W] or [H, W, C]
    linear intensity where a ray misses the board (the result has its channels); supersample:
    samples per pixel side.
    """
    R_bc, t_bc = np.asarray(R_bc, dtype=np.float64), np.asarray(t_bc, dtype=np.float64)
    s = int(supersample)
    H, W = camera.height, camera.width
    sub = (np.arange(s) + 0.5) / s
    u = (np.arange(W)[:, None] + sub[None, :]).ravel()  # [W s] sample x, pixel units
    v = (np.arange(H)[:, None] + sub[None, :]).ravel()  # [H s]
    uu, vv = np.meshgrid(u, v)  # [H s, W s]
    rays = np.stack([uu, vv, np.ones_like(uu)], -1) @ np.linalg.inv(camera.K).T  # camera frame
    origin = -R_bc.T @ t_bc  # camera centre in the board frame
    d = rays @ R_bc  # ray directions in the board frame (R_bcᵀ d per row)
    with np.errstate(divide="ignore", invalid="ignore"):
        lam = -origin[2] / d[..., 2]
    refl = board.reflectance(origin[0] + lam * d[..., 0], origin[1] + lam * d[..., 1])
    refl = np.where(lam > 0, refl, np.nan)
    # per pixel: the fraction of samples off the board (they see the background) and the board's share
    miss = np.isnan(refl)
    on = np.where(miss, 0.0, black + (white - black) * np.nan_to_num(refl)).reshape(H, s, W, s).mean(axis=(1, 3))
    hit = (~miss).reshape(H, s, W, s).mean(axis=(1, 3))
    bg = np.asarray(background, dtype=np.float64)
    if bg.ndim == 3:
        hit, on = hit[..., None], on[..., None]
    return on + (1.0 - hit) * bg


def canonical_order(corners: np.ndarray, gray: np.ndarray, board: Board) -> np.ndarray:
    """The detected inner corners [cols * rows, 2] reordered into the board convention.

    OpenCV returns the corners row by row but may start from any of the board's ends. The
    reading is fixed by (1) handedness: the board's z axis points away from the camera, i.e.
    the image cross product of the row direction and the column direction is positive (image
    y down); (2) colour: the outer square next to corner (0, 0) is darker than the one at the
    far corner. corners are in OpenCV pixel coordinates (pixel centres at integers), as
    `cv2.findChessboardCorners` returns them; gray: the image they were found in ([H, W]).
    """

    grid = np.asarray(corners, dtype=np.float64).reshape(board.rows, board.cols, 2)
    dx, dy = grid[0, -1] - grid[0, 0], grid[-1, 0] - grid[0, 0]
    if dx[0] * dy[1] - dx[1] * dy[0] < 0:  # mirrored reading: reverse each row
        grid = grid[:, ::-1]
    obj = board.object_points()[:, :2].astype(np.float64)
    H, _ = cv2.findHomography(obj, grid.reshape(-1, 2))
    a = board.square
    probes = np.array([[-0.5 * a, -0.5 * a], [(board.cols - 0.5) * a, (board.rows - 0.5) * a]])
    pix = cv2.perspectiveTransform(probes[None], H)[0]
    h, w = gray.shape[:2]
    val = []
    for px, py in pix:  # mean of the 3 x 3 pixels around each probe (OpenCV pixel coordinates)
        r, c = int(np.clip(round(py), 1, h - 2)), int(np.clip(round(px), 1, w - 2))
        val.append(float(np.mean(gray[r - 1 : r + 2, c - 1 : c + 2])))
    if val[0] > val[1]:  # corner (0, 0) sits at the white end: the board is read turned by 180°
        grid = grid[::-1, ::-1]
    return grid.reshape(-1, 1, 2).astype(np.float32)
