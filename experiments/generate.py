"""Generate benchmark sequences (MPM drop + Mitsuba ground truth) into sgdr's sequence format.

    python experiments/generate.py synth.object=torus preset=small seed=0
    python experiments/generate.py synth.object=all preset=small          # the eight objects (docs/benchmark-objects.md)
    python experiments/generate.py synth.object=apple synth.effects.plastic_yield=1500 \
        synth.out=data/apple_plastic

Each sequence goes to `synth.out` (default `<data_dir>/<object>`); complete sequences are
skipped unless `synth.overwrite=true`.
"""

from __future__ import annotations

import logging
import sys
from pathlib import Path

import hydra
from omegaconf import OmegaConf

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from dataclasses import replace

from tqdm import tqdm

import sgdr.backend  # noqa: E402
import sgdr.config  # noqa: E402
from sgdr.checks import ConfigError
from sgdr.cli import user_errors
from sgdr.config import validate
from sgdr.synth.generate import generate_sequence, is_complete
from sgdr.synth.objects import OBJECTS

sgdr.config.register()
log = logging.getLogger("generate")


@hydra.main(config_path="../conf", config_name="config", version_base="1.3")
def main(cfg) -> None:
    with user_errors():
        validate(OmegaConf.to_object(cfg))
        sgdr.backend.init(cfg.backend, cfg.threads or None)
        _generate(cfg)


def _generate(cfg) -> None:
    synth = OmegaConf.to_object(cfg.synth)
    names = list(OBJECTS) if synth.object == "all" else [synth.object]
    if synth.out and len(names) > 1:
        raise ConfigError("synth.out names one sequence folder; leave it empty with synth.object=all")
    bar = tqdm(names, desc="benchmark", unit="object", disable=len(names) == 1)
    for name in bar:
        one = replace(synth, object=name)
        out = Path(synth.out) if synth.out else Path(cfg.data_dir) / name
        if not synth.overwrite and is_complete(out, one):
            log.info("%s: complete, skipped (synth.overwrite=true regenerates)", out)
            continue
        bar.set_postfix_str(name)
        generate_sequence(one, out, cfg.seed, progress=True)
        log.info("%s: written", out)


if __name__ == "__main__":
    main()
