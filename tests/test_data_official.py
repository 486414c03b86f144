"""The official datasets' layouts as released: the scene from the official configs, PAC-NeRF's
background plates and missing time stamps, one RGBA convention."""

import json
from pathlib import Path

import numpy as np
import pytest

from sgdr.cameras import Camera
from sgdr.data import SequenceError, load_sequence
from sgdr.data.foreign import write_pac_nerf, write_spring_gaus
from sgdr.data.matte import matte

W, H = 48, 36


def cameras():
    target = np.array([0.0, 0.5, 0.0])
    return [
        Camera.look_at([0.0, 0.9, 1.6], target, [0, 1, 0], 50.0, W, H, "cam_0"),
        Camera.look_at([1.4, 1.0, 0.4], target, [0, 1, 0], 45.0, W, H, "cam_1"),
    ]


def disc(cam, centre, radius=0.15):
    """[H, W, 4] premultiplied: a two-coloured disc (analytic coverage) on black."""
    (u, v), z = (a[0] for a in cam.project(np.asarray(centre)[None]))
    r = cam.K[0, 0] * radius / z
    ys, xs = np.mgrid[0:H, 0:W] + 0.5
    d = np.hypot(xs - u, ys - v)
    a = np.clip(r + 0.5 - d, 0.0, 1.0)
    rgb = np.where((xs < u)[..., None], [0.9, 0.2, 0.1], [0.1, 0.3, 0.9]) * a[..., None]
    return np.concatenate([rgb, a[..., None]], -1)


def frames(cams, n):
    return [[disc(c, [0.0, 0.8 - 0.05 * f, 0.0]) for f in range(n)] for c in cams]


# ---------------------------------------------------------------------------- Spring-Gaus configs
DEFAULT_YAML = """\
STATIC:
  ITERATIONS: 30000
VELOCITY:
  G: [0, -9.8, 0]
DYNAMIC:
  G: [0, -9.8, 0]
  K_NEIGHBORS: 256
"""

OBJECT_YAML = """\
DEFAULT: config/mpm_synthetic/default.yaml
CHECKPOINTS_ROOT: checkpoints/{name}
DATA:
  TYPE: MPM_Synthetic
  DATA_ROOT: data/mpm_synthetic/render
  OBJ_NAME: {name}
  N_CAM: 2
  N_FRAME: 6
  FRAME_ALL: 8
  HIT_FRAME: 5
  H: {h}
  W: {w}
  BC: [[[0, 0.3, 0], [0, 1, 0]]]
  DT: 0.03
"""


def official_repo(tmp_path, name="blob", w=W, h=H) -> Path:
    repo = tmp_path / "Spring-Gaus"
    (repo / "config" / "mpm_synthetic").mkdir(parents=True)
    (repo / "config" / "mpm_synthetic" / "default.yaml").write_text(DEFAULT_YAML)
    cfg = repo / "config" / "mpm_synthetic" / f"{name}.yaml"
    cfg.write_text(OBJECT_YAML.format(name=name, w=w, h=h))
    return cfg


def test_spring_gaus_scene_from_the_official_yaml(tmp_path):
    cfg = official_repo(tmp_path)
    root = write_spring_gaus(tmp_path / "blob", cameras(), frames(cameras(), 8))
    seq = load_sequence(root, scene_file=cfg)
    assert seq.fps == pytest.approx(1 / 0.03)  # DATA.DT is the frame interval: 33.3 fps, not 24
    np.testing.assert_allclose(seq.gravity, [0, -9.8, 0])  # from the DEFAULT file's DYNAMIC.G
    np.testing.assert_allclose(seq.ground_point, [0, 0.3, 0])
    np.testing.assert_allclose(seq.ground_normal, [0, 1, 0])
    assert (seq.hit_frame, seq.n_fit, seq.n_frames) == (5, 6, 8)
    # a reader argument overrides the file
    assert load_sequence(root, scene_file=cfg, hit_frame=2).hit_frame == 2


def test_spring_gaus_config_errors_name_file_and_key(tmp_path):
    root = write_spring_gaus(tmp_path / "blob", cameras(), frames(cameras(), 8))
    wrong_size = official_repo(tmp_path / "a", w=64)
    with pytest.raises(SequenceError, match=r"blob.yaml.*DATA.W.*width 64"):
        load_sequence(root, scene_file=wrong_size)
    cfg = official_repo(tmp_path / "b")
    (cfg.parent / "default.yaml").unlink()  # gravity lives in the base config
    with pytest.raises(SequenceError, match=r"blob.yaml.*'DEFAULT'.*not found"):
        load_sequence(root, scene_file=cfg)
    cfg.write_text(
        OBJECT_YAML.format(name="blob", w=W, h=H).replace("DEFAULT: config/mpm_synthetic/default.yaml\n", "")
    )
    with pytest.raises(SequenceError, match=r"gravity.*scene_file"):
        load_sequence(root, scene_file=cfg)
    cfg.write_text("DATA: [unclosed")
    with pytest.raises(SequenceError, match=r"blob.yaml.*YAML"):
        load_sequence(root, scene_file=cfg)


def test_straight_alpha_is_composited_on_black_everywhere(tmp_path):
    import imageio.v3 as iio

    root = write_spring_gaus(tmp_path / "blob", cameras(), frames(cameras(), 2))
    half = np.zeros((H, W, 4), np.uint8)
    half[..., :3] = 200  # straight colour 200/255 at alpha 0.5: the official loader reads 200/255 x 0.5
    half[..., 3] = 128
    iio.imwrite(root / "cam_0" / "001.png", half)
    (root / "sgdr_scene.json").write_text(
        json.dumps(
            {"fps": 24, "hit_frame": 1, "ground": {"point": [0, 0, 0], "normal": [0, 1, 0]}, "gravity": [0, -9.8, 0]}
        )
    )
    im = load_sequence(root).image(0, 1)
    np.testing.assert_allclose(im[..., :3], 200 / 255 * 128 / 255, atol=1e-6)
    np.testing.assert_allclose(im[..., 3], 128 / 255, atol=1e-6)


# ---------------------------------------------------------------------------- PAC-NeRF as released
PAC_DEFAULT = """\
cfg = dict(
    dtype='float32',
    dt=1/9600,
    frame_dt=1/24,
    gravity=[0,-9.8,0],
    xyz_min = [-1, -0.1, -1],
    BC = {"ground": [[0,0,0], [0, 1, 0]]}
)
"""

PAC_OBJECT = """\
from lib.engine import MPMSimulator

_base_ = '../configs/default.py'

cfg = dict(
    n_cameras = 2,
    n_frames = 5,
    material = MPMSimulator.elasticity,
    dt = 1/24/200,
    H = {h},
    W = {w},
    E = 1e5,
    hit_frame = 3,
)

del MPMSimulator
"""


def plate(seed):
    """[H, W, 3] a textured, non-black background."""
    rng = np.random.default_rng(seed)
    ys, xs = np.mgrid[0:H, 0:W]
    base = np.stack([0.35 + 0.2 * np.sin(xs / 5.0), 0.4 + 0.1 * np.cos(ys / 4.0), 0.45 + 0 * xs], -1)
    return np.clip(base + rng.normal(0, 0.01, base.shape), 0, 1)


def pac_nerf_release(tmp_path, n=5):
    cams = cameras()
    ims = frames(cams, n)
    root = write_pac_nerf(tmp_path / "blob", cams, ims, fps=None, backgrounds=[plate(0), plate(1)])
    repo = tmp_path / "PAC-NeRF" / "configs"
    repo.mkdir(parents=True)
    (repo / "default.py").write_text(PAC_DEFAULT)
    (repo / "blob.py").write_text(PAC_OBJECT.format(w=W, h=H))
    return root, repo / "blob.py", ims


def test_pac_nerf_as_released_reads_with_its_config_and_mattes_the_background(tmp_path):
    root, cfg, truth = pac_nerf_release(tmp_path)
    entries = json.loads((root / "all_data.json").read_text())
    assert any(e["file_path"].endswith("_-1.png") for e in entries) and not any("time" in e for e in entries)
    with pytest.raises(SequenceError, match=r"fps.*scene_file"):  # no time stamps, no config: refused
        load_sequence(root)
    seq = load_sequence(root, scene_file=cfg)
    assert seq.fps == pytest.approx(24.0)  # the base config's frame_dt (the object's dt is the substep)
    np.testing.assert_allclose(seq.gravity, [0, -9.8, 0])
    np.testing.assert_allclose(seq.ground_normal, [0, 1, 0])
    assert (seq.n_views, seq.n_frames, seq.n_fit, seq.hit_frame) == (2, 5, 5, 3)
    for v in range(2):
        for f in (0, 4):
            im, ref = seq.image(v, f), truth[v][f]
            inside, found = ref[..., 3] > 0.5, im[..., 3] > 0.5
            iou = (inside & found).sum() / (inside | found).sum()
            assert iou > 0.9, (v, f, iou)
            # the matted RGB is on black: the background plate is gone outside the object
            assert np.abs(im[..., :3][im[..., 3] == 0]).max() == 0.0
            assert (im[..., 3] == 0).sum() > 0.8 * im[..., 3].size
            assert np.abs(im[..., 3] - ref[..., 3]).mean() < 0.03
            solid = (ref[..., 3] == 1) & (im[..., 3] == 1)
            assert solid.sum() > 0.5 * inside.sum()
            np.testing.assert_allclose(im[..., :3][solid], ref[..., :3][solid], atol=0.05)


def test_pac_nerf_release_errors(tmp_path):
    root, cfg, _ = pac_nerf_release(tmp_path)
    (root / "data" / "r_1_-1.png").unlink()
    entries = [e for e in json.loads((root / "all_data.json").read_text()) if not e["file_path"].endswith("r_1_-1.png")]
    (root / "all_data.json").write_text(json.dumps(entries))
    with pytest.raises(SequenceError, match=r"r_1_0.png.*no alpha.*r_1_-1.png"):
        load_sequence(root, scene_file=cfg)
    root, cfg, _ = pac_nerf_release(tmp_path / "again")
    (cfg.parent / "blob.py").write_text(PAC_OBJECT.format(w=W + 1, h=H))
    with pytest.raises(SequenceError, match=r"blob.py.*W"):
        load_sequence(root, scene_file=cfg)


def test_matte_against_a_plate_ignores_noise_and_keeps_the_object():
    rng = np.random.default_rng(3)
    bg = plate(2)
    obj = disc(cameras()[0], [0.0, 0.6, 0.0], 0.2)
    image = obj[..., :3] + bg * (1 - obj[..., 3:4])
    noisy = np.clip(image + rng.normal(0, 0.01, image.shape), 0, 1)
    alpha = matte(noisy, np.clip(bg + rng.normal(0, 0.01, bg.shape), 0, 1))
    truth = obj[..., 3] > 0.5
    assert ((alpha > 0.5) == truth).mean() > 0.98
    assert alpha[obj[..., 3] == 0].max() < 0.5 and alpha[obj[..., 3] == 1].min() > 0.5
    with pytest.raises(ValueError, match="differ in shape"):
        matte(noisy, bg[:-1])


def test_spring_gaus_principal_point_is_the_image_centre_as_the_official_loader_reads_it(tmp_path):
    cfg = official_repo(tmp_path)
    root = write_spring_gaus(tmp_path / "blob", cameras(), frames(cameras(), 8))
    entries = json.loads((root / "camera.json").read_text())
    entries[1]["K"][0][2] += 3.0  # the official loader keeps only FovX = 2 atan(W / 2 fx): cx is ignored
    (root / "camera.json").write_text(json.dumps(entries))
    seq = load_sequence(root, scene_file=cfg)
    np.testing.assert_allclose(seq.cameras[1].K[:2, 2], [W / 2, H / 2])
    np.testing.assert_allclose(seq.cameras[1].K[0, 0], entries[1]["K"][0][0])
