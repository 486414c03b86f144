"""The injected truth mapped to each candidate's values (sgdr.discrepancy.truth): the tilt and
offset the ground candidates get put the simulator's plane on the generator's true plane (raised
by the asset's contact margin), the free-fall and material effects map to their settings, and a
candidate that models no active effect gets nothing."""

import numpy as np
import pytest

from sgdr.discrepancy.truth import truth_values
from sgdr.physics.config import PhysicsConfig
from sgdr.physics.extensions import ground_plane


def _scene(margin=0.0, point=(0.5, 0.5, 0.08), normal=(0.0, 0.0, 1.0)):
    n = np.asarray(normal, float) / np.linalg.norm(normal)
    return {
        "gravity": np.array([0.0, 0.0, -9.8]),
        "ground_point": np.asarray(point, float),
        "ground_normal": n,
        "asset_ground_point": np.asarray(point, float) + margin * n,
        "E": 2.0e4,
        "nu": 0.3,
    }


def _effects(active, point, normal, **sizes):
    base = {"plastic_yield": 0.0, "air_drag": 0.0, "stiff_ratio": 1.0, "stiff_axis": 0, "gravity": 9.8}
    base.update(sizes)
    g = [0.0, 0.0, -float(base["gravity"])]
    return {
        **base,
        "active": list(active),
        "truth": {"gravity": g, "ground": {"point": list(point), "normal": list(normal)}},
    }


def _simulated_plane(values, scene):
    from sgdr.discrepancy.candidates import _ground_tilt

    class Ctx:
        physics = PhysicsConfig()

    settings, _ = _ground_tilt(Ctx(), values, None)
    cfg = PhysicsConfig(**settings)
    return ground_plane(scene["asset_ground_point"], scene["ground_normal"], cfg)


@pytest.mark.parametrize("margin", [0.0, 0.01])
@pytest.mark.parametrize("tilt_deg,axis_angle,offset", [(5.0, 0.0, 0.0), (3.0, 40.0, 0.02), (0.0, 0.0, -0.015)])
def test_the_ground_candidates_truth_is_the_true_plane(margin, tilt_deg, axis_angle, offset):
    scene = _scene(margin)
    p_r, n_r = scene["ground_point"], scene["ground_normal"]
    # the normal tilted about a horizontal axis (the generator's: world x, axis_angle 0), the point moved up
    t, a = np.radians(tilt_deg), np.radians(axis_angle)
    n_t = np.array([np.sin(t) * np.sin(a), -np.sin(t) * np.cos(a), np.cos(t)])
    p_t = p_r + offset * n_r
    active = [k for k, on in (("ground_tilt_deg", tilt_deg), ("ground_offset", offset)) if on]
    truth = _effects(active, p_t, n_t, ground_offset=offset, ground_tilt_deg=tilt_deg)
    values, variant = truth_values("ground_tilt", truth, scene)
    assert variant is None
    assert np.hypot(values["tilt_a_deg"], values["tilt_b_deg"]) == pytest.approx(tilt_deg, abs=1e-9)
    point, normal = _simulated_plane(values, scene)
    assert np.allclose(normal, n_t, atol=1e-9)
    true_raised = p_t + margin * n_t  # the asset's plane is the recorded one raised by its margin
    assert abs(np.dot(point - true_raised, n_t)) < 1e-9
    plain = truth_values("ground_plane", truth, scene)
    if tilt_deg:
        assert plain is None  # an offset alone cannot be the truth of a tilted plane
    else:
        assert plain[0]["offset"] == pytest.approx(offset, abs=1e-12)


def test_free_fall_and_material_effects_map_to_their_settings():
    scene = _scene()
    p, n = scene["ground_point"], scene["ground_normal"]
    truth = _effects(["gravity"], p, n, gravity=9.8 * 0.85)
    assert truth_values("gravity", truth, scene)[0]["value"] == pytest.approx(0.85)
    assert truth_values("air_drag", truth, scene) is None  # models no active effect
    assert truth_values("ground_tilt", truth, scene) is None
    truth = _effects(["air_drag"], p, n, air_drag=2.0)
    assert truth_values("air_drag", truth, scene)[0]["value"] == 2.0
    truth = _effects(["stiff_ratio"], p, n, stiff_ratio=4.0, stiff_axis=2)
    values, variant = truth_values("heterogeneous_stiffness", truth, scene)
    assert values["log10_ratio"] == pytest.approx(np.log10(4.0)) and variant == 2
    # von Mises on the Hencky deviator at sigma_y / (2 mu): a volume-preserving bar yields at
    # sigma_y (1 + nu) / (E sqrt(3/2)); 0.1 E with nu 0.3 is a strain of 0.106
    truth = _effects(["plastic_yield"], p, n, plastic_yield=0.1 * scene["E"])
    strain = 10 ** truth_values("plasticity", truth, scene)[0]["log10_yield_strain"]
    assert strain == pytest.approx(0.1 * 1.3 / np.sqrt(1.5), rel=1e-9)
    assert truth_values("plasticity", truth, {**scene, "E": None}) is None  # no material: no map
    assert truth_values("contact", truth, scene) is None
    assert truth_values("gravity", {"active": []}, scene) is None


def test_a_twins_truth_is_its_physics_settings():
    scene = _scene()
    truth = {"physics": {"ground_offset": 0.03}, "active": ["ground_offset"]}
    assert truth_values("ground_plane", truth, scene) == ({"offset": 0.03}, None)
    assert truth_values("ground_tilt", truth, scene)[0] == {"tilt_a_deg": 0.0, "tilt_b_deg": 0.0, "offset": 0.03}
    assert truth_values("gravity", truth, scene) is None
    truth = {
        "physics": {"air_drag": 4.0, "plastic_yield_strain": 0.005},
        "active": ["air_drag", "plastic_yield_strain"],
    }
    assert truth_values("air_drag", truth, scene) == ({"value": 4.0}, None)
    assert 10 ** truth_values("plasticity", truth, scene)[0]["log10_yield_strain"] == pytest.approx(0.005)
    fields = {"physics": {}, "active": ["log10_k"], "fields": {"log10_k": [3.0, 3.5]}}
    assert truth_values("heterogeneous_stiffness", fields, scene) is None
