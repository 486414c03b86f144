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
from dataclasses import asdict, dataclass, fields, is_dataclass
from pathlib import Path

import numpy as np

from sgdr.cameras import Camera
from sgdr.registry import Registry

log = logging.getLogger(__name__)


def _plain(x):
    if is_dataclass(x) and not isinstance(x, type):
        return asdict(x)
    from omegaconf import DictConfig, OmegaConf

    if isinstance(x, DictConfig):
        return OmegaConf.to_container(x, resolve=True)
    return dict(x)


@dataclass
class Asset:
    root: Path
    gaussians: object  # Gaussians [M]
    anchors: np.ndarray  # [N_A, 3]
    rest_centres: np.ndarray  # [M, 3]
    values: dict  # log10_k [N_A], kappa, friction, restitution, v0 [3], gravity [3]
    physics: object  # PhysicsConfig
    anchor_cfg: object  # AnchorConfig
    ground_point: np.ndarray  # [3]
    ground_normal: np.ndarray  # [3] unit, up
    fps: float
    n_frames: int
    n_fit: int
    n_substeps: int
    cameras: list[Camera]

    def build(self):
        """(SpringModel, IDWBinding) rebuilt from the rest anchors and centres."""
        from sgdr.physics import build_spring_model
        from sgdr.skin import IDWBinding

        model = build_spring_model(self.anchors, self.anchor_cfg.n_k, self.physics)
        binding = IDWBinding.build(
            self.rest_centres, self.anchors, self.anchor_cfg.n_b, self.anchor_cfg.p_b, self.anchor_cfg.binding
        )
        return model, binding


def save_asset(
    out,
    gaussians,
    anchors,
    values: dict,
    physics_cfg,
    anchor_cfg,
    seq,
    n_substeps: int,
    rest_centres,
    ground_point=None,
) -> Path:
    """ground_point [3]: the anchors' contact plane as simulated (the sequence's ground raised by
    the pipeline's contact margin); None = the sequence's ground point."""
    from sgdr.gaussians.ply import save_ply

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    save_ply(out / "gaussians.ply", gaussians)
    np.save(out / "anchors.npy", np.asarray(anchors, np.float64))
    np.save(out / "rest_centres.npy", np.asarray(rest_centres, np.float64))
    np.savez(out / "params.npz", **{k: np.asarray(v, np.float64) for k, v in values.items()})
    meta = {
        "physics": _plain(physics_cfg),
        "anchors": _plain(anchor_cfg),
        "ground": {
            "point": np.asarray(seq.ground_point if ground_point is None else ground_point, float).tolist(),
            "normal": np.asarray(seq.ground_normal, float).tolist(),
        },
        "fps": float(seq.fps),
        "n_frames": int(seq.n_frames),
        "n_fit": int(seq.n_fit),
        "n_substeps": int(n_substeps),
        "cameras": [c.to_dict() for c in seq.cameras],
    }
    (out / "asset.json").write_text(json.dumps(meta, indent=1))
    return out


def load_asset(path) -> Asset:
    """Read an asset folder; raises naming the file and field on anything missing."""
    from sgdr.anchors.config import AnchorConfig
    from sgdr.gaussians.ply import load_ply
    from sgdr.physics.config import PhysicsConfig

    root = Path(path)
    meta_file = root / "asset.json"
    if not meta_file.exists():
        raise FileNotFoundError(f"{meta_file}: not an sgdr asset (asset.json missing)")
    meta = json.loads(meta_file.read_text())
    for key in ("physics", "anchors", "ground", "fps", "n_frames", "n_fit", "n_substeps", "cameras"):
        if key not in meta:
            raise ValueError(f"{meta_file}: field {key!r} is missing")
    with np.load(root / "params.npz", allow_pickle=False) as z:
        values = {k: (z[k] if z[k].ndim else float(z[k])) for k in z.files}
    anchors = np.load(root / "anchors.npy", allow_pickle=False)
    rest = np.load(root / "rest_centres.npy", allow_pickle=False)
    if values["log10_k"].shape != (anchors.shape[0],):
        raise ValueError(
            f"{root / 'params.npz'}: log10_k has {values['log10_k'].shape}, expected ({anchors.shape[0]},)"
        )
    return Asset(
        root=root,
        gaussians=load_ply(root / "gaussians.ply"),
        anchors=anchors,
        rest_centres=rest,
        values=values,
        physics=_known_fields(PhysicsConfig, meta["physics"], meta_file),
        anchor_cfg=_known_fields(AnchorConfig, meta["anchors"], meta_file),
        ground_point=np.asarray(meta["ground"]["point"], float),
        ground_normal=np.asarray(meta["ground"]["normal"], float),
        fps=float(meta["fps"]),
        n_frames=int(meta["n_frames"]),
        n_fit=int(meta["n_fit"]),
        n_substeps=int(meta["n_substeps"]),
        cameras=[Camera.from_dict(c, where=f"{meta_file} cameras[{i}]") for i, c in enumerate(meta["cameras"])],
    )


def _known_fields(schema, values: dict, where):
    """schema(**values) without the settings the schema no longer has (an asset written before
    a setting was removed, e.g. physics.grad_mode); each dropped one is logged."""
    known = {f.name for f in fields(schema)}
    dropped = sorted(set(values) - known)
    if dropped:
        log.warning("%s: ignoring settings that no longer exist: %s", where, dropped)
    return schema(**{k: v for k, v in values.items() if k in known})


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


def edited_values(asset: Asset, sim_cfg) -> tuple[dict, np.ndarray, float]:
    """(parameter values, ground point, friction) after the edits of `SimulateConfig`."""
    values = dict(asset.values)
    values["log10_k"] = np.asarray(values["log10_k"], float) + math.log10(float(sim_cfg.stiffness_scale))
    if sim_cfg.friction >= 0:
        values["friction"] = float(sim_cfg.friction)
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
    asset reached in training; an unstable rollout says so.
    """
    from sgdr.physics import Ground, SimulationUnstable
    from sgdr.pipeline.predict import physical_params

    render_with = SIMULATE_CAMERAS.get_named(sim_cfg.cameras)
    model, binding = asset.build()
    values, point, _ = edited_values(asset, sim_cfg)
    ground = Ground(point, asset.ground_normal)
    params = physical_params(model, asset.physics, values)
    n_frames = int(sim_cfg.n_frames) or asset.n_frames
    n_t = int(sim_cfg.n_substeps) or asset.n_substeps
    try:
        return render_with(asset, model, params, binding, ground, n_frames, n_t, render_cfg, progress)
    except SimulationUnstable as exc:
        raise SimulationUnstable(
            f"simulating the asset with n_t={n_t}: {exc}. Here n_t is recon.simulate.n_substeps (0 = the asset's "
            f"{asset.n_substeps}): raise recon.simulate.n_substeps, not physics.n_substeps"
        ) from exc


# How `simulate_asset` renders (recon.simulate.cameras): (asset, model, params, binding, ground,
# n_frames, n_t, render_cfg, progress) -> (Prediction, cameras).
SIMULATE_CAMERAS = Registry("simulate camera set", "recon.simulate.cameras", ValueError)


@SIMULATE_CAMERAS.register("sequence")
def simulate_sequence_cameras(asset, model, params, binding, ground, n_frames, n_t, render_cfg, progress):
    """Every sequence camera renders every frame."""
    from sgdr.pipeline.predict import predict

    return predict(
        model,
        params,
        binding,
        asset.gaussians,
        ground,
        n_frames,
        asset.fps,
        n_t,
        asset.physics,
        asset.cameras,
        render_cfg,
        True,
        progress,
    ), asset.cameras


@SIMULATE_CAMERAS.register("orbit")
def simulate_orbit_cameras(asset, model, params, binding, ground, n_frames, n_t, render_cfg, progress):
    """Frame t from orbit camera t: one turn around the object over the clip."""
    from sgdr.arrays import points_to_array3
    from sgdr.identify.common import posed, render_rgba_numpy
    from sgdr.pipeline.predict import Prediction, predict

    traj = predict(
        model,
        params,
        binding,
        asset.gaussians,
        ground,
        n_frames,
        asset.fps,
        n_t,
        asset.physics,
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
    return Prediction(traj.anchors, traj.centres, np.stack(images)), cams
