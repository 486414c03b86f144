"""The reconstructed asset: everything needed to simulate the object under new conditions.

A folder holding
  gaussians.ply     appearance (3DGS layout), centres at the IDW rest positions
  anchors.npy       [N_A, 3] rest anchors, world, scene units
  rest_centres.npy  [M, 3] static-fit centres the IDW binding was built from (Eq. 14)
  params.npz        identified log10_k [N_A], kappa, friction, restitution, v0 [3], gravity [3]
  asset.json        physics + anchor settings, ground plane, fps, frame counts, n_t, cameras

`simulate_asset` runs it with edited conditions (the paper's Figs. 6-7): ground height and
friction, gravity vector, a stiffness scale, initial velocity, frame count, and renders the
sequence's cameras or an orbit.
"""

from __future__ import annotations

import json
import logging
import math
from dataclasses import fields, replace
from dataclasses import fields as dc_fields
from pathlib import Path

import numpy as np

from sgdr.arrays import points_to_array3, to_numpy
from sgdr.asset.config import SimulateConfig
from sgdr.asset.momentum import internal_impulses, momentum_check
from sgdr.asset.predict import Prediction, physical_params, predict
from sgdr.asset.store import Asset
from sgdr.cameras import Camera
from sgdr.checks import ConfigError
from sgdr.physics import Ground, SimulationUnstable
from sgdr.registry import Registry
from sgdr.render.images import posed, render_rgba_numpy

log = logging.getLogger(__name__)


def orbit_cameras(asset: Asset, n: int) -> list[Camera]:
    """`n` cameras on a circle around the rest anchors' centre, at the sequence cameras'
    mean distance and elevation (about the ground normal), same field of view and size."""
    up = asset.ground_normal / np.linalg.norm(asset.ground_normal)
    target = asset.anchors.mean(0)
    ref = asset.cameras[0]
    offsets = np.stack([c.centre - target for c in asset.cameras])
    radius = float(np.linalg.norm(offsets, axis=1).mean())
    height = float((offsets @ up).mean())
    horizontal = math.sqrt(max(radius**2 - height**2, 1e-12))
    e1 = np.cross(up, [1.0, 0.0, 0.0] if abs(up[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(up, e1)
    cams = []
    for i in range(n):
        a = 2.0 * math.pi * i / n
        eye = target + height * up + horizontal * (math.cos(a) * e1 + math.sin(a) * e2)
        cams.append(Camera.look_at(eye, target, up, ref.fov_x_deg, ref.width, ref.height, name=f"orbit_{i:03d}"))
    return cams


def check_simulate_config(asset: Asset, sim_cfg) -> None:
    """Refuse edits that cannot be simulated, naming the key `recon.simulate.<field>`
    (`sgdr.checks.ConfigError`, a ValueError).

    Kept to what a bare error would otherwise hide (a math domain error, a reshape error, a
    rollout of no frames) and to what depends on the asset (its contact model); the value
    ranges of every config section are also checked up front by the config validator."""

    where = "recon.simulate"

    def finite(name, value):
        if not math.isfinite(float(value)):
            raise ConfigError(f"{where}.{name}={value} must be a finite number")

    for name in ("stiffness_scale", "ground_height", "friction", "restitution", "momentum_tolerance"):
        finite(name, getattr(sim_cfg, name))
    if not float(sim_cfg.stiffness_scale) > 0:
        raise ConfigError(
            f"{where}.stiffness_scale={sim_cfg.stiffness_scale} must be > 0 (every k_i is multiplied by it)"
        )
    for name in ("gravity", "v0"):
        vec = list(getattr(sim_cfg, name))
        if len(vec) not in (0, 3):
            raise ConfigError(
                f"{where}.{name}={vec} must hold 3 numbers [x, y, z] or be empty ([] = the identified value)"
            )
        for v in vec:
            finite(name, v)
    for name in ("n_frames", "n_substeps", "max_substeps"):
        if int(getattr(sim_cfg, name)) < 0:
            raise ConfigError(f"{where}.{name}={getattr(sim_cfg, name)} must be >= 0 (0 = the asset's)")
    if not float(sim_cfg.momentum_tolerance) > 0:
        raise ConfigError(f"{where}.momentum_tolerance={sim_cfg.momentum_tolerance} must be > 0 (scene units / s)")
    contact = asset.physics.contact
    if contact == "project" and float(sim_cfg.friction) > 1:
        raise ConfigError(
            f"{where}.friction={sim_cfg.friction}: with the asset's physics.contact=project friction is the factor "
            "the tangential velocity is multiplied by at every substep in contact, in [0, 1] (1 = frictionless, "
            "0 = sticky); above 1 the ground would push the object along"
        )
    if float(sim_cfg.restitution) > 1:
        raise ConfigError(f"{where}.restitution={sim_cfg.restitution} must be in [0, 1] (< 0 = the identified value)")
    if float(sim_cfg.restitution) >= 0 and contact != "coulomb":
        raise ConfigError(
            f"{where}.restitution={sim_cfg.restitution} has no effect: the asset's contact model is "
            f"physics.contact={contact} (in {asset.root / 'asset.json'}), which never bounces; restitution acts "
            "only under physics.contact=coulomb (reconstruct with it to get a bouncing asset)"
        )
    SIMULATE_CAMERAS.get_named(sim_cfg.cameras)


def edited_values(asset: Asset, sim_cfg) -> tuple[dict, np.ndarray, float]:
    """(parameter values, ground point, friction) after the edits of `SimulateConfig`
    (`check_simulate_config` first: a stiffness_scale <= 0 has no logarithm)."""
    values = dict(asset.values)
    values["log10_k"] = np.asarray(values["log10_k"], float) + math.log10(float(sim_cfg.stiffness_scale))
    if sim_cfg.friction >= 0:
        values["friction"] = float(sim_cfg.friction)
    if sim_cfg.restitution >= 0:
        values["restitution"] = float(sim_cfg.restitution)
    if len(sim_cfg.gravity):
        values["gravity"] = np.asarray(sim_cfg.gravity, float).reshape(3)
    if len(sim_cfg.v0):
        values["v0"] = np.asarray(sim_cfg.v0, float).reshape(3)
    n = asset.ground_normal / np.linalg.norm(asset.ground_normal)
    point = asset.ground_point + float(sim_cfg.ground_height) * n
    return values, point, values["friction"]


def simulate_asset(asset: Asset, sim_cfg, render_cfg, progress: bool = False):
    """Simulate the asset under `sim_cfg`'s edits; returns (Prediction, cameras used).

    `sim_cfg.cameras` (`SIMULATE_CAMERAS`): "sequence", every sequence camera renders every
    frame; "orbit", frame t is rendered from orbit camera t (one turn over the clip). The
    substeps per frame are `sim_cfg.n_substeps` (recon.simulate.n_substeps), 0 = the n_t the
    asset reached in training; an unstable rollout is redone with twice the substeps (the
    asset's physics.retry_on_nan) up to recon.simulate.max_substeps (0 = the asset's
    physics.max_substeps), and if still unstable the error names those two keys and the
    substeps tried. The Prediction's `n_substeps` is what the rollout used, its `velocities`
    feed `sgdr.asset.momentum.momentum_check`. Invalid edits raise ValueError naming
    `recon.simulate.<field>` (`check_simulate_config`).
    """

    check_simulate_config(asset, sim_cfg)
    render_with = SIMULATE_CAMERAS.get_named(sim_cfg.cameras)
    model, binding = asset.build()
    values, point, _ = edited_values(asset, sim_cfg)
    ground = Ground(point, asset.ground_normal)
    n_t = int(sim_cfg.n_substeps) or asset.n_substeps
    max_substeps = int(sim_cfg.max_substeps) or asset.physics.max_substeps
    physics = replace(asset.physics, max_substeps=max(max_substeps, n_t))
    params = physical_params(model, physics, values)
    n_frames = int(sim_cfg.n_frames) or asset.n_frames
    try:
        return render_with(asset, model, params, binding, ground, n_frames, n_t, render_cfg, progress, physics)
    except SimulationUnstable as exc:
        tried = n_t
        while physics.retry_on_nan and 2 * tried <= physics.max_substeps:
            tried *= 2
        inner = str(exc).replace("physics.n_substeps", "recon.simulate.n_substeps")
        inner = inner.replace("physics.max_substeps", "recon.simulate.max_substeps")
        retried = (
            f"doubled up to n_t={tried}, the most recon.simulate.max_substeps={physics.max_substeps} allows"
            if physics.retry_on_nan
            else "not retried (the asset's physics.retry_on_nan is off)"
        )
        raise SimulationUnstable(
            f"the edited rollout is unstable with recon.simulate.n_substeps={sim_cfg.n_substeps} (n_t={n_t}"
            f"{'' if sim_cfg.n_substeps else ', the asset reached in training'}; {retried}): {inner}. The "
            "simulation uses recon.simulate.n_substeps and recon.simulate.max_substeps, not physics.*: raise "
            "them, or lower recon.simulate.stiffness_scale"
        ) from exc


def simulation_tag(sim_cfg) -> str:
    """The default name of a simulation's folder, from its edits: every field that differs from
    `SimulateConfig`'s default (except where the outputs go), `<field>-<value>` joined by `_`,
    e.g. `friction-0_stiffness_scale-0.1`, `gravity-0+0+-1.5`; `unedited` when nothing is edited."""

    default = SimulateConfig()
    parts = []
    for f in dc_fields(SimulateConfig):
        if f.name in ("asset", "out_dir", "tag", "overwrite"):
            continue
        value, base = getattr(sim_cfg, f.name), getattr(default, f.name)
        if isinstance(base, list):
            value = [float(v) for v in value]
            if value == [float(b) for b in base]:
                continue
            text = "+".join(f"{v:g}" for v in value)  # a folder name has no commas (sgdr.checks.folder_name)
        elif isinstance(base, float):
            if float(value) == base:
                continue
            text = f"{float(value):g}"
        else:
            if value == base:
                continue
            text = str(value)
        parts.append(f"{f.name}-{text}")
    return "_".join(parts) or "unedited"


def _simulation_record(sim_cfg, asset_dir) -> dict:
    """What identifies a simulation in its simulate.json: the asset folder and the edits."""

    edits = {
        f.name: getattr(sim_cfg, f.name)
        for f in fields(SimulateConfig)
        if f.name not in ("asset", "out_dir", "tag", "overwrite")
    }
    edits = json.loads(json.dumps(edits, default=list))  # lists of floats, as read back
    return {"asset": str(Path(asset_dir).resolve()), "edits": edits}


def simulation_dir(asset_dir, sim_cfg) -> Path:
    """The output folder of this simulation, never another simulation's silently.

    Default (`recon.simulate.out_dir` and `recon.simulate.tag` empty):
    `<asset>/../simulate/<simulation_tag>`; if that folder holds a different simulation (its
    simulate.json names another asset or other edits), the next free `<tag>-2`, `<tag>-3`, ... is
    used instead. The same simulation again (same asset, same edits) reuses its folder.
    Explicit `recon.simulate.out_dir` or `recon.simulate.tag`: a folder holding a different
    simulation (or files but no simulate.json) is refused with FileExistsError naming the key,
    unless `recon.simulate.overwrite=true`.
    """
    asset_dir = Path(asset_dir)
    record = _simulation_record(sim_cfg, asset_dir)
    explicit = "recon.simulate.out_dir" if sim_cfg.out_dir else "recon.simulate.tag" if sim_cfg.tag else ""
    base = Path(sim_cfg.out_dir) if sim_cfg.out_dir else asset_dir.parent / "simulate" / (sim_cfg.tag or "")
    if not sim_cfg.out_dir and not sim_cfg.tag:
        tag = simulation_tag(sim_cfg)
        base = asset_dir.parent / "simulate" / tag
        out, i = base, 1
        while _holds_other_simulation(out, record):
            i += 1
            out = base.with_name(f"{tag}-{i}")
        return out
    if _holds_other_simulation(base, record) and not sim_cfg.overwrite:
        raise FileExistsError(
            f"{base} ({explicit}) already holds another simulation ({base / 'simulate.json'}: other asset or "
            "edits, or files without a simulate.json): choose another "
            f"{explicit}, leave recon.simulate.tag and out_dir empty for a new folder named after the edits, or "
            "set recon.simulate.overwrite=true to replace it"
        )
    return base


def _holds_other_simulation(folder: Path, record: dict) -> bool:
    if not folder.exists() or not any(folder.iterdir()):
        return False
    meta = folder / "simulate.json"
    if not meta.exists():
        return True
    try:
        saved = json.loads(meta.read_text())
    except json.JSONDecodeError:
        return True
    return {"asset": saved.get("asset"), "edits": saved.get("edits")} != record


def simulation_record(sim_cfg, asset_dir, **extra) -> dict:
    """simulate.json's content: the asset, the edits (what `simulation_dir` compares) and `extra`."""
    return {**_simulation_record(sim_cfg, asset_dir), **extra}


# How `simulate_asset` renders (recon.simulate.cameras): (asset, model, params, binding, ground,
# n_frames, n_t, render_cfg, progress, physics) -> (Prediction, cameras); physics: the asset's
# PhysicsConfig with the simulation's max_substeps.
SIMULATE_CAMERAS = Registry("simulate camera set", "recon.simulate.cameras", ValueError)


@SIMULATE_CAMERAS.register("sequence")
def simulate_sequence_cameras(asset, model, params, binding, ground, n_frames, n_t, render_cfg, progress, physics):
    """Every sequence camera renders every frame."""

    return predict(
        model,
        params,
        binding,
        asset.gaussians,
        ground,
        n_frames,
        asset.fps,
        n_t,
        physics,
        asset.cameras,
        render_cfg,
        True,
        progress,
    ), asset.cameras


@SIMULATE_CAMERAS.register("orbit")
def simulate_orbit_cameras(asset, model, params, binding, ground, n_frames, n_t, render_cfg, progress, physics):
    """Frame t from orbit camera t: one turn around the object over the clip."""

    traj = predict(
        model,
        params,
        binding,
        asset.gaussians,
        ground,
        n_frames,
        asset.fps,
        n_t,
        physics,
        [],
        render_cfg,
        False,
        progress,
    )
    cams = orbit_cameras(asset, n_frames)
    images = []
    for f in range(n_frames):
        g = posed(asset.gaussians, points_to_array3(traj.centres[f]))
        images.append((render_rgba_numpy(g, cams[f], render_cfg)[None] * 255.0 + 0.5).astype(np.uint8))
    return Prediction(traj.anchors, traj.centres, np.stack(images), traj.velocities, traj.n_substeps), cams


def simulation_momentum(asset: Asset, sim_cfg, pred) -> dict:
    """`sgdr.asset.momentum.momentum_check` of a `simulate_asset` result under the same edits:
    the rollout is re-run substep by substep (`internal_impulses`, with the n_t the rollout used)
    to sum its spring forces; masses from the asset's spring model, gravity and ground as edited."""

    if pred.velocities is None or not pred.n_substeps:
        raise ValueError("the prediction has no anchor velocities or substeps (simulate_asset's rollouts have them)")
    model, _ = asset.build()
    values, point, _ = edited_values(asset, sim_cfg)
    physics = replace(asset.physics, max_substeps=max(asset.physics.max_substeps, pred.n_substeps))
    params = physical_params(model, physics, values)
    ground = Ground(point, asset.ground_normal)
    n_frames = pred.velocities.shape[0]
    internal = internal_impulses(model, params, ground, n_frames, 1.0 / asset.fps, pred.n_substeps, physics)
    verdict = momentum_check(
        pred.velocities,
        to_numpy(model.particle_mass),
        internal,
        np.asarray(values.get("gravity", (0.0, 0.0, -9.8)), float),
        asset.ground_normal,
        1.0 / asset.fps,
        physics.springs,
        float(sim_cfg.momentum_tolerance),
    )
    return {**verdict, "n_substeps": int(pred.n_substeps)}
