"""The Table 2 baselines (simplified Dy-Gaus, simplified 4D-Gaus) on their twins, with variants.

    python -m evaluation.studies.baseline_twins            # every variant, ~3 min on 2 cores
    python -m evaluation.studies.baseline_twins dyngaus    # one baseline's variants

Prints one JSON line per variant: the twin, the changed settings, the mean centre error over the
mean motion since frame 0 per moving frame (`sgdr.baselines.known_motion.Twin.error_ratio`), the last
image loss and the wall time. The sizes are the tests' (tests/test_baselines_dynrecon.py); the
method is the schema's default (conf/method) unless the variant changes it. docs/baselines.md
holds the measured numbers.
"""

from __future__ import annotations

import json
import sys
import time
from dataclasses import replace

import sgdr.backend as backend
from sgdr.baselines.config import Deform4DConfig, DynGausConfig

# Dr.Jit and the sgdr modules that import it: inside `main`, after its `sgdr.backend.init`
# (Dr.Jit reads DRJIT_LIBLLVM_PATH, which init sets, when it is first imported).


def variants():
    """(baseline, twin, label, config) of every measured variant."""
    dyn = DynGausConfig(iterations=80, n_neighbours=8)
    d4 = Deform4DConfig(iterations=30, warmup_iterations=40, grid_resolution=6)
    return [
        ("dyngaus", "rigid", "default", dyn),
        ("dyngaus", "rigid", "priors x10 (Luiten et al.'s 4:4:2)", replace(dyn, w_rigid=4.0, w_rot=4.0, w_iso=2.0)),
        ("dyngaus", "rigid", "no rotations", replace(dyn, rotations=False)),
        ("dyngaus", "rigid", "no extrapolation", replace(dyn, extrapolate=False)),
        ("dyngaus", "rigid", "no priors", replace(dyn, w_rigid=0.0, w_rot=0.0, w_iso=0.0)),
        ("deform4d", "twist", "default", d4),
        ("deform4d", "twist", "tv l1", replace(d4, tv="l1")),
        ("deform4d", "twist", "no regularisers", replace(d4, w_tv=0.0, w_time=0.0)),
        ("deform4d", "twist", "init zero (70 joint steps: as many renders)", replace(d4, init="zero", iterations=70)),
    ]


def main(argv: list[str]) -> None:
    backend.init("llvm")
    from sgdr.baselines.deform4d import fit_deformation
    from sgdr.baselines.dyngaus import track_gaussians
    from sgdr.baselines.known_motion import known_motion_cube

    fits = {"dyngaus": track_gaussians, "deform4d": fit_deformation}
    twins = {}
    for baseline, twin_name, label, cfg in variants():
        if argv and baseline not in argv:
            continue
        twin = twins.setdefault(twin_name, known_motion_cube(twin_name))
        start = time.perf_counter()
        res = fits[baseline](twin.gaussians, twin.targets, twin.cameras, twin.render_cfg, cfg, seed=0)
        seconds = time.perf_counter() - start
        line = {
            "baseline": baseline,
            "twin": twin_name,
            "variant": label,
            "error_over_motion": [round(float(r), 4) for r in twin.error_ratio(res.centres)],
            "last_image_loss": round(float(res.image_losses[-1]), 5),
            "seconds": round(seconds, 1),
        }
        print(json.dumps(line), flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
