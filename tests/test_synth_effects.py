"""Injected effects change the truth, never what the sequence records (issue 15 §5): a weaker
gravity and a raised, tilted ground act in the MPM while sequence.json keeps the nominal scene
and gt/effects.json holds the truth."""

import json

import numpy as np
from omegaconf import OmegaConf

from sgdr.config import compose
from sgdr.data import load_sequence


def test_gravity_and_ground_effects_act_but_the_sequence_records_the_nominal_scene(tmp_path):
    from sgdr.synth.generate import generate_sequence, true_ground

    def make(name, *effects):
        cfg = OmegaConf.to_object(
            compose(["preset=tiny", "synth.object=torus", "synth.n_views=1", "synth.n_frames=12", *effects]).synth
        )
        return cfg, load_sequence(generate_sequence(cfg, tmp_path / name, seed=0))

    _, base = make("base")
    cfg, seq = make("moved", "synth.effects.gravity=7.0", "synth.effects.ground_offset=0.03",
                    "synth.effects.ground_tilt_deg=3.0")  # fmt: skip
    # the sequence: the nominal scene (the planned ground, gravity 9.8), whatever the effects
    np.testing.assert_allclose(seq.gravity, [0, 0, -9.8])
    np.testing.assert_allclose(seq.ground_normal, [0, 0, 1])
    recorded = seq.gt_params()["recorded"]
    np.testing.assert_allclose(recorded["ground"]["point"], seq.ground_point)
    np.testing.assert_allclose(base.gravity, seq.gravity)
    # the truth
    effects = json.loads((seq.root / "gt" / "effects.json").read_text())
    assert {"gravity", "ground_offset", "ground_tilt_deg"} <= set(effects["active"])
    assert seq.gt_params()["mpm"]["frame"] == "plane"  # the tilted ground is level in the MPM's frame
    np.testing.assert_allclose(effects["truth"]["gravity"], [0, 0, -7.0])
    point, normal = true_ground(seq.ground_point, cfg)
    np.testing.assert_allclose(effects["truth"]["ground"]["point"], point)
    assert abs(np.degrees(np.arccos(normal @ [0, 0, 1])) - 3.0) < 1e-9
    # the MPM collided with the true plane: at the end the lowest particles rest on it, above the recorded one
    x = seq.gt_particles(seq.n_frames - 1)
    dx = 1.0 / cfg.mpm_grid
    on_true = (x - point) @ normal
    assert -1.0 * dx < on_true.min() < 2.5 * dx, on_true.min()
    assert ((x - seq.ground_point) @ seq.ground_normal).min() > 0.03 - 2 * dx
    # and the weaker gravity slowed the fall: the free-flight frames lag the plain benchmark's
    drop = base.gt_particles(2).mean(0)[2] - seq.gt_particles(2).mean(0)[2]
    assert drop < 0, drop  # the moved sequence is higher at frame 2 (falls slower)


def test_a_tilted_grounds_effect_does_not_depend_on_the_mpm_grid(tmp_path):
    """The MPM simulates a tilted ground in the plane's own frame (`simulate_drop`), so what the
    tilt does to the motion is the same at two grid resolutions. Colliding with the tilted plane
    on the world-aligned grid made a staircase of it: the torus's drift from the level drop by
    frame 11 was 0.083 units at 24 cells per unit and 0.008 at 36 (now 0.046 and 0.048)."""
    from sgdr.synth.generate import generate_sequence

    def com(grid, tilt):
        cfg = OmegaConf.to_object(
            compose(
                [
                    "preset=tiny",
                    "synth.object=torus",
                    "synth.n_views=1",
                    "synth.n_frames=12",
                    f"synth.mpm_grid={grid}",
                    f"synth.effects.ground_tilt_deg={tilt}",
                ]  # fmt: skip
            ).synth
        )
        seq = load_sequence(generate_sequence(cfg, tmp_path / f"g{grid}_t{tilt}", seed=0))
        return seq.gt_particles(seq.n_frames - 1).mean(0)

    drift = {grid: com(grid, 3.0) - com(grid, 0.0) for grid in (24, 36)}
    size = [np.linalg.norm(d) for d in drift.values()]
    assert min(size) > 0.02, drift  # the tilt moves the bounce
    assert np.linalg.norm(drift[24] - drift[36]) < 0.2 * max(size), drift
    assert drift[24][1] < 0 and drift[36][1] < 0, drift  # downhill: the plane rises towards +y
