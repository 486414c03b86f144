"""Registration of the static scan's Gaussians into the dynamic cameras' frame (paper Sec. 4.2).

A real capture's static scan (COLMAP) and its dynamic cameras (calibrated on a checkerboard)
live in different frames with different scales. The static Gaussians are mapped by a
similarity, in the official code's form (`Register.forward`):

    X_d = R (s (X_s - c)) + t        c = mean of the static centres (fixed), scales x s

with R from a continuous 6D vector (Zhou et al. 2019: two columns, Gram-Schmidt, cross product),
t a translation, s a scale. They are found by gradient descent (Adam) on mask losses over the
dynamic views at one frame (the object at rest before it is dropped, or frame 0):

    L = mean_v [ mean_p |A_v(p) - M_v(p)|  +  λ_c |centroid(A_v) - centroid(M_v)|² / (W² + H²)
                 + λ_rgb mean_p |G_v C_v(p) - I_v(p)| ]

A_v is the rendered alpha (sgdr's splatting renderer, differentiable w.r.t. the centres and
scales), M_v the mask, and the mask-centre term (the paper's "mask-centre loss", `LAMBDA_CENTER`)
pulls the silhouettes together when they barely overlap, where the L1 term has no gradient.
The colour term (when the frame's RGB is given) compares the rendered colours C_v with the
frame I_v, both premultiplied on black, through per-channel gains G_v fitted in closed form at
each step (the scan and the videos differ in exposure and white balance). The official code
registers on the RGB frames too (`real_must_img`): silhouettes alone leave the spin of a
symmetric object (a torus about its axis) undetermined.
Parameters are normalised so one learning rate fits all: t = t0 + ℓ δt with ℓ the initial
object size in the dynamic frame, s = s0 exp(δs), the 6D vector starts at R0's columns.

Inputs: `Gaussians` (static frame, detached), dynamic `Camera`s, masks [V][H, W] float in
[0, 1], an initial (R0 [3, 3], t0 [3], s0). Output: `Registration` (R, t, s, c, losses), with
`apply(points)` for NumPy points and `apply_gaussians(g)` for the Gaussians.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from scipy.spatial.transform import Rotation
from tqdm import tqdm

from sgdr.backend import ad
from sgdr.gaussians.model import Gaussians
from sgdr.render.splat import render


@dataclass
class RegisterConfig:
    iterations: int = 200  # Adam steps
    lr: float = 0.01  # Adam learning rate of the normalised parameters (6D vector, δt in object sizes, δs)
    lambda_center: float = 1.0  # weight of the mask-centre term λ_c
    lambda_rgb: float = 1.0  # weight of the colour term λ_rgb (0, or no images given: masks only)
    views_per_step: int = 0  # dynamic views rendered per step (0: all of them)


@dataclass
class Registration:
    R: np.ndarray  # [3, 3] rotation, static -> dynamic frame
    t: np.ndarray  # [3] translation, dynamic frame, scene units of the dynamic frame
    s: float  # scale (dynamic units per static unit)
    c: np.ndarray  # [3] the static centroid the rotation and scale act about
    losses: list = field(default_factory=list)  # loss per step

    def apply(self, points: np.ndarray) -> np.ndarray:
        """[N, 3] static-frame points -> [N, 3] dynamic-frame points."""
        return (self.s * (np.asarray(points, dtype=np.float64) - self.c)) @ self.R.T + self.t

    def as_similarity(self) -> tuple[float, np.ndarray, np.ndarray]:
        """(s, R, t') with X_d = s R X_s + t' (the plain form, for comparing with a truth)."""
        return self.s, self.R, self.t - self.s * self.R @ self.c

    def apply_gaussians(self, g):
        """The Gaussians mapped into the dynamic frame (centres, scales by s, rotations by R)."""

        p = g.to_numpy()
        q = _rotate_quaternions(p["rotations"], self.R)
        return Gaussians.from_numpy(
            self.apply(p["means"]), p["log_scales"] + np.log(self.s), q, p["color_logits"], p["opacity_logits"]
        )


def euler_xyz_deg(angles) -> np.ndarray:
    """The official INIT_R: intrinsic X-Y-Z Euler angles in degrees -> [3, 3] (Rx @ Ry @ Rz)."""

    return Rotation.from_euler("XYZ", np.asarray(angles, dtype=np.float64), degrees=True).as_matrix()


def _rotate_quaternions(q: np.ndarray, R: np.ndarray) -> np.ndarray:
    q = np.asarray(q, dtype=np.float64)
    rot = Rotation.from_matrix(R) * Rotation.from_quat(q[:, [1, 2, 3, 0]])  # scipy: (x, y, z, w)
    xyzw = rot.as_quat()
    return xyzw[:, [3, 0, 1, 2]]


def _rotation_6d(t, a):
    """Float [6] (two columns) -> 3x3 rotation as a list of rows of Dr.Jit Floats."""
    import drjit as dr

    a1 = t.Array3f(dr.gather(t.Float, a, 0), dr.gather(t.Float, a, 1), dr.gather(t.Float, a, 2))
    a2 = t.Array3f(dr.gather(t.Float, a, 3), dr.gather(t.Float, a, 4), dr.gather(t.Float, a, 5))
    b1 = dr.normalize(a1)
    b2 = dr.normalize(a2 - dr.dot(b1, a2) * b1)
    b3 = dr.cross(b1, b2)
    return [[b1[i], b2[i], b3[i]] for i in range(3)]  # columns b1, b2, b3


def _gain(t, rgb, target):
    """Per-channel gains (detached, least squares) that bring the scan's colours to the video's
    (the two recordings differ in exposure and white balance), broadcast to rgb's layout.
    rgb, target: Float [H*W*3] interleaved."""
    import drjit as dr

    n = dr.width(target) // 3
    idx = dr.arange(t.UInt32, n) * 3
    gains = []
    for c in range(3):
        r = dr.detach(dr.gather(t.Float, rgb, idx + c))
        y = dr.gather(t.Float, target, idx + c)
        gains.append(dr.sum(r * y) / dr.maximum(dr.sum(r * r), 1e-8))
    dr.eval(gains)  # width 1 each: evaluated before they meet the 3n-wide layout (no host round trip)
    channel = dr.arange(t.UInt32, 3 * n) % 3
    return dr.select(channel == 0, gains[0], dr.select(channel == 1, gains[1], gains[2]))


def mask_centroid(mask: np.ndarray) -> np.ndarray:
    """(u, v) pixel centroid of a mask [H, W] (pixel centres at +0.5)."""
    ys, xs = np.mgrid[0 : mask.shape[0], 0 : mask.shape[1]] + 0.5
    w = max(float(mask.sum()), 1e-9)
    return np.array([(xs * mask).sum() / w, (ys * mask).sum() / w])


def register(
    gaussians,
    cameras,
    masks,
    R0,
    t0,
    s0: float,
    cfg: RegisterConfig,
    render_cfg,
    seed: int = 0,
    progress: bool = False,
    images=None,
) -> Registration:
    """Fit the similarity static -> dynamic frame to the dynamic masks (see the module docstring)."""
    import drjit as dr
    import mitsuba as mi

    t = ad()
    if len(cameras) != len(masks) or not cameras:
        raise ValueError(f"register: {len(cameras)} cameras and {len(masks)} masks; need one mask per camera")
    if cfg.iterations < 0 or not cfg.lr > 0:
        raise ValueError(f"register: iterations must be >= 0 and lr > 0, got {cfg}")
    p = gaussians.to_numpy()
    X = np.asarray(p["means"], dtype=np.float64)
    c = X.mean(0)
    size = float(s0) * float(np.linalg.norm(X.max(0) - X.min(0)))  # object size in the dynamic frame
    R0, t0 = np.asarray(R0, dtype=np.float64), np.asarray(t0, dtype=np.float64).reshape(3)
    Xc = t.Array3f(*(t.Float((X - c)[:, i].astype(np.float32)) for i in range(3)))
    log_scales = t.Array3f(*(t.Float(p["log_scales"][:, i].astype(np.float32)) for i in range(3)))
    targets, centres, grids, colours = [], [], [], []
    for cam, m in zip(cameras, masks):
        m = np.asarray(m, dtype=np.float32)
        if m.shape != (cam.height, cam.width):
            raise ValueError(f"register: mask of camera {cam.name!r} is {m.shape}, the camera {cam.height}x{cam.width}")
        targets.append(t.Float(m.ravel()))
        if images is not None:  # [H, W, 3|4] premultiplied RGB of the same frame
            im = np.asarray(images[len(targets) - 1], dtype=np.float32)[..., :3]
            colours.append(t.Float(np.ascontiguousarray(im).ravel()))
        centres.append(mask_centroid(m))
        ys, xs = np.mgrid[0 : cam.height, 0 : cam.width] + 0.5
        grids.append((t.Float(xs.ravel().astype(np.float32)), t.Float(ys.ravel().astype(np.float32))))
    opt = mi.ad.Adam(lr=cfg.lr)
    opt["a"] = t.Float(np.concatenate([R0[:, 0], R0[:, 1]]).astype(np.float32))
    opt["dt"] = t.Float(np.zeros(3, np.float32))
    opt["ds"] = t.Float(np.zeros(1, np.float32))
    rng = np.random.default_rng(seed)
    losses = []

    def pose():
        rows = _rotation_6d(t, opt["a"])
        s = float(s0) * dr.exp(dr.gather(t.Float, opt["ds"], 0))
        tr = [float(t0[i]) + size * dr.gather(t.Float, opt["dt"], i) for i in range(3)]
        dr.eval(rows, s, tr)  # width-1 parameters evaluated before they meet the N-wide centres
        return rows, s, tr

    n_views = len(cameras) if cfg.views_per_step <= 0 else min(cfg.views_per_step, len(cameras))
    for _ in tqdm(range(cfg.iterations), desc="registration", unit="step", disable=not progress, leave=False):
        rows, s, tr = pose()
        means = t.Array3f(*(s * (rows[i][0] * Xc.x + rows[i][1] * Xc.y + rows[i][2] * Xc.z) + tr[i] for i in range(3)))
        g = replace(gaussians, means=means, log_scales=log_scales + dr.log(s))
        loss = t.Float(0.0)
        for v in rng.permutation(len(cameras))[:n_views]:
            cam = cameras[v]
            out = render(g, cam, render_cfg)
            alpha = out.alpha.array
            l1 = dr.mean(dr.abs(alpha - targets[v]))
            w = dr.maximum(dr.sum(alpha), 1e-6)
            cu, cv = dr.sum(alpha * grids[v][0]) / w, dr.sum(alpha * grids[v][1]) / w
            d2 = (dr.square(cu - float(centres[v][0])) + dr.square(cv - float(centres[v][1]))) / float(
                cam.width**2 + cam.height**2
            )
            term = l1 + cfg.lambda_center * d2
            if colours and cfg.lambda_rgb > 0:
                rgb = out.rgb.array  # [H*W*3] interleaved, premultiplied on black
                term = term + cfg.lambda_rgb * dr.mean(dr.abs(_gain(t, rgb, colours[v]) * rgb - colours[v]))
            loss = loss + term / n_views
        dr.backward(loss)
        opt.step()
        losses.append(float(loss[0]))
    rows, s, tr = pose()
    R = np.array([[float(rows[i][j][0]) for j in range(3)] for i in range(3)])
    return Registration(R=R, t=np.array([float(x[0]) for x in tr]), s=float(s[0]), c=c, losses=losses)
