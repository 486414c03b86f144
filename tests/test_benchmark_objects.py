"""The benchmark's per-object materials (issue 16 §1, docs/benchmark-objects.md): every object
has its own E, ν and v0, spread over more than a decade of E; the heterogeneous torus of the
paper's ablation has two regions of distinct E; the generator uses them, records them in
gt/params.json, and an explicit synth.* setting still wins."""

import json

import numpy as np
import pytest
from omegaconf import OmegaConf

from sgdr.config import compose
from sgdr.synth import mpm
from sgdr.synth.generate import as_synth_config, generate_sequence, with_object_material
from sgdr.synth.objects import OBJECTS

SEVEN = ("torus", "cross", "cream", "apple", "paste", "chess", "banana")


def _synth(*overrides):
    return as_synth_config(OmegaConf.to_object(compose(["preset=tiny", *overrides])).synth)


def test_every_object_has_its_own_material_spread_over_a_decade():
    assert set(OBJECTS) == {*SEVEN, "torus_hetero"}
    mats = {n: OBJECTS[n].material for n in SEVEN}
    assert len({m.E for m in mats.values()}) == 7  # no two share E
    assert len({(m.E, m.nu, tuple(m.v0)) for m in mats.values()}) == 7
    assert len({tuple(m.v0) for m in mats.values()}) >= 6
    E = np.array([m.E for m in mats.values()])
    assert E.max() / E.min() >= 10.0
    for name, m in mats.items():
        assert 0.2 <= m.nu <= 0.4 and m.stiff_ratio == 1.0, name
        assert len(m.v0) == 3 and m.v0[2] < 0, name  # thrown downwards
    hetero = OBJECTS["torus_hetero"]
    assert hetero.sdf is OBJECTS["torus"].sdf and hetero.material.stiff_ratio >= 4.0


def test_the_stiffest_object_stays_within_the_mpm_step_budget():
    """A stiffer object needs more CFL substeps; at small the stiffest needs <= 3x the torus's."""
    small = as_synth_config(OmegaConf.to_object(compose(["preset=small"])).synth)
    dx, dt_frame = 1.0 / small.mpm_grid, 1.0 / small.fps

    def substeps(name):
        m = OBJECTS[name].material
        return mpm.cfl_substeps(dt_frame, dx, m.E * m.stiff_ratio, m.nu, small.density, small.cfl, 3.5)

    counts = {n: substeps(n) for n in OBJECTS}
    assert max(counts.values()) <= 3 * counts["torus"], counts
    assert counts["apple"] > counts["cross"]  # the stiffest needs more than the softest


def test_null_settings_take_the_objects_material_and_explicit_ones_win():
    apple = OBJECTS["apple"].material
    own = with_object_material(_synth("synth.object=apple"))
    assert (own.E, own.nu, tuple(own.v0), own.effects.stiff_ratio) == (apple.E, apple.nu, tuple(apple.v0), 1.0)
    set_ = with_object_material(_synth("synth.object=apple", "synth.E=3e4", "synth.nu=0.33", "synth.v0=[0,0,-1]"))
    assert (set_.E, set_.nu, set_.v0) == (3.0e4, 0.33, [0.0, 0.0, -1.0])
    flat = with_object_material(_synth("synth.object=torus_hetero", "synth.effects.stiff_ratio=1.0"))
    assert flat.effects.stiff_ratio == 1.0 and flat.E == OBJECTS["torus_hetero"].material.E


SIZES = ("synth.n_views=1", "synth.n_frames=7", "synth.n_fit=6", "synth.resolution=16", "synth.spp=2")


@pytest.fixture(scope="module")
def generated(tmp_path_factory):
    root = tmp_path_factory.mktemp("objects")
    runs = {
        "hetero": ("synth.object=torus_hetero",),
        "override": ("synth.object=cream", "synth.E=3e4", "synth.v0=[0.0,0.1,-0.6]"),
    }
    out = {}
    for key, overrides in runs.items():
        cfg = _synth(*overrides, *SIZES)
        path = generate_sequence(cfg, root / key, seed=0)
        out[key] = (path, json.loads((path / "gt" / "params.json").read_text()))
    return out


def test_params_json_records_the_heterogeneous_objects_two_regions(generated):
    path, params = generated["hetero"]
    m = OBJECTS["torus_hetero"].material
    assert (params["E"], params["nu"], params["v0"]) == (m.E, m.nu, list(m.v0))
    assert params["density"] == 1.0e3 and params["material"] == "neo_hookean"
    E1, E2 = params["E_regions"]
    assert (E1, E2) == (m.E, m.E * m.stiff_ratio) and E2 / E1 >= 4.0
    assert params["material_source"] == {"E": "object", "nu": "object", "v0": "object"}
    # the regions are the particles' two halves along x, as recorded
    scale = np.load(path / "gt" / "particle_E_scale.npy")
    x0 = np.load(path / "gt" / "particles_000.npy")
    assert set(np.unique(scale)) == {1.0, m.stiff_ratio}
    assert x0[scale > 1, 0].min() >= x0[scale == 1, 0].max()
    assert abs((scale > 1).mean() - 0.5) < 0.01
    # the object's own heterogeneity is not an injected effect
    assert json.loads((path / "gt" / "effects.json").read_text())["active"] == []
    # the CFL substeps are sized by the stiff region
    dx, dt_frame = params["mpm"]["dx"], 1.0 / 24.0
    assert params["mpm"]["substeps_per_frame"] > mpm.cfl_substeps(dt_frame, dx, m.E, m.nu, 1e3, 0.3, 0.0)


def test_params_json_records_an_explicit_override(generated):
    _, params = generated["override"]
    cream = OBJECTS["cream"].material
    assert (params["E"], params["nu"], params["v0"]) == (3.0e4, cream.nu, [0.0, 0.1, -0.6])
    assert params["E_regions"] == [3.0e4]
    assert params["material_source"] == {"E": "config", "nu": "object", "v0": "config"}
