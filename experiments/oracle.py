"""Fit the spring-mass model to a generated sequence's ground-truth particle tracks: how far
identification could go if rendering, static fit and v0 were perfect (`evaluation.studies.oracle`).

    python experiments/oracle.py preset=small synth.object=torus

Uses the same sequence as `experiments/reconstruct.py` (generated when missing), the preset's
N_A, n_k and physics, and the dynamic stage's learning rates. Writes `oracle.json`,
`oracle.png`, `log10_k.npy` and `tracks.npz` (simulated and true anchor tracks [T, N_A, 3]) to
`<recon.output_dir>/<run name>_oracle/`; the last line printed is one JSON object with the
oracle's fit / future scores beside the physics-free baseline's. The config is sgdr's plus the
`oracle` section (`evaluation.studies.config.StudyConfig`).
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
from evaluation.studies import config as study_config  # noqa: E402
from evaluation.studies.oracle import oracle_study, plot_oracle  # noqa: E402
from sgdr.cli import user_errors  # noqa: E402
from sgdr.data import load_sequence  # noqa: E402
from sgdr.run_folder import default_run_name, ensure_sequence  # noqa: E402

study_config.register()  # sgdr's schema with the `oracle` section (sgdr.config.register's, extended)


@hydra.main(config_path="../conf", config_name="config", version_base="1.3")
def main(cfg: DictConfig) -> None:
    with user_errors():
        sgdr.backend.init(cfg.backend, cfg.threads or None)
        logging.getLogger("sgdr").setLevel(logging.INFO)
        c = OmegaConf.to_object(cfg)
        study_config.validate(c)
        seq = load_sequence(ensure_sequence(c))
        result = oracle_study(
            seq, c.anchors.n_anchors, c.anchors.n_k, c.physics, c.recon, c.oracle, seed=c.seed, progress=True
        )
        out = Path(c.recon.output_dir) / f"{default_run_name(c)}_oracle"
        out.mkdir(parents=True, exist_ok=True)
        summary = {"sequence": str(seq.root), "contact": c.physics.contact, **result.summary()}
        record = {
            **summary,
            "track_error": result.track_error.tolist(),
            "cd": result.cd.tolist(),
            "baseline_cd": {k: v.tolist() for k, v in result.baseline_cd.items()},
            "baseline_track_error": {k: v.tolist() for k, v in result.baseline_track_error.items()},
            "losses": result.losses,
            "k_offset_scan": result.scan,
            "ensemble": result.ensemble,
            "config": OmegaConf.to_container(cfg, resolve=True),
        }
        (out / "oracle.json").write_text(json.dumps(record, indent=1))
        np.save(out / "log10_k.npy", result.values["log10_k"])
        np.savez_compressed(
            out / "tracks.npz",
            simulated=result.simulated.astype(np.float32),
            tracks=result.tracks.astype(np.float32),
            anchor_index=result.anchor_index,
        )
        plot_oracle(result, out / "oracle.png", title=f"{seq.root.name}: spring-mass fitted to the particle tracks")
        for row in result.scan:
            print(
                f"log10 k {row['offset']:+.3f}: fit track error {row['fit_track_error']:.4f}, "
                f"future {row['future_track_error']:.4f}"
            )
        print(f"oracle: {out / 'oracle.json'}, {out / 'oracle.png'}")
        print(json.dumps({k: v for k, v in summary.items() if not isinstance(v, dict)}))


if __name__ == "__main__":
    main()
