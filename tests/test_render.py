"""Splat renderer: forward and adjoint against the dense NumPy reference, finite differences,
gradients into upstream AD graphs, and bad inputs."""

import drjit as dr
import numpy as np
import pytest

from sgdr.backend import ad
from sgdr.cameras import Camera
from sgdr.gaussians.model import Gaussians
from sgdr.render.config import RenderConfig
from sgdr.render.reference import FIELDS, reference_vjp, render_numpy
from sgdr.render.splat import RenderError, render


def _scene(rng, m, lo=0.35, hi=0.65, s=(0.03, 0.08), opacity=(1.0, 1.0), iso=False):
    scales = rng.uniform(*s, (m, 1 if iso else 3)).repeat(1 if not iso else 3, axis=1)
    return dict(
        means=rng.uniform(lo, hi, (m, 3)),
        log_scales=np.log(scales),
        rotations=np.tile([1.0, 0, 0, 0], (m, 1)) if iso else rng.normal(size=(m, 4)),
        color_logits=rng.normal(size=(m, 3)),
        opacity_logits=rng.normal(*opacity, m),
    )


def _camera(w=40, h=36, eye=(0.5, -1.5, 0.6)):
    return Camera.look_at(eye, [0.5, 0.5, 0.5], [0, 0, 1], 40, w, h)


def _np(x):
    return np.asarray(x, dtype=np.float64)


def _grad(g, name):
    v = _np(dr.grad(getattr(g, name)))
    return v.T if v.ndim == 2 else v


@pytest.mark.parametrize(
    "m, iso, size, opacity, bg",
    [
        (6, False, (40, 36), (1.0, 1.0), (0.1, 0.2, 0.3)),  # anisotropic, partial tiles
        (40, True, (48, 32), (3.0, 0.5), (0.0, 0.0, 0.0)),  # dense, opaque: α clamp + early stop
        (200, True, (33, 17), (0.0, 2.0), (1.0, 1.0, 1.0)),  # many per tile, odd size
    ],
)
def test_forward_matches_numpy_reference(rng, m, iso, size, opacity, bg):
    p = _scene(rng, m, opacity=opacity, iso=iso)
    cam = _camera(*size)
    cfg = RenderConfig(background=list(bg))
    out = render(Gaussians.from_numpy(**p), cam, cfg)
    rgb, alpha = render_numpy(p, cam, cfg)
    assert out.rgb.shape == (size[1], size[0], 3) and out.alpha.shape == (size[1], size[0])
    assert alpha.max() > 0.3  # the scene is visible
    np.testing.assert_allclose(_np(out.rgb), rgb, atol=1e-4)
    np.testing.assert_allclose(_np(out.alpha), alpha, atol=1e-4)


@pytest.mark.parametrize("pixels_per_thread", [1, 2, 8, 16])
def test_pixel_strip_widths_agree(rng, pixels_per_thread):
    """Every strip width (pixels shaded per SIMD lane) gives the reference's image and the same
    gradients as the default width."""
    p = _scene(rng, 30, opacity=(2.0, 1.0), iso=True)
    cam = _camera(40, 36)
    cfg = RenderConfig(background=[0.2, 0.3, 0.1], pixels_per_thread=pixels_per_thread)
    rgb, alpha = render_numpy(p, cam, cfg)
    grads = []
    for c in (cfg, RenderConfig(background=[0.2, 0.3, 0.1])):
        g = Gaussians.from_numpy(**p)
        dr.enable_grad(g.means, g.opacity_logits)
        out = render(g, cam, c)
        np.testing.assert_allclose(_np(out.rgb), rgb, atol=1e-4)
        np.testing.assert_allclose(_np(out.alpha), alpha, atol=1e-4)
        dr.backward(dr.sum(out.rgb * out.rgb, axis=None) + dr.sum(out.alpha, axis=None))
        grads.append((_grad(g, "means"), _grad(g, "opacity_logits")))
    for a, b in zip(*grads):
        np.testing.assert_allclose(a, b, atol=1e-4 * np.abs(b).max())


def test_early_termination_and_clamp_are_exercised(rng):
    """The dense scene really saturates pixels (otherwise the reference test proves less)."""
    p = _scene(rng, 40, opacity=(3.0, 0.5), iso=True)
    _, alpha = render_numpy(p, _camera(48, 32), RenderConfig())
    assert alpha.max() > 1 - 1e-3


def test_no_per_tile_cap(rng):
    """3000 Gaussians on one 16x16 tile: every one is composited (the reference has no cap)."""
    p = _scene(rng, 3000, lo=0.49, hi=0.51, s=(0.002, 0.004), opacity=(-3.0, 0.5), iso=True)
    cam = _camera(16, 16, eye=(0.5, 0.2, 0.5))
    cfg = RenderConfig()
    out = render(Gaussians.from_numpy(**p), cam, cfg)
    rgb, alpha = render_numpy(p, cam, cfg)
    np.testing.assert_allclose(_np(out.rgb), rgb, atol=1e-4)
    np.testing.assert_allclose(_np(out.alpha), alpha, atol=1e-4)


@pytest.mark.parametrize("opacity, bg", [((1.0, 1.0), (0.1, 0.2, 0.3)), ((3.0, 0.5), (0.0, 0.0, 0.0))])
def test_random_cotangent_matches_reference_vjp(rng, opacity, bg):
    """Backward of <w, render> for random cotangents w equals the reference's finite-difference VJP,
    for every field (centres, scales, rotations, colours, opacities)."""
    p = _scene(rng, 5, opacity=opacity)
    cam = _camera(32, 32)
    cfg = RenderConfig(background=list(bg))
    w_rgb = rng.normal(size=(32, 32, 3))
    w_alpha = rng.normal(size=(32, 32))
    g = Gaussians.from_numpy(**p)
    dr.enable_grad(g.means, g.log_scales, g.rotations, g.color_logits, g.opacity_logits)
    t = ad()
    out = render(g, cam, cfg)
    L = dr.sum(out.rgb * t.TensorXf(w_rgb.astype(np.float32)), axis=None) + dr.sum(
        out.alpha * t.TensorXf(w_alpha.astype(np.float32)), axis=None
    )
    dr.backward(L)
    ref = reference_vjp(p, cam, cfg, w_rgb, w_alpha)
    for name in FIELDS:
        scale = np.abs(ref[name]).max()
        assert scale > 1e-3, name
        np.testing.assert_allclose(_grad(g, name), ref[name], atol=2e-3 * scale, err_msg=name)


def _scalar_direction_fd(p, cam, cfg, name, direction, eps):
    """Central difference of the Dr.Jit renderer's loss sum(rgb²)+sum(alpha) along `direction`."""

    def loss(delta):
        q = dict(p)
        q[name] = p[name] + delta * direction
        out = render(Gaussians.from_numpy(**q), cam, cfg)
        return float((_np(out.rgb) ** 2).sum() + _np(out.alpha).sum())  # float64 sums

    return (loss(eps) - loss(-eps)) / (2 * eps)


@pytest.mark.parametrize(
    "name, eps", [("means", 1e-3), ("log_scales", 1e-3), ("color_logits", 1e-2), ("opacity_logits", 1e-2)]
)
def test_central_differences_of_dr_renderer(rng, name, eps):
    """Directional derivative along a random direction: AD vs central differences of the
    Dr.Jit renderer itself (binning recomputed at every evaluation). alpha_min is lowered so the
    jumps of the 1/255 cutoff contour do not swamp a float32 difference quotient."""
    p = _scene(rng, 8, iso=True, s=(0.05, 0.08))
    cam = _camera(32, 32)
    cfg = RenderConfig(background=[0.2, 0.2, 0.2], alpha_min=1e-6)
    direction = rng.normal(size=p[name].shape)
    if name == "log_scales":
        direction = np.repeat(direction[:, :1], 3, axis=1)  # stay isotropic
    g = Gaussians.from_numpy(**p)
    dr.enable_grad(getattr(g, name))
    out = render(g, cam, cfg)
    dr.backward(dr.sum(out.rgb * out.rgb, axis=None) + dr.sum(out.alpha, axis=None))
    ad_dir = float((_grad(g, name) * direction).sum())
    fd = _scalar_direction_fd(p, cam, cfg, name, direction, eps)
    assert abs(ad_dir) > 1e-2
    assert abs(ad_dir - fd) <= 0.02 * abs(fd) + 1e-3, (ad_dir, fd)


def test_gradients_flow_to_upstream_parameters(rng):
    """means = f(anchors, θ) computed by recorded AD upstream (an IDW-like skinning of rotated
    anchors); d loss / d anchors and d loss / dθ through the custom op match central
    differences of the NumPy reference."""
    t = ad()
    n_a, m = 4, 10
    anchors_np = rng.uniform(0.35, 0.65, (n_a, 3))
    W = rng.uniform(0.1, 1.0, (m, n_a))
    W /= W.sum(1, keepdims=True)
    theta0 = 0.3
    p = _scene(rng, m, iso=True, s=(0.05, 0.08))
    cam = _camera(32, 32)
    cfg = RenderConfig(background=[0.3, 0.1, 0.2])
    w_rgb = rng.normal(size=(32, 32, 3))

    def means_np(anchors, theta):
        c, s = np.cos(theta), np.sin(theta)
        Rz = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
        return W @ ((anchors - 0.5) @ Rz.T + 0.5)

    def loss_np(anchors, theta):
        rgb, _ = render_numpy({**p, "means": means_np(anchors, theta)}, cam, cfg)
        return float((w_rgb * rgb).sum())

    # Dr.Jit: anchors and θ are the only AD leaves; means are an upstream AD expression
    A = t.Array3f(*(t.Float(anchors_np[:, k].astype(np.float32)) for k in range(3)))
    theta = t.Float(theta0)
    dr.enable_grad(A, theta)
    c, s = dr.cos(theta), dr.sin(theta)
    rot = t.Array3f(c * (A.x - 0.5) - s * (A.y - 0.5) + 0.5, s * (A.x - 0.5) + c * (A.y - 0.5) + 0.5, A.z)
    means = dr.zeros(t.Array3f, m)
    for j in range(n_a):  # means_i = Σ_j W_ij rot(a_j): gathers + weights, all recorded AD
        a_j = dr.gather(t.Array3f, rot, t.UInt32(j) + dr.zeros(t.UInt32, m))
        means += t.Float(W[:, j].astype(np.float32)) * a_j
    g = Gaussians.from_numpy(**p)
    g.means = means
    out = render(g, cam, cfg)
    dr.backward(dr.sum(out.rgb * t.TensorXf(w_rgb.astype(np.float32)), axis=None))
    g_theta = float(dr.grad(theta)[0])
    g_anchors = _np(dr.grad(A)).T

    eps = 1e-5
    fd_theta = (loss_np(anchors_np, theta0 + eps) - loss_np(anchors_np, theta0 - eps)) / (2 * eps)
    fd_anchors = np.zeros_like(anchors_np)
    for idx in np.ndindex(anchors_np.shape):
        hi, lo = anchors_np.copy(), anchors_np.copy()
        hi[idx] += eps
        lo[idx] -= eps
        fd_anchors[idx] = (loss_np(hi, theta0) - loss_np(lo, theta0)) / (2 * eps)
    assert abs(fd_theta) > 1e-2 and np.abs(fd_anchors).max() > 1e-2
    assert abs(g_theta - fd_theta) <= 2e-3 * abs(fd_theta) + 1e-4, (g_theta, fd_theta)
    np.testing.assert_allclose(g_anchors, fd_anchors, atol=2e-3 * np.abs(fd_anchors).max())


# ---------------------------------------------------------------------------- bad input
def test_empty_gaussian_set_gives_background():
    cfg = RenderConfig(background=[0.25, 0.5, 0.75])
    g = Gaussians.from_numpy(np.zeros((0, 3)))
    out = render(g, _camera(20, 12), cfg)
    assert out.rgb.shape == (12, 20, 3)
    np.testing.assert_array_equal(_np(out.rgb), np.broadcast_to([0.25, 0.5, 0.75], (12, 20, 3)).astype(np.float32))
    np.testing.assert_array_equal(_np(out.alpha), 0.0)


def test_camera_behind_everything_gives_background(rng):
    p = _scene(rng, 20)
    cam = Camera.look_at([0.5, -1.5, 0.6], [0.5, -3.0, 0.6], [0, 0, 1], 40, 24, 24)  # looks away
    g = Gaussians.from_numpy(**p)
    dr.enable_grad(g.means)
    out = render(g, cam, RenderConfig(background=[0.5, 0.5, 0.5]))
    np.testing.assert_array_equal(_np(out.rgb), 0.5)
    np.testing.assert_array_equal(_np(out.alpha), 0.0)
    dr.backward(dr.sum(out.rgb, axis=None))  # well defined, zero gradient
    np.testing.assert_array_equal(_np(dr.grad(g.means)), 0.0)


@pytest.mark.parametrize("field", FIELDS)
def test_nan_parameters_raise_naming_the_field(rng, field):
    p = _scene(rng, 5)
    p[field] = np.array(p[field], dtype=np.float64)
    p[field].flat[3] = np.nan
    with pytest.raises(RenderError, match=field):
        render(Gaussians.from_numpy(**p), _camera(), RenderConfig())


def test_mismatched_field_sizes_raise(rng):
    t = ad()
    g = Gaussians.from_numpy(**_scene(rng, 5))
    g.opacity_logits = t.Float([0.0, 0.0])
    with pytest.raises(RenderError, match="opacity_logits"):
        render(g, _camera(), RenderConfig())


def test_argsort_tile_sort_path_agrees(rng, monkeypatch):
    """Above the counting-sort bucket limit the tile lists are sorted by dr.argsort: same image."""
    import sgdr.render.splat as splat

    p = _scene(rng, 40, opacity=(2.0, 1.0), iso=True)
    cam, cfg = _camera(48, 32), RenderConfig()
    rgb, alpha = render_numpy(p, cam, cfg)
    monkeypatch.setattr(splat, "_MAX_COUNTING_SORT_BUCKETS", 0)
    out = render(Gaussians.from_numpy(**p), cam, cfg)
    np.testing.assert_allclose(_np(out.rgb), rgb, atol=1e-4)
    np.testing.assert_allclose(_np(out.alpha), alpha, atol=1e-4)


def test_render_batch_equals_each_render_and_keeps_footprints_in_their_image(rng):
    """Poses x views in one atlas equal the single renders (float rounding), with an image size
    that is not a multiple of the tile and Gaussians large enough to spill past the image's
    edges (a footprint reaching into a neighbouring cell would show there)."""
    from sgdr.render.splat import render_batch

    cfg = RenderConfig()
    cams = [_camera(eye=e) for e in [(0.5, -1.5, 0.6), (1.6, 0.5, 0.9), (-0.4, 1.4, 0.3)]]
    poses = [_scene(rng, 60, lo=0.2, hi=0.8, s=(0.05, 0.15)) for _ in range(2)]
    stacked = Gaussians.from_numpy(**{k: np.concatenate([p[k] for p in poses]) for k in poses[0]})
    out = _np(render_batch(stacked, 2, cams, cfg)).reshape(6, 36, 40, 3)
    for b in range(6):
        single = _np(render(Gaussians.from_numpy(**poses[b // 3]), cams[b % 3], cfg).rgb).reshape(36, 40, 3)
        np.testing.assert_allclose(out[b], single, atol=2e-5)
    with pytest.raises(RenderError, match="one image size"):
        render_batch(stacked, 2, [cams[0], _camera(w=32)], cfg)
    with pytest.raises(RenderError, match="do not split into 7 poses"):
        render_batch(stacked, 7, cams, cfg)
