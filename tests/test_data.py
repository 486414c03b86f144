"""Sequence formats: sgdr's own layout round trip, Spring-Gaus and PAC-NeRF readers, errors."""

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from sgdr.data import SequenceError, load_sequence

DATA = Path(__file__).parent / "data"
LAYOUTS = {"sgdr": "sgdr_seq", "spring_gaus": "spring_gaus", "pac_nerf": "pac_nerf"}


def fixture_copy(tmp_path, layout):
    dst = tmp_path / LAYOUTS[layout]
    shutil.copytree(DATA / LAYOUTS[layout], dst)
    return dst


@pytest.mark.parametrize("layout", sorted(LAYOUTS))
def test_every_layout_reads_the_same_cameras_images_and_scene(layout):
    ref = load_sequence(DATA / "sgdr_seq")
    seq = load_sequence(DATA / LAYOUTS[layout])
    assert seq.layout == layout
    assert (seq.n_frames, seq.n_fit, seq.hit_frame, seq.n_views) == (3, 2, 2, 2)
    assert seq.fps == pytest.approx(24.0, rel=1e-9)
    np.testing.assert_allclose(seq.ground_point, [0.5, 0.5, 0.1])
    np.testing.assert_allclose(seq.ground_normal, [0, 0, 1])
    np.testing.assert_allclose(seq.gravity, [0, 0, -9.8])
    for cam, cam_ref in zip(seq.cameras, ref.cameras):
        np.testing.assert_allclose(cam.K, cam_ref.K, atol=1e-9)
        np.testing.assert_allclose(cam.w2c, cam_ref.w2c, atol=1e-9)
        assert (cam.width, cam.height) == (16, 12)
        # A world point projects to the same pixel through every reader.
        X = np.array([[0.55, 0.47, 0.42]])
        np.testing.assert_allclose(cam.project(X)[0], cam_ref.project(X)[0], atol=1e-6)
    for v in range(2):
        for f in range(3):
            im = seq.image(v, f)
            assert im.shape == (12, 16, 4) and im.dtype == np.float32
            # one convention everywhere: RGB on black (premultiplied) + alpha; the foreign PNGs hold
            # straight alpha, so 8-bit rounding of rgb / alpha moves a channel by at most one level
            np.testing.assert_allclose(im, ref.image(v, f), atol=1.01 / 255)


def assert_json_close(a, b, path="$", rtol=1e-9, atol=1e-12):
    """Same structure, keys and strings exactly; numbers within a tolerance (the fixtures are
    computed with float64 trigonometry whose last digit differs between CPUs and libms)."""
    if isinstance(a, dict):
        assert isinstance(b, dict) and sorted(a) == sorted(b), f"{path}: keys {sorted(a)} != {sorted(b)}"
        for k in a:
            assert_json_close(a[k], b[k], f"{path}.{k}", rtol, atol)
    elif isinstance(a, list):
        assert isinstance(b, list) and len(a) == len(b), f"{path}: list lengths differ"
        for i, (x, y) in enumerate(zip(a, b)):
            assert_json_close(x, y, f"{path}[{i}]", rtol, atol)
    elif isinstance(a, bool) or not isinstance(a, (int, float)):
        assert a == b, f"{path}: {a!r} != {b!r}"
    else:
        assert isinstance(b, (int, float)) and not isinstance(b, bool), f"{path}: {b!r} is not a number"
        assert abs(a - b) <= atol + rtol * abs(b), f"{path}: {a!r} != {b!r}"


def test_json_comparison_tolerates_the_last_digit_only():
    assert_json_close({"K": [[-0.8703882797784892, 1]], "name": "a"}, {"K": [[-0.8703882797784891, 1]], "name": "a"})
    for other in (
        {"K": [[-0.8704, 1]], "name": "a"},
        {"K": [[-0.8703882797784892, 1]], "name": "b"},
        {"K": [[-0.8703882797784892]], "name": "a"},
        {"K": [[-0.8703882797784892, 1]]},
    ):
        with pytest.raises(AssertionError):
            assert_json_close({"K": [[-0.8703882797784892, 1]], "name": "a"}, other)


def test_fixtures_are_reproduced_by_the_documented_command(tmp_path):
    from tests.data.make_fixtures import make

    paths = make(tmp_path)
    for name in ("sgdr_seq/sequence.json", "spring_gaus/camera.json", "pac_nerf/all_data.json"):
        assert_json_close(json.loads((tmp_path / name).read_text()), json.loads((DATA / name).read_text()), name)
    # 8-bit images: a float difference in the last digit may move one channel by one level.
    fresh = load_sequence(paths["pac_nerf"])
    np.testing.assert_allclose(fresh.image(1, 2), load_sequence(DATA / "pac_nerf").image(1, 2), atol=1.01 / 255)


def test_sgdr_round_trip_keeps_ground_truth_and_cameras_project_the_ball():
    from tests.data.make_fixtures import ball_track

    seq = load_sequence(DATA / "sgdr_seq")
    track = ball_track()
    for f in range(3):
        np.testing.assert_allclose(seq.gt_particles(f).mean(0), track[f], atol=1e-6)
        # The disc drawn at the ball's projection is where the camera projects the ball.
        for v, cam in enumerate(seq.cameras):
            a = seq.image(v, f)[..., 3]
            ys, xs = np.mgrid[0:12, 0:16] + 0.5
            centroid = np.array([(xs * a).sum(), (ys * a).sum()]) / a.sum()
            uv, _ = cam.project(track[f][None])
            assert np.linalg.norm(centroid - uv[0]) < 0.5
    assert seq.gt_params() == {"object": "ball", "radius": 0.08}
    assert seq.gt_effects() == {}


def test_foreign_layout_without_scene_is_refused_naming_what_is_missing(tmp_path):
    root = fixture_copy(tmp_path, "spring_gaus")
    (root / "sgdr_scene.json").unlink()
    raises_naming(
        ["fps", "hit_frame", "ground", "gravity", "scene_file", "sgdr_scene.json"], lambda: load_sequence(root)
    )
    # reader arguments give it; n_fit defaults to every frame
    seq = load_sequence(
        root, fps=30.0, hit_frame=1, gravity=[0, 0, -3.0], ground={"point": [0, 0, 0], "normal": [0, 0, 1]}
    )
    assert seq.hit_frame == 1 and seq.n_fit == 3 and seq.fps == 30.0
    np.testing.assert_allclose(seq.gravity, [0, 0, -3.0])
    # PAC-NeRF's time stamps give the frame rate, nothing else
    pac = fixture_copy(tmp_path, "pac_nerf")
    (pac / "sgdr_scene.json").unlink()
    raises_naming(["hit_frame", "ground", "gravity"], lambda: load_sequence(pac))


def test_sgdr_layout_refuses_scene_values(tmp_path):
    root = fixture_copy(tmp_path, "sgdr")
    raises_naming(["sequence.json"], lambda: load_sequence(root, hit_frame=1))


# ---------------------------------------------------------------------------- error messages
def edit_json(path, fn):
    data = json.loads(path.read_text())
    fn(data)
    path.write_text(json.dumps(data))


def raises_naming(fragments, fn):
    with pytest.raises(SequenceError) as e:
        fn()
    for frag in fragments:
        assert frag in str(e.value), f"{frag!r} not in {e.value}"


def test_sgdr_errors_name_file_and_field(tmp_path):
    root = fixture_copy(tmp_path, "sgdr")
    meta = root / "sequence.json"
    original = meta.read_text()

    edit_json(meta, lambda d: d.pop("fps"))
    raises_naming(["sequence.json", "'fps'", "missing"], lambda: load_sequence(root))

    meta.write_text(original)
    edit_json(meta, lambda d: d["views"][1].__setitem__("K", [[1, 0], [0, 1]]))
    raises_naming(["sequence.json", "views[1].K", "[3, 3]"], lambda: load_sequence(root))

    meta.write_text(original)
    edit_json(meta, lambda d: d["ground"].pop("normal"))
    raises_naming(["sequence.json", "'normal'"], lambda: load_sequence(root))

    meta.write_text(original)
    edit_json(meta, lambda d: d.__setitem__("n_fit", 7))
    raises_naming(["sequence.json", "'n_fit'"], lambda: load_sequence(root))

    meta.write_text(original)
    edit_json(meta, lambda d: d["views"][0].__setitem__("width", 20))
    raises_naming(["000.png", "16x12", "20x12"], lambda: load_sequence(root))

    meta.write_text(original)
    edit_json(meta, lambda d: d.update(n_frames=2, hit_frame=1))
    raises_naming(["002.png", "n_frames"], lambda: load_sequence(root))

    meta.write_text(original)
    (root / "images" / "cam_b" / "001.png").unlink()
    raises_naming(["cam_b/001.png", "missing"], lambda: load_sequence(root))


def test_sgdr_ground_truth_errors_name_the_file(tmp_path):
    root = fixture_copy(tmp_path, "sgdr")
    (root / "gt" / "particles_001.npy").unlink()
    raises_naming(["particles_001.npy", "'particles'"], lambda: load_sequence(root))


def test_spring_gaus_errors_name_file_and_field(tmp_path):
    root = fixture_copy(tmp_path, "spring_gaus")
    cams = root / "camera.json"
    original = cams.read_text()

    edit_json(cams, lambda d: d[1].pop("c2w"))
    raises_naming(["camera.json", "'c2w'", "missing"], lambda: load_sequence(root))

    cams.write_text(original)
    edit_json(cams, lambda d: d[0].__setitem__("c2w", np.eye(3).tolist()))
    raises_naming(["camera.json", "[0].c2w", "[4, 4]"], lambda: load_sequence(root))

    cams.write_text(original)
    (root / "cam_b" / "002.png").unlink()
    raises_naming(["'frames'", "cam_a: 3", "cam_b: 2"], lambda: load_sequence(root))

    shutil.copy(root / "cam_a" / "002.png", root / "cam_b" / "002.png")
    import imageio.v3 as iio

    # an RGB frame is opaque, as the official loader's convert("RGBA") reads it
    iio.imwrite(root / "cam_a" / "001.png", np.full((12, 16, 3), 128, np.uint8))
    im = load_sequence(root).image(0, 1)
    np.testing.assert_allclose(im[..., 3], 1.0)
    np.testing.assert_allclose(im[..., :3], 128 / 255, atol=1e-6)
    # a frame missing in every camera is a gap, never a shorter sequence
    for cam in ("cam_a", "cam_b"):
        (root / cam / "001.png").unlink()
    raises_naming(["001.png", "missing", "frames must run from 0"], lambda: load_sequence(root))

    shutil.rmtree(root / "cam_a")
    raises_naming(["cam_a", "missing"], lambda: load_sequence(root))


def test_pac_nerf_errors_name_file_and_field(tmp_path):
    root = fixture_copy(tmp_path, "pac_nerf")
    meta = root / "all_data.json"
    original = meta.read_text()

    edit_json(meta, lambda d: d[3].pop("intrinsic"))
    raises_naming(["all_data.json", "'intrinsic'", "missing"], lambda: load_sequence(root))

    meta.write_text(original)
    edit_json(meta, lambda d: d[0].__setitem__("c2w", np.eye(4).tolist()))
    raises_naming(["all_data.json", "[0].c2w", "[3, 4]"], lambda: load_sequence(root))

    meta.write_text(original)
    edit_json(meta, lambda d: d.pop(4))
    raises_naming(["all_data.json", "lacks frames"], lambda: load_sequence(root))

    meta.write_text(original)
    edit_json(meta, lambda d: d[1].__setitem__("time", 5.0))
    raises_naming(["all_data.json", "'time'"], lambda: load_sequence(root))

    meta.write_text(original)
    import imageio.v3 as iio

    iio.imwrite(root / "data" / "r_1_2.png", np.zeros((10, 16, 4), np.uint8))
    raises_naming(["r_1_2.png", "16x10", "16x12"], lambda: load_sequence(root))


def test_unknown_folder_names_the_expected_files(tmp_path):
    raises_naming(["sequence.json", "camera.json", "all_data.json"], lambda: load_sequence(tmp_path))
    raises_naming(["does not exist"], lambda: load_sequence(tmp_path / "nope"))
