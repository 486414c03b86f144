"""Static fit on the tiny preset recovers a known scene; PLY round trip; bad inputs."""

import numpy as np
import pytest

from sgdr.cameras import Camera
from sgdr.config import compose
from sgdr.evaluate import psnr
from sgdr.gaussians.model import Gaussians
from sgdr.gaussians.ply import PROPERTIES, SH_C0, load_ply, save_ply
from sgdr.render.config import RenderConfig
from sgdr.render.splat import render
from sgdr.static_fit.config import StaticFitConfig
from sgdr.static_fit.fit import StaticFitError, box_from_masks, fit_static


def _known_scene(s0, n=300, seed=0):
    """A blob of Gaussians of scale s0 with a smooth colour field, inside [0.37, 0.63]^3."""
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    pts = 0.5 + 0.13 * d * rng.uniform(0, 1, (n, 1)) ** (1 / 3)
    cols = np.clip(0.2 + 0.6 * (pts - 0.37) / 0.26, 0.05, 0.95)
    return Gaussians.isotropic(pts, s0, cols, 0.9)


def _ring_cameras(n, res):
    cams = []
    for i in range(n):
        az, el = 2 * np.pi * i / n, (0.3 if i % 2 else -0.2)
        eye = 0.5 + 1.3 * np.array([np.cos(az) * np.cos(el), np.sin(az) * np.cos(el), np.sin(el)])
        cams.append(Camera.look_at(eye, [0.5, 0.5, 0.5], [0, 0, 1], 40, res, res, name=f"v{i}"))
    return cams


def _rgba(g, cam, rcfg):
    out = render(g, cam, rcfg)
    return np.concatenate([np.asarray(out.rgb), np.asarray(out.alpha)[..., None]], -1)


def test_static_fit_tiny_recovers_known_scene_held_out_psnr():
    cfg = compose(["preset=tiny"])
    fit_cfg = StaticFitConfig(**cfg.static_fit)
    rcfg = RenderConfig(**cfg.render)
    res = int(cfg.synth.resolution)
    truth = _known_scene(fit_cfg.s0)
    cams = _ring_cameras(10, res)
    images = [_rgba(truth, c, rcfg) for c in cams]
    train, held_out = [0, 1, 2, 3, 5, 6, 7, 8], [4, 9]
    g = fit_static(
        [images[i] for i in train], [cams[i] for i in train], fit_cfg, rcfg, box=None, seed=0, progress=False
    )
    assert 0 < g.count <= fit_cfg.n_init
    scores = [psnr(np.asarray(render(g, cams[i], rcfg).rgb), images[i][..., :3]) for i in held_out]
    assert min(scores) >= 28.0, scores
    np.testing.assert_allclose(g.to_numpy()["log_scales"], np.log(fit_cfg.s0), rtol=1e-6)  # s0 stays constant


def test_box_from_masks_contains_the_object():
    rcfg = RenderConfig()
    truth = _known_scene(0.03)
    cams = _ring_cameras(8, 32)
    images = [_rgba(truth, c, rcfg) for c in cams]
    lo, hi = box_from_masks(images, cams, StaticFitConfig())
    assert np.all(lo < 0.4) and np.all(hi > 0.6)  # the blob spans ~[0.37, 0.63]
    assert np.all(lo > 0.2) and np.all(hi < 0.8)  # and the box is not the whole carving cube


def test_ply_round_trip_in_3dgs_layout(tmp_path, rng):
    m = 7
    g = Gaussians.from_numpy(
        rng.uniform(0, 1, (m, 3)),
        rng.normal(-3, 0.3, (m, 3)),
        rng.normal(size=(m, 4)),
        rng.normal(size=(m, 3)),
        rng.normal(size=m),
    )
    path = save_ply(tmp_path / "g.ply", g)
    raw = path.read_bytes()
    header = raw[: raw.index(b"end_header")].decode().splitlines()
    assert header[:3] == ["ply", "format binary_little_endian 1.0", f"element vertex {m}"]
    assert [h.split()[-1] for h in header[3:]] == PROPERTIES
    body = np.frombuffer(raw[raw.index(b"end_header") + len(b"end_header\n") :], dtype="<f4").reshape(
        m, len(PROPERTIES)
    )
    d = g.to_numpy()
    rgb = 1 / (1 + np.exp(-d["color_logits"]))
    np.testing.assert_allclose(body[:, 6:9], (rgb - 0.5) / SH_C0, rtol=1e-5, atol=1e-6)  # f_dc
    np.testing.assert_allclose(body[:, 9], d["opacity_logits"], rtol=1e-6)  # opacity logit
    np.testing.assert_allclose(body[:, 10:13], d["log_scales"], rtol=1e-6)  # log scales
    back = load_ply(path).to_numpy()
    for k in d:
        np.testing.assert_allclose(back[k], d[k], rtol=1e-4, atol=1e-4, err_msg=k)


def test_static_fit_bad_inputs():
    cams = _ring_cameras(2, 16)
    good = np.zeros((16, 16, 4), np.float32)
    with pytest.raises(StaticFitError, match=r"image 1 .*shape \(16, 15, 4\)"):
        fit_static([good, np.zeros((16, 15, 4), np.float32)], cams, StaticFitConfig(), RenderConfig(), progress=False)
    with pytest.raises(StaticFitError, match="one image per camera"):
        fit_static([good], cams, StaticFitConfig(), RenderConfig(), progress=False)
    with pytest.raises(StaticFitError, match="no voxel"):  # empty masks: nothing to carve
        fit_static([good, good], cams, StaticFitConfig(), RenderConfig(), progress=False)
