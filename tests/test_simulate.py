"""experiments/simulate.py's machinery on a small hand-made asset (no pipeline run): edits
checked naming their key, the instability message naming recon.simulate.*, one folder per
simulation, and the momentum audit: directed springs with unequal k_i gain momentum on a
frictionless ground, symmetric ones do not."""

import json
from dataclasses import replace

import numpy as np
import pytest

from sgdr.anchors.config import AnchorConfig
from sgdr.asset.config import SimulateConfig
from sgdr.asset.store import Asset
from sgdr.asset.whatif import (
    check_simulate_config,
    simulate_asset,
    simulation_dir,
    simulation_momentum,
    simulation_record,
    simulation_tag,
)
from sgdr.physics import PhysicsConfig, SimulationUnstable


def small_asset(tmp_path, springs="directed", contact="coulomb", log10_k=None) -> Asset:
    """64 anchors in a 0.2-wide box 0.05 above the ground z = 0, thrown down and sideways;
    no Gaussians or cameras (enough to simulate, not to render)."""
    rng = np.random.default_rng(7)
    anchors = rng.uniform(0.0, 0.2, (64, 3)) + [0.4, 0.4, 0.05]
    values = {
        "log10_k": np.asarray(log10_k if log10_k is not None else rng.uniform(2.0, 3.0, 64), float),
        "kappa": 0.1,
        "friction": 0.5,
        "restitution": 0.0,
        "v0": np.array([0.3, 0.0, -1.0]),
        "gravity": np.array([0.0, 0.0, -9.8]),
    }
    return Asset(
        root=tmp_path / "asset",
        gaussians=None,
        anchors=anchors,
        rest_centres=anchors.copy(),
        values=values,
        physics=PhysicsConfig(springs=springs, contact=contact, n_c=4),
        anchor_cfg=AnchorConfig(n_k=8, n_b=4),
        ground_point=np.zeros(3),
        ground_normal=np.array([0.0, 0.0, 1.0]),
        fps=24.0,
        n_frames=24,
        n_fit=12,
        n_substeps=40,
        cameras=[],
    )


def rollout_of(asset, sim):
    """simulate_asset's rollout without rendering (the asset has no Gaussians)."""
    from sgdr.asset.predict import physical_params, predict
    from sgdr.asset.whatif import edited_values
    from sgdr.physics import Ground

    check_simulate_config(asset, sim)
    model, binding = asset.build()
    values, point, _ = edited_values(asset, sim)
    params = physical_params(model, asset.physics, values)
    n_frames = sim.n_frames or asset.n_frames
    ground = Ground(point, asset.ground_normal)
    n_t = sim.n_substeps or asset.n_substeps
    return predict(model, params, binding, None, ground, n_frames, asset.fps, n_t, asset.physics, [], None, False)


@pytest.mark.parametrize(
    "edit, key",
    [
        ({"stiffness_scale": 0.0}, "recon.simulate.stiffness_scale"),
        ({"gravity": [0.0, -9.8]}, "recon.simulate.gravity"),
        ({"v0": [1.0]}, "recon.simulate.v0"),
        ({"n_frames": -1}, "recon.simulate.n_frames"),
        ({"restitution": 1.5}, "recon.simulate.restitution"),
        ({"ground_height": float("nan")}, "recon.simulate.ground_height"),
        ({"cameras": "fisheye"}, "recon.simulate.cameras"),
    ],
)
def test_bad_edits_name_their_key(tmp_path, edit, key):
    with pytest.raises(ValueError, match=key.replace(".", r"\.")):
        check_simulate_config(small_asset(tmp_path), SimulateConfig(**edit))


def test_restitution_is_refused_under_project_contact_and_acts_under_coulomb(tmp_path):
    with pytest.raises(ValueError, match=r"restitution=0\.5 has no effect.*physics\.contact=project"):
        check_simulate_config(small_asset(tmp_path, contact="project"), SimulateConfig(restitution=0.5))
    with pytest.raises(ValueError, match=r"recon\.simulate\.friction=1\.5"):
        check_simulate_config(small_asset(tmp_path, contact="project"), SimulateConfig(friction=1.5))
    # coulomb: the edited e reaches the simulator (a soft random body barely bounces as a whole,
    # so this checks that the bounce changes the rollout and is recorded as edited)
    from sgdr.asset.whatif import edited_values

    asset = small_asset(tmp_path, springs="symmetric")
    assert edited_values(asset, SimulateConfig(restitution=0.9))[0]["restitution"] == 0.9
    assert edited_values(asset, SimulateConfig())[0]["restitution"] == 0.0  # < 0: the identified one
    dead, bouncy = (rollout_of(asset, SimulateConfig(restitution=e, n_frames=12)) for e in (0.0, 0.9))
    assert np.abs(bouncy.anchors - dead.anchors).max() > 1e-3
    assert bouncy.velocities[:, :, 2].max() > dead.velocities[:, :, 2].max() + 0.1


def test_unstable_edit_names_the_simulate_substeps(tmp_path):
    asset = small_asset(tmp_path)
    sim = SimulateConfig(stiffness_scale=1e4, n_substeps=5, max_substeps=20, n_frames=3)
    with pytest.raises(SimulationUnstable) as info:
        simulate_asset(asset, sim, None)
    msg = str(info.value)
    assert "recon.simulate.n_substeps=5" in msg and "n_t=20" in msg and "recon.simulate.max_substeps=20" in msg
    assert "physics.n_substeps" not in msg.replace("not physics.*", "")


def test_each_simulation_gets_its_own_folder(tmp_path):
    asset_dir = tmp_path / "run" / "asset"
    asset_dir.mkdir(parents=True)
    soft = SimulateConfig(stiffness_scale=0.1, friction=0.0)
    assert simulation_tag(soft) == "friction-0_stiffness_scale-0.1"
    assert simulation_tag(SimulateConfig()) == "unedited"
    assert simulation_tag(SimulateConfig(gravity=[0, 0, -1.5])) == "gravity-0+0+-1.5"
    from sgdr.asset.config import SIMULATE_CHECKS

    for sim in (soft, SimulateConfig(gravity=[0, 0, -1.5], v0=[1, 0, 0], cameras="orbit")):
        assert SIMULATE_CHECKS["tag"].ok(simulation_tag(sim))  # a default tag is a valid explicit one

    def write(out, sim):
        out.mkdir(parents=True, exist_ok=True)
        (out / "simulate.json").write_text(json.dumps(simulation_record(sim, asset_dir)))

    first = simulation_dir(asset_dir, soft)
    assert first == tmp_path / "run" / "simulate" / "friction-0_stiffness_scale-0.1"
    write(first, soft)
    assert simulation_dir(asset_dir, soft) == first  # the same simulation again: its own folder
    # another simulation whose folder name is taken (an older simulate.json, other edits)
    other = tmp_path / "run" / "simulate" / "unedited"
    other.mkdir()
    (other / "simulate.json").write_text(json.dumps({"tag": "edited", "stiffness_scale": 0.5}))
    assert simulation_dir(asset_dir, SimulateConfig()) == other.with_name("unedited-2")
    # explicit tag holding another simulation: refused, unless overwrite
    tagged = SimulateConfig(tag="friction-0_stiffness_scale-0.1", stiffness_scale=0.2)
    with pytest.raises(FileExistsError, match=r"recon\.simulate\.tag"):
        simulation_dir(asset_dir, tagged)
    assert simulation_dir(asset_dir, replace(tagged, overwrite=True)) == first
    with pytest.raises(FileExistsError, match=r"recon\.simulate\.out_dir"):
        simulation_dir(asset_dir, SimulateConfig(out_dir=str(other)))


def test_directed_springs_gain_momentum_on_a_frictionless_ground_symmetric_do_not(tmp_path):
    sim = SimulateConfig(friction=0.0, n_frames=24)
    verdicts = {}
    for springs in ("directed", "symmetric"):
        asset = small_asset(tmp_path, springs=springs)
        pred = rollout_of(asset, sim)
        v = simulation_momentum(asset, sim, pred)
        verdicts[springs] = v
        # frictionless: the ground adds nothing along it, so the centre of mass's change along
        # the ground is the springs' (the audit re-runs the same rollout)
        com = pred.velocities.mean(1)
        along = np.linalg.norm(com[-1, :2] - com[0, :2])
        assert v["ground_dv_end_along_ground"] < 1e-4
        assert along == pytest.approx(np.linalg.norm(v["springs_dv_end"][:2]), abs=1e-4)
        assert v["n_substeps"] == pred.n_substeps == 40
    d, s = verdicts["directed"], verdicts["symmetric"]
    assert d["gains_momentum"] and d["springs_dv_max"] > 10 * d["tolerance"]
    assert "physics.springs=directed" in d["warning"] and "physics.springs=symmetric does" in d["warning"]
    assert not s["gains_momentum"] and s["warning"] is None and s["springs_dv_max"] < 1e-3
    # the ground did push back (normal impulse): the body landed
    assert s["ground_dv_end"][2] > 1.0


def test_directed_springs_with_equal_stiffness_still_break_newtons_third_law(tmp_path):
    """kNN is not symmetric (i among j's neighbours does not make j among i's), so even with
    one k for every anchor the directed springs' forces need not cancel."""
    asset = small_asset(tmp_path, log10_k=np.full(64, 2.5))
    sim = SimulateConfig(friction=0.0, n_frames=24)
    v = simulation_momentum(asset, sim, rollout_of(asset, sim))
    assert v["springs_dv_max"] > 0.05
