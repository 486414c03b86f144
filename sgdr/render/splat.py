"""Differentiable tile-based Gaussian splatting (Eqs. 1-3 of the seed paper), in Dr.Jit.

    render(gaussians, camera, cfg) -> RenderOutput(rgb TensorXf [H, W, 3], alpha TensorXf [H, W])

Three phases, as in 3DGS (Kerbl et al. 2023):

1. **Projection** (`project`, recorded Dr.Jit AD, one thread per Gaussian): camera-space
   centre p = W μ + t, image centre (u, v) = (fx p_x/p_z + cx, fy p_y/p_z + cy), screen
   covariance Σ' = J W Σ Wᵀ Jᵀ + δ I (EWA splatting; δ = `cfg.dilation` px² low-pass),
   its inverse (the *conic*), a footprint radius (3σ, or less where the opacity is low: the
   disc outside which α < `cfg.alpha_min`), colour c = sigmoid(logits) and opacity
   σ = sigmoid(logit). Gaussians with p_z <= `cfg.near` are culled.
2. **Binning** (`bin_gaussians`, no gradients): each visible Gaussian is duplicated into
   every 16x16 tile its footprint disc reaches. The per-Gaussian tile counts are turned
   into offsets by a prefix sum, the entries are sorted by tile with a stable counting sort
   (`dr.detail.block_mkperm`, the pass under `dr.argsort`) of detached keys after the
   Gaussians were put in depth order (`dr.argsort`), so every tile holds a
   variable-length, front-to-back list. Nothing is ever dropped by a per-tile cap.
3. **Compositing** (`_Rasterize`, a `dr.CustomOp`; one SIMD lane per strip of
   `cfg.pixels_per_thread` pixels of a tile column, so each list entry is loaded once per
   strip and a packet of lanes walks one tile list in lock-step): front-to-back
   alpha blending over the pixel's tile list (Eq. 3),
       α_i = min(0.99, σ_i exp(-½ dᵀ Σ'⁻¹ d)),   C = Σ_i c_i α_i T_i + T_N · background,
       T_i = Π_{j<i} (1 - α_j),
   skipping α_i < `cfg.alpha_min` and stopping before T would fall below
   `cfg.transmittance_min`. Its adjoint is written by hand and walks each pixel's list back
   to front, recovering T_i = T_{i+1} / (1 - α_i) and the normalised colour behind i,
   S_i = c_{i+1} α_{i+1} + (1 - α_{i+1}) S_{i+1}, so that
       ∂C/∂α_i = T_i (c_i - S_i) - T_N / (1 - α_i) · background,   ∂A/∂α_i = T_N / (1 - α_i)
   with A = 1 - T_N the accumulated opacity. Per-Gaussian adjoints are accumulated in fixed
   point (below). The custom op hands its input adjoints (image centre, conic, colour,
   opacity) back to Dr.Jit's AD graph, which carries them through the projection into every
   field of `Gaussians`, and on into whatever computed the means upstream (IDW skinning of
   simulated anchors).

Deterministic adjoint accumulation: every lane (pixel strip) of a tile adds its share of an
entry's adjoint, and a Gaussian collects the adjoints of all its entries. Float scatter-adds
would sum these in an order set by Dr.Jit's thread scheduling, so gradients would change with
the thread count and from run to run. Instead each strip's share is rounded to a 64-bit
integer in units of 2^-e and added with an integer scatter-add (`Int64`, exact, so any order
gives the same sum), straight into per-Gaussian accumulators; one conversion back to float
per Gaussian at the end. The exponents e are fixed before the loop from bounds that hold for
every term (`_fixed_point_scales`): the image adjoints are first divided by a power of two
2^e_γ so that γ = |δL/δC|_1 + |δL/δA - δL/δC·background| <= 1 at every pixel; then
|δL/δα_i| <= γ and |δL/δc_i| <= γ, every pixel of a Gaussian's tiles lies within R = radius +
tile_size of its centre, and its tiles hold at most P = (2R)² pixels, so a component's sum is
bounded by 2 P γ times 1 (opacity, colour), (|a| + |b|) R or (|b| + |c|) R (centre), R² (conic)
(the 2 absorbs rounding). With that bound below 2^(61 - e) the sum fits in 61 bits, i.e. a
resolution of about 2^-61 of the bound, far below float32's 2^-24 of the value for any
gradient not ~10^11 smaller than its bound. The exponents, the scaling by 2^e_γ (exact) and the
max over pixels giving e_γ (max is exact in any order) do not depend on the schedule either.

Memory: the forward keeps, per pixel, the final transmittance and the index after the last
contributing entry (8 bytes/pixel), plus the tile lists and 48 bytes of packed attributes per
list entry; nothing per (pixel, Gaussian). The backward accumulates 9 Int64 adjoints (72 bytes)
per Gaussian (per worker thread on the LLVM backend, whose `Expand` scatter mode gives each
worker a copy).

Pixel centres are at integer + 0.5 (see `sgdr.cameras`). The slow NumPy reference of this file is
`sgdr.render.reference` (tests only).
"""

from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import numpy as np

from sgdr.backend import ad
from sgdr.cameras import Camera
from sgdr.gaussians.model import Gaussians
from sgdr.render.config import RenderConfig

# Reduction mode of the adjoint's fixed-point scatter-add. Auto = Expand on the LLVM backend
# (per-core copies, no atomics), measured fastest here against Local and Direct.
_SCATTER_MODE = dr.ReduceMode.Auto
# Fixed-point accumulation (module docstring): a component's bound is kept below 2^(61 - e),
# leaving two bits of Int64 headroom; exponents are clamped to keep 2^±e a normal float.
_FIXED_BITS = 60
_MIN_EXPONENT = -120
# Tile lists are sorted by a single stable counting sort when the tile count is at most this
# (1024x1024 images with 16-pixel tiles have 4096 tiles); above it, by dr.argsort.
_MAX_COUNTING_SORT_BUCKETS = 1 << 14


class RenderError(ValueError):
    """Invalid renderer input; the message names the offending field."""


@dataclass
class RenderOutput:
    rgb: object  # TensorXf [H, W, 3] linear RGB in [0, 1], background composited
    alpha: object  # TensorXf [H, W] accumulated opacity A = 1 - T_N


@dataclass
class Projected:
    """Per-Gaussian screen-space quantities (phase 1); AD-attached to `Gaussians`."""

    mean2d: object  # Array2f [M] image centre (u, v), pixels
    conic: object  # Array3f [M] (a, b, c) of Σ'⁻¹ = [[a, b], [b, c]], 1/pixels²
    color: object  # Array3f [M] RGB in [0, 1]
    opacity: object  # Float [M] in (0, 1)
    depth: object  # Float [M] camera-space z, scene units (detached)
    radius: object  # Float [M] footprint radius, pixels; 0 for culled Gaussians (detached)


@dataclass
class Bins:
    """Tile lists (phase 2): non-differentiable index arrays, rebuilt every call."""

    tiles_x: int
    tiles_y: int
    n_entries: int  # total (Gaussian, tile) pairs
    entry_gaussian: object  # UInt32 [n_entries] Gaussian index, sorted by (tile, depth)
    tile_start: object  # UInt32 [tiles] first entry of each tile
    tile_end: object  # UInt32 [tiles] one past the last entry of each tile


# ---------------------------------------------------------------------------- phase 1
def _quat_to_matrix(q):
    """Unit quaternion (w, x, y, z) (normalised here) -> 3x3 rotation rows."""
    n = dr.sqrt(dr.maximum(q.x * q.x + q.y * q.y + q.z * q.z + q.w * q.w, 1e-24))
    w, x, y, z = q.x / n, q.y / n, q.z / n, q.w / n
    return (
        (1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)),
        (2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)),
        (2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)),
    )


def camera_constants(camera: Camera, cfg: RenderConfig) -> np.ndarray:
    """The 18 numbers of a view that phase 1 reads, float64 [18]: R (row-major, 9), t (3), fx, fy,
    cx, cy and the guard band's limits of x/z and y/z."""
    K = np.asarray(camera.K, np.float64)
    lim_x = cfg.guard_band * 0.5 * camera.width / K[0, 0]
    lim_y = cfg.guard_band * 0.5 * camera.height / K[1, 1]
    return np.concatenate(
        [np.asarray(camera.R, np.float64).ravel(), np.asarray(camera.t, np.float64).ravel(),
         [K[0, 0], K[1, 1], K[0, 2], K[1, 2], lim_x, lim_y]]
    )  # fmt: skip


def project(g: Gaussians, camera: Camera, cfg: RenderConfig) -> Projected:
    """Phase 1: EWA projection of every Gaussian (recorded AD; one thread per Gaussian)."""
    t = ad()
    # camera constants as opaque JIT scalars: one compiled kernel serves every view
    return project_with(g, [dr.opaque(t.Float, float(x)) for x in camera_constants(camera, cfg)], cfg)


def project_with(g: Gaussians, constants: list, cfg: RenderConfig) -> Projected:
    """`project` with the view's 18 constants (`camera_constants`) given as Dr.Jit values: opaque
    scalars (one view), or one per Gaussian (`render_batch`: each Gaussian seen by its own view)."""
    t = ad()
    R = [constants[0:3], constants[3:6], constants[6:9]]
    tc = constants[9:12]
    fx, fy, cx, cy, lim_x, lim_y = constants[12:18]
    m = g.means
    # camera-space centre p = W μ + t  (OpenCV axes, z forward)
    p = [R[r][0] * m.x + R[r][1] * m.y + R[r][2] * m.z + tc[r] for r in range(3)]
    z = p[2]
    visible = z > cfg.near
    zs = dr.select(visible, z, 1.0)  # safe denominator for culled Gaussians
    inv_z = 1.0 / zs
    u = fx * p[0] * inv_z + cx
    v = fy * p[1] * inv_z + cy
    # Jacobian of the perspective map at p, with the 3DGS guard-band clamp of x/z, y/z
    tx = dr.clip(p[0] * inv_z, -lim_x, lim_x)
    ty = dr.clip(p[1] * inv_z, -lim_y, lim_y)
    J = ((fx * inv_z, 0.0, -fx * tx * inv_z), (0.0, fy * inv_z, -fy * ty * inv_z))
    # T = J W (2x3), then A = T R_q S (2x3) and Σ' = A Aᵀ
    T = [[J[r][0] * R[0][c] + J[r][1] * R[1][c] + J[r][2] * R[2][c] for c in range(3)] for r in range(2)]
    Rq = _quat_to_matrix(g.rotations)
    s = (dr.exp(g.log_scales.x), dr.exp(g.log_scales.y), dr.exp(g.log_scales.z))
    A = [[(T[r][0] * Rq[0][c] + T[r][1] * Rq[1][c] + T[r][2] * Rq[2][c]) * s[c] for c in range(3)] for r in range(2)]
    a = A[0][0] * A[0][0] + A[0][1] * A[0][1] + A[0][2] * A[0][2] + cfg.dilation
    b = A[0][0] * A[1][0] + A[0][1] * A[1][1] + A[0][2] * A[1][2]
    c = A[1][0] * A[1][0] + A[1][1] * A[1][1] + A[1][2] * A[1][2] + cfg.dilation
    det = a * c - b * b
    visible &= det > 0
    inv_det = 1.0 / dr.select(visible, det, 1.0)
    conic = t.Array3f(c * inv_det, -b * inv_det, a * inv_det)
    # 3σ footprint from the larger eigenvalue of Σ' (detached: binning only)
    ad_, cd_, dd_ = dr.detach(a), dr.detach(c), dr.detach(det)
    mid = 0.5 * (ad_ + cd_)
    lam = mid + dr.sqrt(dr.maximum(0.1, mid * mid - dd_))
    color = dr.rcp(1.0 + dr.exp(-g.color_logits))
    opacity = dr.rcp(1.0 + dr.exp(-g.opacity_logits))
    # α >= alpha_min needs dᵀΣ'⁻¹d <= 2 ln(σ / alpha_min), inside |d| <= sqrt(that · λ_max):
    # the footprint is that disc, capped at 3σ as in 3DGS (a pure work saving: pixels outside it
    # are skipped by the α test anyway, except beyond 3σ where 3DGS also truncates)
    k_sigma = dr.minimum(3.0, dr.sqrt(dr.maximum(2.0 * dr.log(dr.detach(opacity) / cfg.alpha_min), 0.0)))
    radius = dr.select(visible, dr.ceil(k_sigma * dr.sqrt(lam)), 0.0)
    return Projected(
        mean2d=t.Array2f(u, v),
        conic=conic,
        color=color,
        opacity=opacity,
        depth=dr.detach(z),
        radius=radius,
    )


# ---------------------------------------------------------------------------- phase 2
def tile_rects(u, v, radius, width: int, height: int, tile: int, cells=None):
    """Tile rectangle [x0, x1) x [y0, y1) covered by each footprint (3DGS `getRect`), clamped to
    the image's tiles, or with `cells` = (first tile column, first tile row) Float per Gaussian
    and (tiles across, tiles down) of one cell, to the Gaussian's own cell of an atlas of images
    (`render_batch`: no footprint reaches into a neighbouring image)."""
    t = ad()
    if cells is None:
        lo_x = lo_y = 0.0
        hi_x, hi_y = (dr.opaque(t.Float, -(-n // tile)) for n in (width, height))
    else:
        lo_x, lo_y, n_x, n_y = cells
        hi_x, hi_y = lo_x + dr.opaque(t.Float, n_x), lo_y + dr.opaque(t.Float, n_y)

    def clamp(x, lo, hi):
        return t.UInt32(dr.clip(x, lo, hi))

    x0 = clamp(dr.floor((u - radius) / tile), lo_x, hi_x)
    x1 = clamp(dr.floor((u + radius + tile - 1) / tile), lo_x, hi_x)
    y0 = clamp(dr.floor((v - radius) / tile), lo_y, hi_y)
    y1 = clamp(dr.floor((v + radius + tile - 1) / tile), lo_y, hi_y)
    return x0, x1, y0, y1


def _first_greater(sorted_values, query, n: int):
    """For each query, the first index k in [0, n) with sorted_values[k] > query (binary search
    with an opaque bound, so the kernel is reused for every n of the same bit length)."""
    t = ad()
    lo = dr.zeros(t.UInt32, dr.width(query))
    hi = dr.opaque(t.UInt32, n - 1) + lo  # answer lies in [lo, hi]
    for _ in range(max(int(n - 1).bit_length(), 1)):
        mid = (lo + hi) >> 1
        go_right = dr.gather(t.UInt32, sorted_values, mid) <= query
        lo = dr.select(go_right, mid + 1, lo)
        hi = dr.select(go_right, hi, mid)
    return lo


def bin_gaussians(proj: Projected, width: int, height: int, cfg: RenderConfig, checks=None, cells=None) -> Bins:
    """Phase 2: variable-length, depth-ordered tile lists (prefix sum + stable argsort).

    checks: optional (arrays, fn): the arrays are evaluated in the same launch as the tile
    counts and fn(arrays) runs before anything is allocated from those counts (used to reject
    non-finite inputs without an extra synchronisation). cells: optional per-Gaussian cell
    bounds of an atlas (`tile_rects`)."""
    t = ad()
    ts = int(cfg.tile_size)
    tiles_x, tiles_y = -(-width // ts), -(-height // ts)
    n_tiles = tiles_x * tiles_y
    m = dr.width(proj.radius)
    # Gaussians in front-to-back order; entries are generated in this order, so a *stable*
    # sort by tile afterwards leaves every tile list sorted by depth.
    depth = dr.select(proj.radius > 0, proj.depth, dr.inf)
    order = dr.argsort(depth)
    u = dr.gather(t.Float, dr.detach(proj.mean2d.x), order)
    v = dr.gather(t.Float, dr.detach(proj.mean2d.y), order)
    r = dr.gather(t.Float, proj.radius, order)
    if cells is not None:
        cells = (dr.gather(t.Float, cells[0], order), dr.gather(t.Float, cells[1], order), cells[2], cells[3])
    x0, x1, y0, y1 = tile_rects(u, v, r, width, height, ts, cells)
    w_rect = x1 - x0
    n = dr.select(r > 0, w_rect * (y1 - y0), 0)
    offsets = dr.cumsum(n)  # inclusive prefix sum, UInt32 [M]
    extra, check = checks if checks is not None else ([], None)
    dr.eval(offsets, x0, y0, w_rect, *extra)
    if check is not None:
        check(extra)
    total = int(offsets[m - 1]) if m > 0 else 0
    if total == 0:
        zeros = dr.zeros(t.UInt32, n_tiles)
        return Bins(tiles_x, tiles_y, 0, t.UInt32(), zeros, zeros)
    e = dr.arange(t.UInt32, total)
    # k: position in depth order of the Gaussian owning entry e (first offsets[k] > e)
    k = _first_greater(offsets, e, m)
    local = e - (dr.gather(t.UInt32, offsets, k) - dr.gather(t.UInt32, n, k))
    w_k = dr.maximum(dr.gather(t.UInt32, w_rect, k), 1)  # >= 1 also in masked SIMD tail lanes
    tile_x = dr.gather(t.UInt32, x0, k) + local % w_k
    tile_y = dr.gather(t.UInt32, y0, k) + local // w_k
    # keep the entry only if the footprint disc reaches a pixel centre of the tile (drops the
    # corners of the bounding square); dropped entries get a sentinel key and sort to the end
    u_k, v_k, r_k = dr.gather(t.Float, u, k), dr.gather(t.Float, v, k), dr.gather(t.Float, r, k)
    tx0, ty0 = t.Float(tile_x * ts) + 0.5, t.Float(tile_y * ts) + 0.5
    dx = u_k - dr.clip(u_k, tx0, tx0 + (ts - 1))
    dy = v_k - dr.clip(v_k, ty0, ty0 + (ts - 1))
    keep = dx * dx + dy * dy <= r_k * r_k
    tile_id = dr.select(keep, tile_y * dr.opaque(t.UInt32, tiles_x) + tile_x, dr.opaque(t.UInt32, n_tiles))
    if n_tiles + 1 <= _MAX_COUNTING_SORT_BUCKETS:
        # one stable counting-sort pass (the primitive under dr.argsort, which would spend three
        # 11-bit radix passes on these small keys)
        perm = t.UInt32(dr.detail.block_mkperm(tile_id, total, n_tiles + 1))
    else:
        perm = dr.argsort(tile_id)
    entry_gaussian = dr.gather(t.UInt32, order, dr.gather(t.UInt32, k, perm))
    counts = dr.zeros(t.UInt32, n_tiles)
    dr.scatter_add(counts, t.UInt32(1), tile_id, keep)
    tile_end = dr.cumsum(counts)
    tile_start = tile_end - counts
    dr.eval(entry_gaussian, tile_start, tile_end)
    return Bins(tiles_x, tiles_y, total, entry_gaussian, tile_start, tile_end)


# ---------------------------------------------------------------------------- phase 3
def _pixel_layout(width: int, height: int, tile: int, tiles_x: int, tiles_y: int, k_px: int):
    """Thread layout of phase 3. Threads are tile-major (all threads of tile 0, then tile 1, ...)
    so that a SIMD packet walks one tile list in lock-step, and each thread shades a vertical
    strip of `k_px` pixels, so one load of a list entry serves k_px pixels.

    Returns per thread: tile id, pixel column x, first row y0 (strip rows y0 .. y0 + k_px - 1);
    and for every image pixel (row-major) its (thread, strip slot) as a flat index
    thread * k_px + slot.
    """
    t = ad()
    per_tile = tile * tile // k_px
    n_threads, n_pixels = tiles_x * tiles_y * per_tile, width * height
    # image sizes as opaque JIT scalars: one compiled kernel serves every image size
    width_, tiles_x_ = dr.opaque(t.UInt32, width), dr.opaque(t.UInt32, tiles_x)
    i = dr.arange(t.UInt32, n_threads)
    tile_id = i // per_tile
    local = i % per_tile
    px = (tile_id % tiles_x_) * tile + local % tile
    py0 = (tile_id // tiles_x_) * tile + (local // tile) * k_px
    x = dr.arange(t.UInt32, n_pixels)
    ix, iy = x % width_, x // width_
    thread = ((iy // tile) * tiles_x_ + ix // tile) * per_tile + ((iy % tile) // k_px) * tile + ix % tile
    image_to_slot = thread * k_px + (iy % tile) % k_px
    return tile_id, px, py0, image_to_slot


def _gaussian_alpha(mean2d, conic, opacity, pxf, pyf, cfg):
    """α = min(0.99, σ exp(power)), power = -½ dᵀ Σ'⁻¹ d with d = centre - pixel centre."""
    dx = mean2d.x - pxf
    dy = mean2d.y - pyf
    power = -0.5 * (conic.x * dx * dx + conic.z * dy * dy) - conic.y * dx * dy
    g = dr.exp(power)
    raw = opacity * g
    alpha = dr.minimum(cfg.alpha_max, raw)
    contrib = (power <= 0.0) & (alpha >= cfg.alpha_min)
    return dx, dy, g, raw, alpha, contrib


def _pow2(e):
    """2^e as a Float, exactly, for integer e (Int32) in [-126, 127] (built from the bits)."""
    t = ad()
    return dr.reinterpret_array(t.Float, t.UInt32(e + 127) << 23)


def _floor_log2(x):
    """floor(log2 x), exactly, for positive normal Float x (read from the exponent bits)."""
    t = ad()
    return t.Int32(dr.reinterpret_array(t.UInt32, x) >> 23) - 127


def _fixed_point_scales(conic, radius, n_pixels: int, tile: int):
    """Per-Gaussian fixed-point exponents of the adjoint's three component groups (module
    docstring): Int32 [M] each for (centre u, v), (conic a, b, c), (opacity, colour), chosen so
    that 2^e times the group's bound (for image adjoints with γ <= 1) stays below 2^61."""
    R = radius + float(tile)  # every pixel of the Gaussian's tiles is within R of its centre
    P = dr.minimum(4.0 * R * R, float(n_pixels))  # pixels in its tiles (at most the image)
    a, b, c = dr.abs(conic.x), dr.abs(conic.y), dr.abs(conic.z)
    bounds = (
        2.0 * P * dr.maximum(a + b, b + c) * R,  # δu, δv
        2.0 * P * R * R,  # δa, δb, δc
        2.0 * P,  # δσ, δcolour
    )
    # B >= 2 P >= 2 tile² > 1, so e <= _FIXED_BITS; huge footprints are capped at float max
    return tuple(dr.maximum(_FIXED_BITS - _floor_log2(dr.minimum(B, 3e38)), _MIN_EXPONENT) for B in bounds)


# Per-entry packed attributes: one packet load per loop iteration instead of twelve gathers (the
# LLVM backend turns gathers of consecutive floats into aligned packet loads + a transpose).
_PACK = 12  # u, v, conic a, b, c, opacity, r, g, b, fixed-point scales 2^e of the 3 groups
_GRAD = 9  # δu, δv, δa, δb, δc, δσ, δr, δg, δb
_GROUP = (0, 0, 1, 1, 1, 2, 2, 2, 2)  # fixed-point group of each adjoint component


def _pack_entries(mean2d, conic, color, opacity, scales, entry_gaussian):
    """Flat Float [n_entries * _PACK]: the attributes of each tile-list entry, in list order."""
    t = ad()
    comps = [mean2d.x, mean2d.y, conic.x, conic.y, conic.z, opacity, color.x, color.y, color.z, *scales]
    gathered = [dr.gather(t.Float, c_, entry_gaussian) for c_ in comps]
    return dr.ravel(t.ArrayXf(gathered))


def _load(packed, j, active=True):
    """(mean2d, conic, opacity, colour, fixed-point scales) of entries j."""
    t = ad()
    e = dr.gather(t.ArrayXf, packed, j, active, shape=(_PACK, dr.width(j)))
    return t.Array2f(e[0], e[1]), t.Array3f(e[2], e[3], e[4]), e[5], t.Array3f(e[6], e[7], e[8]), (e[9], e[10], e[11])


class _Rasterize(dr.CustomOp):
    """Phase 3 as a custom differentiable op: front-to-back forward, back-to-front adjoint.

    Inputs (AD): mean2d Array2f [M], conic Array3f [M], color Array3f [M], opacity Float [M].
    Inputs (no AD): radius Float [M] footprint radius, pixels (for the fixed-point bounds).
    Outputs: rgb Float [H*W*3] (row-major, interleaved), alpha Float [H*W].
    """

    def eval(self, mean2d, conic, color, opacity, radius, bins: Bins, width, height, cfg, background):
        t = ad()
        self.m = dr.width(opacity)
        self.bins, self.cfg, self.bg = bins, cfg, background
        ts, kp = int(cfg.tile_size), int(cfg.pixels_per_thread)
        tile_id, px, py0, image_to_slot = _pixel_layout(width, height, ts, bins.tiles_x, bins.tiles_y, kp)
        self.layout = (tile_id, px, py0, image_to_slot)
        self.exponents = _fixed_point_scales(conic, radius, width * height, ts)
        scales = [_pow2(e) for e in self.exponents]
        packed = _pack_entries(mean2d, conic, color, opacity, scales, bins.entry_gaussian)
        dr.eval(packed)
        self.packed = packed
        n = dr.width(tile_id)
        start = dr.gather(t.UInt32, bins.tile_start, tile_id)
        end = dr.gather(t.UInt32, bins.tile_end, tile_id)
        pxf = t.Float(px) + 0.5
        pyf = [t.Float(py0 + k) + 0.5 for k in range(kp)]
        w_, h_ = dr.opaque(t.UInt32, width), dr.opaque(t.UInt32, height)
        done0 = [~((px < w_) & (py0 + k < h_)) for k in range(kp)]  # outside the image
        t_min = float(cfg.transmittance_min)

        def cond(j, T, C, last, done):
            alive = ~done[0]
            for d in done[1:]:
                alive |= ~d
            return (j < end) & alive

        def body(j, T, C, last, done):
            m2, co, op, col, _ = _load(packed, j)
            T, C, last, done = list(T), list(C), list(last), list(done)
            for k in range(kp):
                _, _, _, _, alpha, contrib = _gaussian_alpha(m2, co, op, pxf, pyf[k], cfg)
                contrib &= ~done[k]
                T_next = T[k] * (1.0 - alpha)
                stop = contrib & (T_next < t_min)
                contrib &= ~stop
                C[k] = dr.select(contrib, C[k] + col * (alpha * T[k]), C[k])
                T[k] = dr.select(contrib, T_next, T[k])
                last[k] = dr.select(contrib, j + 1, last[k])
                done[k] = done[k] | stop
            return j + 1, tuple(T), tuple(C), tuple(last), tuple(done)

        j, T, C, last, _ = dr.while_loop(
            (
                t.UInt32(start),
                tuple(dr.ones(t.Float, n) for _ in range(kp)),
                tuple(dr.zeros(t.Array3f, n) for _ in range(kp)),
                tuple(t.UInt32(start) for _ in range(kp)),
                tuple(done0),
            ),
            cond,
            body,
            label="splat_forward",
        )
        dr.eval(T, C, last)  # one loop kernel (the scatters below would each re-run it)
        # interleave the strip slots: flat index thread * kp + slot
        bg = t.Array3f(*background)
        T_all = dr.zeros(t.Float, n * kp)
        C_all = dr.zeros(t.Array3f, n * kp)
        last_all = dr.zeros(t.UInt32, n * kp)
        slot0 = dr.arange(t.UInt32, n) * kp
        for k in range(kp):
            dr.scatter(T_all, T[k], slot0 + k)
            dr.scatter(C_all, C[k] + T[k] * bg, slot0 + k)
            dr.scatter(last_all, last[k], slot0 + k)
        self.T_final, self.last = T_all, last_all
        dr.eval(T_all, C_all, last_all)
        rgb = dr.gather(t.Array3f, C_all, image_to_slot)
        alpha = 1.0 - dr.gather(t.Float, T_all, image_to_slot)
        return dr.ravel(rgb), alpha

    def backward(self):
        t = ad()
        g_rgb_flat, g_alpha_img = self.grad_out()
        cfg, bins = self.cfg, self.bins
        kp = int(cfg.pixels_per_thread)
        tile_id, px, py0, image_to_slot = self.layout
        n = dr.width(tile_id)
        n_px = dr.width(image_to_slot)
        # adjoints of the image, into (thread, slot) order; pixels outside the image stay 0
        g_C_all = dr.zeros(t.Array3f, n * kp)
        g_A_all = dr.zeros(t.Float, n * kp)
        dr.scatter(g_C_all, dr.unravel(t.Array3f, g_rgb_flat + dr.zeros(t.Float, 3 * n_px)), image_to_slot)
        dr.scatter(g_A_all, g_alpha_img + dr.zeros(t.Float, n_px), image_to_slot)
        slot0 = dr.arange(t.UInt32, n) * kp
        g_C = [dr.gather(t.Array3f, g_C_all, slot0 + k) for k in range(kp)]
        g_A = [dr.gather(t.Float, g_A_all, slot0 + k) for k in range(kp)]
        T_N = [dr.gather(t.Float, self.T_final, slot0 + k) for k in range(kp)]
        last = [dr.gather(t.UInt32, self.last, slot0 + k) for k in range(kp)]
        bg = t.Array3f(*self.bg)
        # fixed point (module docstring): divide the image adjoints by 2^e_γ so that γ <= 1
        g_bg_all = dr.dot(g_C_all, bg)
        gamma = dr.max(dr.abs(g_C_all.x) + dr.abs(g_C_all.y) + dr.abs(g_C_all.z) + dr.abs(g_A_all - g_bg_all))
        gamma_finite = dr.isfinite(gamma)  # (NaN/inf adjoints give NaN gradients, as a float sum would)
        e_gamma = dr.select(
            gamma_finite & (gamma > 0), dr.clip(_floor_log2(dr.maximum(gamma, 1e-30)) + 1, -125, 126), 0
        )
        inv_gamma = _pow2(-e_gamma)
        g_C = [g * inv_gamma for g in g_C]
        g_A = [g * inv_gamma for g in g_A]
        g_bg = [dr.dot(g_C[k], bg) for k in range(kp)]  # δL/δC · background
        # every thread of a tile starts at the tile's furthest last contributor (lock-step SIMD)
        tile_last = dr.zeros(t.UInt32, bins.tiles_x * bins.tiles_y)
        for k in range(kp):
            dr.scatter_reduce(dr.ReduceOp.Max, tile_last, last[k], tile_id)
        start = dr.gather(t.UInt32, bins.tile_start, tile_id)
        j0 = dr.maximum(dr.gather(t.UInt32, tile_last, tile_id), start)
        pxf = t.Float(px) + 0.5
        pyf = [t.Float(py0 + k) + 0.5 for k in range(kp)]
        packed = self.packed
        m = self.m
        # per-Gaussian fixed-point adjoint accumulator, Int64 [M * _GRAD]
        d_fixed = dr.zeros(t.Int64, m * _GRAD)
        zero = dr.zeros(t.Float, n)

        def cond(j, T, S):
            return j > start

        def body(j, T, S):
            jj = j - 1
            m2, co, op, col, scale = _load(packed, jj)
            T, S = list(T), list(S)
            acc = [zero] * 9  # Σ over the strip: δu, δv, δa, δb, δc, δσ, δr, δg, δb
            any_contrib = t.Bool(False)
            for k in range(kp):
                dx, dy, gauss, raw, alpha, contrib = _gaussian_alpha(m2, co, op, pxf, pyf[k], cfg)
                contrib &= jj < last[k]
                one_minus = 1.0 - alpha
                T_i = T[k] / one_minus  # transmittance in front of entry jj
                # δL/δα_i (see module docstring); clamped α has no gradient
                dalpha = T_i * dr.dot(col - S[k], g_C[k]) + (T_N[k] / one_minus) * (g_A[k] - g_bg[k])
                dalpha = dr.select(contrib & (raw < cfg.alpha_max), dalpha, 0.0)
                dpower = dalpha * alpha  # α = σ G, G = exp(power)
                dcol = dr.select(contrib, alpha * T_i, 0.0) * g_C[k]  # δL/δc_i = α_i T_i δL/δC
                terms = (
                    -dpower * (co.x * dx + co.y * dy),  # δu
                    -dpower * (co.z * dy + co.y * dx),  # δv
                    -0.5 * dpower * dx * dx,  # δ conic a
                    -dpower * dx * dy,  # δ conic b
                    -0.5 * dpower * dy * dy,  # δ conic c
                    dalpha * gauss,  # δσ
                    dcol.x,
                    dcol.y,
                    dcol.z,
                )
                acc = [a_ + b_ for a_, b_ in zip(acc, terms)]
                any_contrib |= contrib
                S[k] = dr.select(contrib, col * alpha + one_minus * S[k], S[k])
                T[k] = dr.select(contrib, T_i, T[k])
            fixed = t.ArrayXi64([t.Int64(dr.round(a_ * scale[_GROUP[c_]])) for c_, a_ in enumerate(acc)])
            gaussian = dr.gather(t.UInt32, bins.entry_gaussian, jj)
            dr.scatter_add(d_fixed, fixed, gaussian, any_contrib, mode=_SCATTER_MODE)
            return jj, tuple(T), tuple(S)

        dr.while_loop(
            (t.UInt32(j0), tuple(t.Float(x) for x in T_N), tuple(dr.zeros(t.Array3f, n) for _ in range(kp))),
            cond,
            body,
            label="splat_backward",
        )
        # fixed point -> float: δ = sum · 2^-e · 2^e_γ (NaN where the image adjoints were not finite)
        d_fixed = dr.gather(t.ArrayXi64, d_fixed, dr.arange(t.UInt32, m), shape=(_GRAD, m))
        unscale = [_pow2(-e) for e in self.exponents]
        to_image = dr.select(gamma_finite, _pow2(e_gamma), dr.nan)
        d = [t.Float(d_fixed[c_]) * unscale[_GROUP[c_]] * to_image for c_ in range(_GRAD)]
        self.set_grad_in("mean2d", t.Array2f(d[0], d[1]))
        self.set_grad_in("conic", t.Array3f(d[2], d[3], d[4]))
        self.set_grad_in("opacity", d[5])
        self.set_grad_in("color", t.Array3f(d[6], d[7], d[8]))

    def forward(self):
        raise NotImplementedError(
            "sgdr.render.splat: forward-mode derivatives of the rasteriser are not implemented; use dr.backward"
        )

    def name(self):
        return "GaussianRasterize"


# ---------------------------------------------------------------------------- entry point
_FIELDS = ("means", "log_scales", "rotations", "color_logits", "opacity_logits")


def _nonfinite_counts(g: Gaussians) -> list:
    """Per field, the number of Gaussians holding NaN/inf (lazy UInt32 arrays of width 1)."""
    t = ad()
    counts = []
    for name in _FIELDS:
        v = dr.detach(getattr(g, name))
        comps = [v] if isinstance(v, t.Float) else [v[i] for i in range(len(v))]
        s = comps[0]
        for c in comps[1:]:
            s = s + c
        counts.append(dr.count(~dr.isfinite(s)))
    return counts


def _raise_nonfinite(counts: list) -> None:
    """Raise RenderError naming the first field with non-finite entries (counts evaluated)."""
    for name, n in zip(_FIELDS, counts):
        if int(n[0]) > 0:
            raise RenderError(f"render: Gaussians.{name} has {int(n[0])} non-finite entries (NaN or inf)")


def _check_sizes(g: Gaussians) -> int:
    m = dr.width(g.opacity_logits)
    for name in ("means", "log_scales", "rotations", "color_logits"):
        w = dr.width(getattr(g, name))
        if w != m:
            raise RenderError(f"render: Gaussians.{name} has {w} entries but opacity_logits has {m}")
    return m


def render(gaussians: Gaussians, camera: Camera, cfg: RenderConfig) -> RenderOutput:
    """Render one view. Differentiable w.r.t. every field of `gaussians` (reverse mode).

    gaussians: M Gaussians (M may be 0: the image is the background, alpha 0).
    camera: OpenCV pinhole camera; the image is camera.height x camera.width.
    Returns rgb TensorXf [H, W, 3] and alpha TensorXf [H, W].
    """
    t = ad()
    if len(cfg.background) != 3:
        raise RenderError(f"RenderConfig.background must have 3 entries, got {list(cfg.background)}")
    if cfg.tile_size <= 0:
        raise RenderError(f"RenderConfig.tile_size must be positive, got {cfg.tile_size}")
    if cfg.pixels_per_thread <= 0 or cfg.tile_size % cfg.pixels_per_thread:
        raise RenderError(
            f"RenderConfig.pixels_per_thread ({cfg.pixels_per_thread}) must divide tile_size ({cfg.tile_size})"
        )
    width, height = camera.width, camera.height
    bg = [float(x) for x in cfg.background]
    m = _check_sizes(gaussians)
    if m > 0:
        checks = (_nonfinite_counts(gaussians), _raise_nonfinite) if cfg.check_finite else None
        proj = project(gaussians, camera, cfg)
        bins = bin_gaussians(proj, width, height, cfg, checks)
    if m == 0 or bins.n_entries == 0:
        # nothing visible: background, alpha 0, attached to the inputs with zero gradients so a
        # caller's dr.backward stays well defined
        def attached_zeros(n):
            # opaque: a literal 0 would be folded out of the AD graph; a fresh one per output
            # because Dr.Jit broadcasts a width-1 variable in place
            g = gaussians
            s = dr.sum(g.means.x) + dr.sum(g.log_scales.x) + dr.sum(g.rotations.x)
            s = s + dr.sum(g.color_logits.x) + dr.sum(g.opacity_logits)
            return dr.opaque(t.Float, 0.0) * s + dr.zeros(t.Float, n)

        bg_img = np.broadcast_to(np.array(bg, np.float32), (height, width, 3)).ravel()
        rgb = t.TensorXf(attached_zeros(height * width * 3) + t.Float(bg_img), (height, width, 3))
        alpha = t.TensorXf(attached_zeros(height * width), (height, width))
        return RenderOutput(rgb=rgb, alpha=alpha)
    rgb, alpha = dr.custom(
        _Rasterize, proj.mean2d, proj.conic, proj.color, proj.opacity, proj.radius, bins, width, height, cfg, bg
    )
    return RenderOutput(rgb=t.TensorXf(rgb, (height, width, 3)), alpha=t.TensorXf(alpha, (height, width)))


def render_batch(stacked: Gaussians, n_poses: int, cameras: list, cfg: RenderConfig):
    """Forward-only renders of `n_poses` sets of M Gaussians, each seen from every camera, in one
    program: TensorXf [n_poses * V, H, W, 3] (pose-major: image b is pose b // V, view b % V),
    equal to `render(pose, camera, cfg).rgb` of each pair to float rounding.

    stacked: the poses' Gaussians one after the other (n_poses * M entries); cameras: V views of
    one image size. The B = n_poses * V images are laid out as the cells of one atlas image, each
    cell a whole number of tiles: every Gaussian instance is projected by its own view and
    shifted into its cell, binned only into its cell's tiles (`tile_rects`), and the atlas is
    composited by the same phase 3 as one image; then each image is cut out. One projection, one
    sort and one compositing loop instead of B of each: what a population of candidates costs in
    the global search (sgdr.identify.global_search). No gradients (phase 3's adjoint would need
    the cells too); memory grows with B x M, so callers split large batches.
    """
    t = ad()
    n_poses, n_views = int(n_poses), len(cameras)
    if n_poses < 1 or n_views < 1:
        raise RenderError(f"render_batch: need at least one pose and one camera, got {n_poses} and {n_views}")
    width, height = cameras[0].width, cameras[0].height
    for cam in cameras[1:]:
        if (cam.width, cam.height) != (width, height):
            raise RenderError(
                f"render_batch: every camera must have one image size; {cam.width}x{cam.height} differs from "
                f"{width}x{height}"
            )
    total = _check_sizes(stacked)
    if total % n_poses:
        raise RenderError(f"render_batch: {total} Gaussians do not split into {n_poses} poses")
    m = total // n_poses
    ts = int(cfg.tile_size)
    tiles_x, tiles_y = -(-width // ts), -(-height // ts)
    cell_w, cell_h = tiles_x * ts, tiles_y * ts
    n_images = n_poses * n_views
    cols = int(np.ceil(np.sqrt(n_images)))
    rows = -(-n_images // cols)
    atlas_w, atlas_h = cols * cell_w, rows * cell_h
    bg = [float(x) for x in cfg.background]
    with dr.suspend_grad():
        # instance i: image b = i // M (pose b // V, view b % V), Gaussian i % M of that pose
        i = dr.arange(t.UInt32, n_images * m)
        b = i // dr.opaque(t.UInt32, m)
        pose, view = b // dr.opaque(t.UInt32, n_views), b % dr.opaque(t.UInt32, n_views)
        src = pose * dr.opaque(t.UInt32, m) + i % dr.opaque(t.UInt32, m)
        g = Gaussians(*(dr.gather(type(getattr(stacked, f)), dr.detach(getattr(stacked, f)), src) for f in _FIELDS))
        table = np.stack([camera_constants(c, cfg) for c in cameras]).astype(np.float32)  # [V, 18]
        constants = [dr.gather(t.Float, t.Float(np.ascontiguousarray(table[:, k])), view) for k in range(18)]
        proj = project_with(g, constants, cfg)
        col, row = t.Float(b % dr.opaque(t.UInt32, cols)), t.Float(b // dr.opaque(t.UInt32, cols))
        proj.mean2d = t.Array2f(proj.mean2d.x + col * cell_w, proj.mean2d.y + row * cell_h)
        checks = (_nonfinite_counts(stacked), _raise_nonfinite) if cfg.check_finite else None
        bins = bin_gaussians(
            proj, atlas_w, atlas_h, cfg, checks, cells=(col * tiles_x, row * tiles_y, tiles_x, tiles_y)
        )
        if bins.n_entries == 0:
            img = np.broadcast_to(np.array(bg, np.float32), (n_images, height, width, 3))
            return t.TensorXf(np.ascontiguousarray(img))
        rgb, _ = dr.custom(
            _Rasterize, proj.mean2d, proj.conic, proj.color, proj.opacity, proj.radius, bins, atlas_w, atlas_h, cfg, bg
        )
        # cut the images out of the atlas: pixel (b, y, x, channel)
        k = dr.arange(t.UInt32, n_images * height * width * 3)
        ch, k = k % 3, k // 3
        x, k = k % dr.opaque(t.UInt32, width), k // dr.opaque(t.UInt32, width)
        y, b = k % dr.opaque(t.UInt32, height), k // dr.opaque(t.UInt32, height)
        ax = (b % dr.opaque(t.UInt32, cols)) * cell_w + x
        ay = (b // dr.opaque(t.UInt32, cols)) * cell_h + y
        out = dr.gather(t.Float, rgb, (ay * dr.opaque(t.UInt32, atlas_w) + ax) * 3 + ch)
        return t.TensorXf(out, (n_images, height, width, 3))
