"""Simulate a reconstructed asset under new conditions and render videos (Figs. 6-7).

    python experiments/simulate.py recon.simulate.asset=outputs/torus_small_s0/asset \
        recon.simulate.stiffness_scale=0.1 recon.simulate.n_frames=60 recon.simulate.cameras=orbit

Edits (all under `recon.simulate`, see sgdr/identify/config.py `SimulateConfig`): ground_height,
friction, restitution (physics.contact=coulomb assets only), gravity=[gx,gy,gz], stiffness_scale,
v0=[vx,vy,vz], n_frames, n_substeps, max_substeps; cameras=sequence|orbit. The rollout uses the
asset's physics settings (physics.* of the command line do not act).

Each simulation gets its own folder, `<asset>/../simulate/<tag>` with the tag named after the
edits (e.g. `friction-0_stiffness_scale-0.1`), a new `<tag>-2`, ... when that folder holds
another simulation; an explicit recon.simulate.tag / out_dir holding another simulation is
refused unless recon.simulate.overwrite=true (`sgdr.asset.whatif.simulation_dir`). It holds
`video.mp4` (all views tiled, or the orbit, over the ground plane), `trajectory.npz` (anchors, centres, velocities)
and `simulate.json` (asset, edits, substeps used, momentum check).

The momentum check (`sgdr.asset.momentum`): the springs' own impulse summed over every
substep; if it moves the centre of mass by more than recon.simulate.momentum_tolerance (the
directed springs, physics.springs=directed, do not conserve momentum) a warning is printed and
written to simulate.json. The last line printed is one JSON object: the folder, frames,
cameras, substeps and the momentum verdict.
"""

from __future__ import annotations

import json
import logging
import sys
from pathlib import Path

import hydra
import numpy as np
from omegaconf import DictConfig, OmegaConf

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import sgdr.backend  # noqa: E402
import sgdr.config  # noqa: E402
from sgdr.asset.store import load_asset
from sgdr.asset.whatif import edited_values, simulate_asset, simulation_dir, simulation_momentum, simulation_record
from sgdr.cli import user_errors
from sgdr.config import validate
from sgdr.report.media import composite_ground, tile, write_video
from sgdr.run_folder import default_run_name

sgdr.config.register()


@hydra.main(config_path="../conf", config_name="config", version_base="1.3")
def main(cfg: DictConfig) -> None:
    """A bad value, a missing asset, a taken output folder or an unstable edit ends with one
    line `error: ...` naming the key or file (exit 2); anything else keeps its traceback."""

    with user_errors():
        try:
            simulate(cfg)
        except (FileNotFoundError, FileExistsError, RuntimeError) as exc:
            from sgdr.physics import SimulationUnstable

            if not isinstance(exc, (FileNotFoundError, FileExistsError, SimulationUnstable)):
                raise
            print(f"error: {exc}", file=sys.stderr, flush=True)
            sys.exit(2)


def simulate(cfg: DictConfig) -> None:
    sgdr.backend.init(cfg.backend, cfg.threads or None)

    logging.getLogger("sgdr").setLevel(logging.INFO)
    c = OmegaConf.to_object(cfg)
    validate(c)  # every config value, recon.simulate.* included, before any work
    sim = c.recon.simulate
    asset_dir = Path(sim.asset) if sim.asset else Path(c.recon.output_dir) / default_run_name(c) / "asset"
    asset = load_asset(asset_dir)
    out = simulation_dir(asset_dir, sim)  # refuses, before simulating, to overwrite another simulation
    pred, cams = simulate_asset(asset, sim, c.render, progress=True)
    momentum = simulation_momentum(asset, sim, pred)
    if momentum["warning"]:
        logging.getLogger("sgdr.simulate").warning(momentum["warning"])
    out.mkdir(parents=True, exist_ok=True)
    ground = edited_values(asset, sim)[1]  # the simulated ground plane, drawn behind the object
    view_cam = (lambda f, v: cams[f]) if sim.cameras == "orbit" else (lambda f, v: cams[v])
    frames = [
        tile(
            [
                composite_ground(im[..., :3], im[..., 3], view_cam(f, v), ground, asset.ground_normal)
                for v, im in enumerate(views)
            ]
        )
        for f, views in enumerate(pred.images)
    ]
    video = write_video(out / "video.mp4", frames, asset.fps)
    np.savez(out / "trajectory.npz", anchors=pred.anchors, centres=pred.centres, velocities=pred.velocities)
    record = simulation_record(sim, asset_dir, n_substeps_used=pred.n_substeps, momentum=momentum)
    (out / "simulate.json").write_text(json.dumps(record, indent=1))
    print(f"video: {video}\ntrajectory: {out / 'trajectory.npz'}")
    summary = {
        "simulate": str(out),
        "frames": int(pred.centres.shape[0]),
        "cameras": sim.cameras,
        "n_substeps": pred.n_substeps,
        "gains_momentum": momentum["gains_momentum"],
        "momentum_warning": momentum["warning"],
    }
    print(json.dumps(summary))


if __name__ == "__main__":
    main()
