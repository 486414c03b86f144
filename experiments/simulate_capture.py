"""Write a simulated real capture in the Spring-Gaus real-capture layout (sgdr.synth.capture).

    python experiments/simulate_capture.py preset=tiny out=/tmp/cap
    python experiments/simulate_capture.py preset=small out=data/realcap_torus realcap.object=torus seed=1

The capture's sizes are the preset's `realcap:` section (conf/preset/*.yaml); anything can be
overridden (`realcap.n_frames=20`, `realcap.video_width=320 realcap.video_height=240`). A
complete capture made with the same settings is skipped; one made with other settings is
replaced only with `realcap.overwrite=true`. The last line printed is one JSON object: the
folder, the object, the hit frame and the timings.
"""

from __future__ import annotations

import json
import logging
import sys
from dataclasses import dataclass
from pathlib import Path

import hydra
from hydra.core.config_store import ConfigStore
from omegaconf import OmegaConf

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import sgdr.backend  # noqa: E402
import sgdr.config  # noqa: E402
from sgdr.checks import ConfigError
from sgdr.cli import user_errors
from sgdr.config import validate


@dataclass
class SimulateCaptureConfig(sgdr.config.Config):
    out: str = ""  # the capture's folder (required)


# This driver's schema is sgdr's plus `out`: stored under the name conf/config.yaml composes.
sgdr.config.register()
ConfigStore.instance().store(name="config_schema", node=SimulateCaptureConfig)
log = logging.getLogger("simulate_capture")


@hydra.main(config_path="../conf", config_name="config", version_base="1.3")
def main(cfg) -> None:
    with user_errors():
        c = OmegaConf.to_object(cfg)
        validate(c)
        if not c.out:
            raise ConfigError("out='': the capture's folder is required, e.g. out=/tmp/cap")
        sgdr.backend.init(c.backend, c.threads or None)
        from sgdr.synth.capture import read_marker, simulate_real_capture

        logging.getLogger("sgdr").setLevel(logging.INFO)
        out = simulate_real_capture(c.out, c.realcap, c.seed, progress=True)
        truth = json.loads((out / "gt" / "truth.json").read_text())
        marker = read_marker(out) or {}
        print(
            json.dumps(
                {
                    "capture": str(out),
                    "object": truth["object"],
                    "n_frames": truth["n_frames"],
                    "hit_frame": truth["hit_frame"],
                    "timings": marker.get("timings"),
                }
            )
        )


if __name__ == "__main__":
    main()
