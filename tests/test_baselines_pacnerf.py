"""The PAC-NeRF baseline (sgdr/baselines/pacnerf.py, method=pacnerf): batched MPM candidates
equal single rollouts, the volume fill, the domain, the search's box, the config, and the twin:
a sequence made by the same MPM with a known E, ν and a sticky ground gives them back."""

import json

import numpy as np
import pytest
from omegaconf import OmegaConf

from sgdr.baselines import pacnerf as pn
from sgdr.baselines.config import PacNerfConfig
from sgdr.config import ConfigError, compose, validate
from sgdr.gaussians import Gaussians
from sgdr.synth import mpm


def _cube(side=0.16, spacing=0.02, centre=(0.5, 0.5, 0.35)):
    g = np.arange(-side / 2 + spacing / 2, side / 2, spacing)
    return np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3) + centre


def _scene(x, v0=(0.1, 0.0, -0.6), spacing=0.02):
    return pn.plan_scene(x, spacing, v0, (0, 0, -9.8), (0.5, 0.5, 0.2), (0, 0, 1), 1 / 24, 10)


def test_batched_candidates_equal_single_rollouts():
    """S candidates in one program (each on its own grid) = S separate rollouts."""
    x = _cube()
    scene = _scene(x)
    cfg = PacNerfConfig(collider="sticky", substeps=80)
    E, nu = np.array([5e3, 2e4, 8e4]), np.array([0.2, 0.3, 0.4])
    batch = pn.rollout(scene, cfg, E, nu, 10)
    assert batch.shape == (3, 10, len(x), 3)
    for s in range(3):
        single = pn.rollout(scene, cfg, E[s : s + 1], nu[s : s + 1], 10)[0]
        np.testing.assert_allclose(batch[s], single, atol=1e-5)
    # and the candidates differ: the stiffer one is squashed less at its most compressed frame
    squashed = (batch[..., 2].max(2) - batch[..., 2].min(2)).min(1)
    assert squashed[0] < squashed[1] < squashed[2]


def test_scene_holds_the_motion_and_puts_the_ground_on_a_node_layer():
    x = _cube()
    scene = _scene(x)
    lo = scene.origin + scene.wall_cells * scene.dx
    hi = scene.origin + (scene.n_grid - scene.wall_cells) * scene.dx
    assert np.all(x > lo) and np.all(x < hi)
    assert lo[2] < 0.2  # the ground (z = 0.2) and the wall cells below it are inside
    layer = (0.2 - scene.origin[2]) / scene.dx
    assert abs(layer - round(layer)) < 1e-6
    # the rollout stays finite and lands on the ground: the lowest particle rests near it
    frames = pn.rollout(scene, PacNerfConfig(), [2e4], [0.3], 10)[0]
    assert np.all(np.isfinite(frames))
    assert 0.2 - scene.dx < frames[-1, :, 2].min() < 0.2 + 2 * scene.dx


def _gaussians(points, scale, opacity=0.9):
    return Gaussians.isotropic(points, scale, np.full((len(points), 3), 0.5), opacity).to_numpy()


def test_fill_gives_the_volume_and_fills_a_hollow_fit():
    """A ball of Gaussians and a shell of Gaussians (a surface-only fit) are both filled solid."""
    r, spacing = 0.1, 0.01
    rng = np.random.default_rng(0)
    pts = rng.uniform(-r, r, (20000, 3))
    ball = pts[np.linalg.norm(pts, axis=1) < r - 0.01][:3000] + 0.5
    dirs = rng.normal(size=(3000, 3))
    shell = 0.5 + (r - 0.01) * dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
    truth = 4 / 3 * np.pi * r**3
    for what, centres in (("ball", ball), ("shell", shell)):
        filled = pn.fill_particles(_gaussians(centres, 0.008), spacing, 0.5)
        volume = len(filled) * spacing**3
        assert 0.8 * truth < volume < 1.25 * truth, (what, volume / truth)
        assert np.linalg.norm(filled - 0.5, axis=1).max() < r + 2 * spacing
    with pytest.raises(pn.PacNerfError, match="fill_threshold"):
        pn.fill_particles(_gaussians(ball, 0.008, opacity=0.05), spacing, 0.9)


def test_search_box_halves_the_step_and_stays_in_bounds():
    box = [3.0, 5.0]
    nxt = pn.next_box(box, 4.0, 5, box)  # step 0.5 -> the next grid's step 0.25 around the best
    assert nxt == pytest.approx([3.5, 4.5])
    edge = pn.next_box(box, 3.0, 5, box)  # at the low bound: same width, inside the bounds
    assert edge == pytest.approx([3.0, 4.0])
    assert pn.next_box([0.1, 0.4], 0.2, 1, [0.0, 0.5]) == [0.1, 0.4]  # one value: unchanged
    # an inner best whose interval is exactly two half-widths wide in floats stays around the best
    # (a rounding of hi - lo once sent it to the upper bound: [4.875, 5.5] for a best at 4.042)
    b = 3.0 + 2.5 / 3 - 0.625 + 1.25 / 3 * np.arange(4)  # round 2's grid of a 4-point search from [3, 5.5]
    nxt = pn.next_box([b[0], b[-1]], b[2], 4, [3.0, 5.5])
    assert nxt == pytest.approx([b[2] - 0.3125, b[2] + 0.3125])
    for best in np.linspace(3.0, 5.5, 41):
        lo, hi = pn.next_box([3.0, 5.5], best, 4, [3.0, 5.5])
        assert 3.0 <= lo <= best <= hi <= 5.5 and hi - lo == pytest.approx(1.25)


def test_method_composes_and_bad_values_name_their_key():
    cfg = OmegaConf.to_object(compose(["preset=tiny", "method=pacnerf"]))
    assert cfg.recon.model == "pacnerf" and cfg.baseline.pacnerf.collider == "sticky"
    assert cfg.anchors.n_anchors == 64  # the preset's scale is kept
    validate(cfg)
    for override, key in (
        ("baseline.pacnerf.grid_E=2", "baseline.pacnerf.grid_E"),
        ("baseline.pacnerf.nu_range=[0.3,0.1]", "baseline.pacnerf.nu_range"),
        ("baseline.pacnerf.collider=glue", "baseline.pacnerf.collider"),
        ("recon.model=nerf", "recon.model"),
    ):
        bad = OmegaConf.to_object(compose(["preset=tiny", "method=pacnerf", override]))
        with pytest.raises(ConfigError, match=key.replace(".", r"\.")):
            validate(bad)


def test_substeps_below_the_cfl_bound_are_refused():
    scene = _scene(_cube())
    with pytest.raises(pn.PacNerfError, match="baseline.pacnerf.substeps"):
        pn.substeps_for(scene, PacNerfConfig(substeps=2), 3e5, 0.45, 10)
    v_bound = np.linalg.norm([0.1, 0.0, -0.6]) + 9.8 * 10 / 24 + 1.0
    expected = mpm.cfl_substeps(1 / 24, scene.dx, 3e5, 0.45, 1e3, 0.3, v_bound)
    assert pn.substeps_for(scene, PacNerfConfig(), 3e5, 0.45, 10) == expected
    assert expected > pn.substeps_for(scene, PacNerfConfig(), 3e4, 0.3, 10)  # softer: fewer


@pytest.mark.slow
def test_twin_sticky_mpm_gives_back_E_and_nu(tmp_path):
    """A tiny torus made by the same MPM (sticky ground, E = 2e4 Pa, ν = 0.3, the generator's
    grid: Δx = 1/24) reconstructed with method=pacnerf from its images only: E within 15%, ν
    within 0.05; the run writes its report, metrics and asset."""
    from sgdr.pipeline.run import run_pipeline

    cfg = OmegaConf.to_object(
        compose(
            [
                "preset=tiny",
                "method=pacnerf",
                f"data_dir={tmp_path / 'data'}",
                f"recon.output_dir={tmp_path / 'out'}",
                "tracking.enabled=false",
                "recon.eval_emd=false",
                "synth.ground=sticky",
                "synth.E=2e4",
                "synth.nu=0.3",
                "baseline.pacnerf.dx=0.041666667",  # the generator's cell at tiny (synth.mpm_grid=24)
                "recon.v0_iterations=60",
            ]
        )
    )
    out = run_pipeline(cfg, progress=False)
    ident = out.metrics["identified"]
    assert out.metrics["model"] == "pacnerf"
    assert abs(ident["E"] / 2e4 - 1) < 0.15, ident
    assert abs(ident["nu"] - 0.3) < 0.05, ident
    dyn = json.loads((out.run_dir / "dynamics" / "pacnerf.json").read_text())
    assert len(dyn["evaluated"]) == 5 * 5 * 3 and not dyn["at_bound"]
    html = (out.run_dir / "report" / "report.html").read_text()
    assert "E, ν search" in html and "Identified parameters" in html
    asset = json.loads((out.run_dir / "asset" / "pacnerf.json").read_text())
    assert asset["E"] == pytest.approx(ident["E"]) and asset["collider"] == "sticky"
    assert out.metrics["fit_cd"] is not None and out.metrics["future_cd"] is not None
