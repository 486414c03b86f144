"""The asset on disk: `Asset` (Gaussians, anchors, binding, identified physics, cameras and ground
of a finished run) and `save_asset` / `load_asset` of its folder `<run>/asset/`."""

from __future__ import annotations

import json
import logging
from dataclasses import asdict, dataclass, fields, is_dataclass
from pathlib import Path

import numpy as np
from omegaconf import DictConfig, OmegaConf

from sgdr.anchors.config import AnchorConfig
from sgdr.cameras import Camera
from sgdr.gaussians.ply import load_ply, save_ply
from sgdr.physics import build_spring_model
from sgdr.physics.config import PhysicsConfig
from sgdr.skin import IDWBinding

log = logging.getLogger(__name__)


def _plain(x):
    if is_dataclass(x) and not isinstance(x, type):
        return asdict(x)

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

    root = Path(path)
    meta_file = root / "asset.json"
    if not meta_file.exists():
        if (root / "pacnerf.json").is_file():
            raise FileNotFoundError(
                f"{root} is the PAC-NeRF baseline's MPM object (pacnerf.json), not a spring-mass asset: "
                "experiments/simulate.py simulates spring-mass assets only"
            )
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
