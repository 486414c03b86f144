"""Twin sequences (sgdr.synth.twin): an asset's own model, simulated with a known truth and
rendered, written as a sequence that sgdr reads back, with the truth recorded."""

import json

import numpy as np
import pytest

from sgdr.anchors.config import AnchorConfig
from sgdr.asset.store import load_asset, save_asset
from sgdr.cameras import Camera
from sgdr.data import load_sequence
from sgdr.gaussians.model import Gaussians
from sgdr.observe.contact import hit_frame
from sgdr.physics import PhysicsConfig
from sgdr.synth.twin import twin_sequence, twin_values


@pytest.fixture(scope="module")
def asset_dir(tmp_path_factory):
    """A small renderable asset: 300 Gaussians in a 0.2-wide ball 0.08 above the ground z = 0,
    48 anchors, thrown down and sideways, two 32x24 cameras."""
    rng = np.random.default_rng(3)
    pts = rng.normal(size=(300, 3))
    pts = 0.1 * pts / np.linalg.norm(pts, axis=1, keepdims=True) * rng.uniform(0.3, 1.0, (300, 1)) ** (1 / 3)
    centres = pts + [0.5, 0.5, 0.2]
    anchors = centres[rng.choice(300, 48, replace=False)]
    gaussians = Gaussians.isotropic(centres, 0.015, rng.uniform(0.2, 0.9, (300, 3)), 0.8)
    cams = [
        Camera.look_at(
            [0.5 + 0.9 * np.cos(a), 0.5 + 0.9 * np.sin(a), 0.5], [0.5, 0.5, 0.12], [0, 0, 1], 45, 32, 24, f"c{i}"
        )
        for i, a in enumerate((0.3, 2.0))
    ]

    class Seq:  # what save_asset reads of a sequence
        ground_point, ground_normal, fps, n_frames, n_fit, cameras = (
            np.zeros(3),
            np.array([0, 0, 1.0]),
            24.0,
            8,
            5,
            cams,
        )

    values = {
        "log10_k": rng.uniform(2.6, 3.0, 48),
        "kappa": 0.0,
        "friction": 0.5,
        "restitution": 0.0,
        "v0": np.array([0.2, 0.0, -0.8]),
        "gravity": np.array([0.0, 0.0, -9.8]),
    }
    out = tmp_path_factory.mktemp("twin") / "asset"
    physics = PhysicsConfig(contact="coulomb", n_c=4)
    return save_asset(
        out, gaussians, anchors, values, physics, AnchorConfig(n_k=8, n_b=4, binding="displacement"), Seq, 40, centres
    )


def test_twin_is_read_back_with_its_truth(asset_dir, tmp_path):
    truth = {"log10_k_shift": 0.3, "friction": 0.2}
    seq = load_sequence(twin_sequence(asset_dir, tmp_path / "twin", truth))
    assert seq.n_frames == 8 and seq.n_fit == 5 and seq.n_views == 2
    params = seq.gt_params()
    assert params["twin"] is True and params["truth"] == truth
    asset = load_asset(asset_dir)
    assert params["log10_k_mean"] == pytest.approx(float(np.mean(asset.values["log10_k"])) + 0.3)
    assert params["values"]["friction"] == 0.2 and params["values"]["kappa"] == 0.0
    # (displacement binding: frame 0 puts every Gaussian at its rest centre, checked below)
    # the object is visible and falls: its mask moves between frame 0 and the last frame
    first, last = seq.image(0, 0)[..., 3], seq.image(0, seq.n_frames - 1)[..., 3]
    assert first.sum() > 5 and np.abs(first - last).sum() > 1
    assert 1 <= seq.hit_frame < seq.n_frames
    gt0 = seq.gt_particles(0)
    assert gt0.shape == (300, 3) and np.allclose(gt0, asset.rest_centres, atol=1e-5)


def test_the_truth_changes_the_motion_and_nothing_else_does(asset_dir, tmp_path):
    base = load_sequence(twin_sequence(asset_dir, tmp_path / "base", {}))
    again = load_sequence(twin_sequence(asset_dir, tmp_path / "again", {}))
    stiff = load_sequence(twin_sequence(asset_dir, tmp_path / "stiff", {"log10_k_shift": 1.0}))
    last = base.n_frames - 1
    assert np.allclose(base.gt_particles(last), again.gt_particles(last), atol=1e-6)
    assert np.abs(base.gt_particles(last) - stiff.gt_particles(last)).max() > 1e-3
    assert json.loads((tmp_path / "base" / "gt" / "effects.json").read_text()) == {}


def test_a_noisy_twin_has_the_stated_noise_in_its_colours_and_a_clean_alpha(asset_dir, tmp_path):
    clean = load_sequence(twin_sequence(asset_dir, tmp_path / "clean", {}))
    noisy = load_sequence(twin_sequence(asset_dir, tmp_path / "noisy", {}, image_noise=0.05, noise_seed=1))
    again = load_sequence(twin_sequence(asset_dir, tmp_path / "again", {}, image_noise=0.05, noise_seed=1))
    a, b = clean.image(1, 3), noisy.image(1, 3)
    assert np.allclose(b, again.image(1, 3), atol=1.5 / 255)  # seeded (the render itself may differ by a step)
    assert np.allclose(a[..., 3], b[..., 3], atol=1 / 255)
    diff = (b[..., :3] - a[..., :3])[(a[..., :3] > 0.2) & (a[..., :3] < 0.8)]  # away from the clip at 0 and 1
    assert diff.std() == pytest.approx(0.05, rel=0.15) and abs(diff.mean()) < 0.01
    assert noisy.gt_params()["image_noise"] == 0.05 and clean.gt_params()["image_noise"] == 0.0
    with pytest.raises(ValueError, match="image_noise"):
        twin_sequence(asset_dir, tmp_path / "bad", {}, image_noise=-0.1)


def test_bad_truths_are_refused(asset_dir):
    asset = load_asset(asset_dir)
    with pytest.raises(ValueError, match="unknown keys"):
        twin_values(asset, {"stiffness": 2.0})
    with pytest.raises(ValueError, match="restitution"):
        twin_values(asset, {"restitution": 1.5})


def test_hit_frame():
    z = np.array([0.3, 0.1, 0.0, 0.0])  # lowest anchor height per frame
    anchors = np.stack([np.array([[0.0, 0.0, h], [0.1, 0.1, h + 0.1]]) for h in z])
    assert hit_frame(anchors, np.zeros(3), [0, 0, 1]) == 2
    assert hit_frame(anchors[2:], np.zeros(3), [0, 0, 1]) == 1  # in contact from the start


def test_a_design_search_is_kept_and_reused_only_for_the_same_sequence_and_settings(asset_dir, tmp_path):
    from dataclasses import replace

    from omegaconf import OmegaConf

    from sgdr.config import compose
    from sgdr.posterior.run import cached_search, search_key

    cfg = OmegaConf.to_object(compose(["preset=tiny"]))
    seq = twin_sequence(asset_dir, tmp_path / "twin", {})
    calls = []

    def search(value):
        def run():
            calls.append(value)
            return {"names": ["log10_k"], "candidates": [[value]], "losses": [0.1]}

        return run

    path = tmp_path / "posterior" / "design_search.json"
    key = search_key(cfg, asset_dir, seq)
    assert cached_search(path, key, search(3.0))["candidates"] == [[3.0]]
    assert cached_search(path, key, search(4.0))["candidates"] == [[3.0]] and calls == [3.0]  # kept
    # another search budget (the design search's own, or recon.search's where it has none), another
    # sequence's images: searched again
    pc = cfg.posterior
    ds = pc.surrogate.design_search
    more = replace(
        cfg,
        posterior=replace(
            pc, surrogate=replace(pc.surrogate, design_search=replace(ds, generations=ds.generations + 1))
        ),
    )
    assert search_key(more, asset_dir, seq) != key
    wider = replace(
        cfg, recon=replace(cfg.recon, search=replace(cfg.recon.search, popsize=cfg.recon.search.popsize + 1))
    )
    assert search_key(wider, asset_dir, seq) != key
    # recon.search's own budget is the user's identification's, not the design search's
    longer = replace(
        cfg, recon=replace(cfg.recon, search=replace(cfg.recon.search, generations=cfg.recon.search.generations + 1))
    )
    assert search_key(longer, asset_dir, seq) == key
    # another prior box: another design search's box (`prior_search_box`)
    priors = replace(pc.priors, restitution=[0.0, 0.8])
    assert search_key(replace(cfg, posterior=replace(pc, priors=priors)), asset_dir, seq) != key
    noisy = twin_sequence(asset_dir, tmp_path / "noisy", {}, image_noise=0.05)
    assert search_key(cfg, asset_dir, noisy) != key
    assert cached_search(path, search_key(cfg, asset_dir, noisy), search(5.0))["candidates"] == [[5.0]]
    assert calls == [3.0, 5.0]
    path.write_text("{not json")  # a file cut short by a kill: searched again
    assert cached_search(path, key, search(6.0))["candidates"] == [[6.0]]


def test_the_design_search_is_recon_search_with_the_posteriors_budget_and_windows():
    from omegaconf import OmegaConf

    from sgdr.config import compose
    from sgdr.posterior.run import design_search_config

    overrides = ["preset=small", "posterior.surrogate.design_search.line_points=5", "recon.search.popsize=7"]
    for cfg in (compose(overrides), OmegaConf.to_object(compose(overrides))):
        sc = design_search_config(cfg)
        ds = cfg.posterior.surrogate.design_search
        assert (sc.initial_samples, sc.generations, sc.line_points) == (ds.initial_samples, ds.generations, 5)
        assert list(sc.frame_schedule) == [0.5, 1.0] and list(cfg.recon.search.frame_schedule) == [1.0]
        # the rest is the identification's: candidates per generation, image scale, parameters, ranges
        assert sc.popsize == 7 and sc.image_scale == cfg.recon.search.image_scale
        assert list(sc.parameters) == list(cfg.recon.search.parameters)
        assert cfg.recon.search.line_points == 0  # the user's own search is left as it was


def test_the_design_search_box_is_the_posteriors_prior_box():
    """A truth the SBC draws from the prior must be reachable by the design search: its box is the
    prior's (the identification's own restitution ends at 0.9), the level's around the asset's level."""
    from omegaconf import OmegaConf

    from sgdr.config import compose
    from sgdr.posterior.run import design_search_config, prior_search_box

    overrides = ["preset=small", "posterior.priors.log10_k_shift=[-0.5,1.0]"]
    for cfg in (compose(overrides), OmegaConf.to_object(compose(overrides))):
        assert list(cfg.recon.search.restitution_range) == [0.0, 0.9]
        pc = cfg.posterior
        sc = prior_search_box(design_search_config(cfg), pc.priors, pc.parameters, level=3.1)
        assert list(sc.restitution_range) == [0.0, 1.0] and list(sc.friction_range) == [0.0, 1.0]
        assert list(sc.kappa_range) == [-4.0, 4.0]
        assert list(sc.log10_k_range) == pytest.approx([2.6, 4.1])
        assert sc.generations == pc.surrogate.design_search.generations  # the rest as before
        # a parameter the posterior does not sample keeps the identification's range
        only = prior_search_box(design_search_config(cfg), pc.priors, ["friction"], level=3.1)
        assert list(only.restitution_range) == [0.0, 0.9]


def test_a_resumed_calibration_case_keeps_its_twin_only_when_truth_scale_and_noise_match(asset_dir, tmp_path):
    from evaluation.studies.calibrate_posterior import same_twin

    truth = {"friction": 0.3}
    twin = twin_sequence(asset_dir, tmp_path / "twin", truth, image_noise=0.02, noise_seed=4)
    assert same_twin(twin, asset_dir, truth, 1, 0.02)
    assert not same_twin(twin, asset_dir, {"friction": 0.31}, 1, 0.02)
    assert not same_twin(twin, asset_dir, truth, 2, 0.02)
    assert not same_twin(twin, asset_dir, truth, 1, 0.0)
    assert not same_twin(tmp_path / "missing", asset_dir, truth, 1, 0.02)
    (twin / "sequence.json").unlink()  # written last: a twin cut short is rendered again
    assert not same_twin(twin, asset_dir, truth, 1, 0.02)
