"""The injected truth as a candidate's values: what the data show of an effect at its true size.

A generated sequence records the nominal scene and keeps the injected effects in `gt/effects.json`
(`sgdr.synth.generate`). For each candidate that models an active effect, `truth_values` maps
the truth to that candidate's values, so the diagnosis can judge the candidate *at the truth*
exactly as it judges its fitted values (`sgdr.discrepancy.run.judge_truth`). The gain at the
truth is what the data and the base model let the effect show at all: a miss whose candidate
gains less than its threshold even at the truth is below what this data can reveal (no search
would find it), a miss whose truth gain passes is the search's or the decision's.

The maps (exact unless said):
- gravity: |g_true| / |g_recorded|; air_drag: the MPM's linear drag c (1/s), the same law.
- ground_plane (an offset only): the true plane's distance from the recorded one along its normal.
- ground_tilt: the tilt vector (θ cos φ, θ sin φ) of the true normal in the recorded plane's axes
  (`sgdr.physics.extensions.plane_axes`) and the offset that puts the moved point on the true
  plane (raised by the asset's contact margin, as the asset's own plane is).
- heterogeneous_stiffness: log10 of the generator's E ratio of the upper half along its axis (the
  variant); springs scale with E.
- plasticity, approximate: the MPM yields when the Hencky strain's deviator exceeds
  σ_y / (2 μ) (`sgdr.synth.mpm.von_mises_return`); a bar stretched uniaxially at constant volume
  reaches that at the strain σ_y / (2 μ) / sqrt(3/2) = σ_y (1 + ν) / (E sqrt(3/2)), taken as the
  springs' yield strain.
"""

from __future__ import annotations

import numpy as np

from sgdr.physics.extensions import plane_axes


def _unit(v) -> np.ndarray:
    v = np.asarray(v, float).reshape(3)
    return v / np.linalg.norm(v)


def _gravity(truth: dict, scene: dict) -> dict | None:
    if "gravity" not in truth["active"]:
        return None
    g_true = np.linalg.norm(np.asarray(truth["truth"]["gravity"], float))
    return {"value": float(g_true / np.linalg.norm(np.asarray(scene["gravity"], float)))}


def _air_drag(truth: dict, scene: dict) -> dict | None:
    return {"value": float(truth["air_drag"])} if "air_drag" in truth["active"] else None


def _planes(truth: dict, scene: dict):
    """(recorded point, recorded normal, true point, true normal, the asset's point)."""
    g = truth["truth"]["ground"]
    return (
        np.asarray(scene["ground_point"], float),
        _unit(scene["ground_normal"]),
        np.asarray(g["point"], float),
        _unit(g["normal"]),
        np.asarray(scene["asset_ground_point"], float),
    )


def _ground_offset(truth: dict, scene: dict) -> dict | None:
    active = truth["active"]
    if "ground_offset" not in active or "ground_tilt_deg" in active:
        return None
    p_r, n_r, p_t, _, _ = _planes(truth, scene)
    return {"offset": float(np.dot(p_t - p_r, n_r))}


def _ground_tilt(truth: dict, scene: dict) -> dict | None:
    active = truth["active"]
    if "ground_tilt_deg" not in active and "ground_offset" not in active:
        return None
    p_r, n_r, p_t, n_t, p_a = _planes(truth, scene)
    a, b = plane_axes(n_r)
    theta = float(np.degrees(np.arccos(np.clip(np.dot(n_r, n_t), -1.0, 1.0))))
    phi = float(np.arctan2(np.dot(n_t, b), np.dot(n_t, a)))
    margin = float(np.dot(p_a - p_r, n_r))  # the asset's plane above the recorded one
    offset = float(np.dot(p_t + margin * n_t - p_a, n_t) / np.dot(n_r, n_t))
    return {"tilt_a_deg": theta * np.cos(phi), "tilt_b_deg": theta * np.sin(phi), "offset": offset}


def _stiff_ratio(truth: dict, scene: dict) -> dict | None:
    if "stiff_ratio" not in truth["active"]:
        return None
    return {"log10_ratio": float(np.log10(float(truth["stiff_ratio"])))}


def _plastic(truth: dict, scene: dict) -> dict | None:
    if "plastic_yield" not in truth["active"]:
        return None
    E, nu = scene.get("E"), scene.get("nu")
    if E is None or nu is None:  # gt/params.json missing or without the material
        return None
    strain = float(truth["plastic_yield"]) * (1.0 + float(nu)) / (float(E) * np.sqrt(1.5))
    return {"log10_yield_strain": float(np.log10(strain))}


# candidate name -> (truth, scene) -> its values at the truth, or None when it models no active effect
TRUTH = {
    "gravity": _gravity,
    "air_drag": _air_drag,
    "ground_plane": _ground_offset,
    "ground_tilt": _ground_tilt,
    "heterogeneous_stiffness": _stiff_ratio,
    "plasticity": _plastic,
}


def _twin_tilt(p: dict) -> dict | None:
    theta, phi = float(p.get("ground_tilt_deg", 0.0)), np.radians(float(p.get("ground_tilt_azimuth_deg", 0.0)))
    if theta == 0.0 and "ground_offset" not in p:
        return None
    return {
        "tilt_a_deg": theta * np.cos(phi),
        "tilt_b_deg": theta * np.sin(phi),
        "offset": float(p.get("ground_offset", 0.0)),
    }


# a twin of an asset (`sgdr.synth.twin`) records the extension settings themselves
# (gt/effects.json "physics"): candidate name -> those settings -> its values, or None
TWIN = {
    "gravity": lambda p: {"value": float(p["gravity_scale"])} if "gravity_scale" in p else None,
    "air_drag": lambda p: {"value": float(p["air_drag"])} if "air_drag" in p else None,
    "ground_plane": lambda p: (
        {"offset": float(p["ground_offset"])} if "ground_offset" in p and not p.get("ground_tilt_deg") else None
    ),
    "ground_tilt": _twin_tilt,
    "contact": lambda p: {"value": float(p["contact_restitution"])} if "contact_restitution" in p else None,
    "plasticity": lambda p: (
        {"log10_yield_strain": float(np.log10(float(p["plastic_yield_strain"])))}
        if float(p.get("plastic_yield_strain", 0.0)) > 0.0
        else None
    ),
}


def truth_values(name: str, truth: dict | None, scene: dict) -> tuple[dict, object] | None:
    """(values, variant) of candidate `name` at the injected truth, or None.

    truth: gt/effects.json: the generator's (its "active" list, the effect sizes and "truth": the
    true gravity and ground) or a twin's ("physics": the extension settings); scene: the recorded
    "gravity", "ground_point", "ground_normal" (sequence.json), the asset's "asset_ground_point",
    and the material's "E" and "nu" (gt/params.json) when known."""
    if not truth or not truth.get("active"):
        return None
    if "physics" in truth:  # a twin: its fields (e.g. a stiffness field) map to no candidate's values
        values = TWIN[name](truth["physics"]) if name in TWIN else None
        return (values, None) if values else None
    if name not in TRUTH:
        return None
    values = TRUTH[name](truth, scene)
    if values is None:
        return None
    variant = int(truth.get("stiff_axis", 0)) if name == "heterogeneous_stiffness" else None
    return values, variant


def scene_of(seq, asset) -> dict:
    """The `scene` argument of `truth_values` for a sequence and the asset that observes it."""
    scene = {
        "gravity": np.asarray(seq.gravity, float),
        "ground_point": np.asarray(seq.ground_point, float),
        "ground_normal": np.asarray(seq.ground_normal, float),
        "asset_ground_point": np.asarray(asset.ground_point, float),
    }
    params = seq.gt_params() if seq.gt_dir is not None and (seq.gt_dir / "params.json").is_file() else None
    if params:
        scene["E"] = (params.get("E_regions") or [params.get("E")])[0]
        scene["nu"] = params.get("nu")
    return scene
