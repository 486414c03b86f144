"""Simulate a reconstructed asset under new conditions and render videos (Figs. 6-7).

    python experiments/simulate.py recon.simulate.asset=outputs/torus_small_s0/asset \
        recon.simulate.stiffness_scale=0.1 recon.simulate.n_frames=60 recon.simulate.cameras=orbit

Edits (all under `recon.simulate`): ground_height, friction, gravity=[gx,gy,gz],
stiffness_scale, v0=[vx,vy,vz], n_frames, n_substeps; cameras=sequence|orbit. Writes
`video.mp4` (all views tiled, or the orbit, over the ground plane) and `trajectory.npz` (anchors, centres).
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

sgdr.config.register()


@hydra.main(config_path="../conf", config_name="config", version_base="1.3")
def main(cfg: DictConfig) -> None:
    sgdr.backend.init(cfg.backend, cfg.threads or None)
    from sgdr.pipeline.asset import edited_values, load_asset, simulate_asset
    from sgdr.pipeline.report import composite_ground, tile, write_video
    from sgdr.pipeline.run import default_run_name

    logging.getLogger("sgdr").setLevel(logging.INFO)
    c = OmegaConf.to_object(cfg)
    sim = c.recon.simulate
    asset_dir = Path(sim.asset) if sim.asset else Path(c.recon.output_dir) / default_run_name(c) / "asset"
    asset = load_asset(asset_dir)
    pred, cams = simulate_asset(asset, sim, c.render, progress=True)
    out = Path(sim.out_dir) if sim.out_dir else asset_dir.parent / "simulate" / sim.tag
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
    np.savez(out / "trajectory.npz", anchors=pred.anchors, centres=pred.centres)
    (out / "simulate.json").write_text(json.dumps(OmegaConf.to_container(cfg.recon.simulate), indent=1))
    print(f"video: {video}\ntrajectory: {out / 'trajectory.npz'}")
    print(json.dumps({"simulate": str(out), "frames": int(pred.centres.shape[0]), "cameras": sim.cameras}))


if __name__ == "__main__":
    main()
