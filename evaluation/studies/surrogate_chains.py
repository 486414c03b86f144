"""Re-run a finished posterior's chains on its validated surrogate, longer, without new renders.

    python -m evaluation.studies.surrogate_chains outputs/torus_small_s0 [outputs/...] --steps 8000

The surrogate sampler (sgdr/posterior/surrogate.py) stores every true evaluation in
`<run>/posterior/samples.npz` (`evaluated`, `evaluated_log_like`). The round that passed the
check fitted its Gaussian process on the evaluations before that round's draws (the record's
`n_design`), with seed = the run's seed + the round's index: refitting on those reproduces it,
and new chains on it cost GP predictions only. Prints, per run, the convergence verdict of
`--steps`-long chains (the preset's walkers, ensembles, moves, space and criteria) beside the
run's own intervals, one JSON object per run with `--json`. Used when a run's chains were too
short for the 50 τ criterion while the surrogate itself had passed (docs/posterior.md).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
from omegaconf import OmegaConf


def rechain(run: Path, steps: int, preset: str, seed: int) -> dict:
    from sgdr.config import compose
    from sgdr.posterior.sample import Problem, diagnose, run_ensembles
    from sgdr.posterior.surrogate import GPSurrogate

    post = json.loads((run / "posterior" / "posterior.json").read_text())
    sur = (post.get("sampler") or {}).get("surrogate")
    if not sur:
        raise SystemExit(f"{run}: the posterior was not sampled with posterior.sampler=surrogate")
    if not sur["validated"]:
        return {"run": str(run), "validated": False}
    pc = OmegaConf.to_object(compose([f"preset={preset}"])).posterior
    names = post["names"]
    problem = Problem(
        names,
        np.array([post["priors"][n][0] for n in names]),
        np.array([post["priors"][n][1] for n in names]),
        np.array([post["map"][n] for n in names]),
    )
    last = sur["rounds"][-1]
    with np.load(run / "posterior" / "samples.npz") as z:
        thetas, log_like = z["evaluated"][: last["n_design"]], z["evaluated_log_like"][: last["n_design"]]
    surrogate = GPSurrogate(problem.low, problem.high, pc.surrogate.clip, seed + len(sur["rounds"]) - 1)
    surrogate.fit(thetas, log_like)
    chains, _, acc = run_ensembles(surrogate, problem, pc.n_walkers, steps, pc.n_ensembles, pc.init_ball, seed=seed,
                                   move=pc.moves, space=pc.space, independence=pc.surrogate.independence,
                                   pilot_steps=pc.surrogate.pilot_steps)  # fmt: skip
    d = diagnose(chains, names, pc, acc)
    d0 = post["diagnostics"]
    return {
        "run": str(run),
        "validated": True,
        "steps": int(steps),
        "converged": d["converged"],
        "failed": d["failed"],
        "tau_max": d["tau_max"],
        "rhat_max": max(d["rhat"].values()),
        "ess_min": min(min(d["ess_bulk"].values()), min(d["ess_tail"].values())),
        "interval": {n: [d["q05"][n], d["median"][n], d["q95"][n]] for n in names},
        "run_interval": {n: [d0["q05"][n], d0["median"][n], d0["q95"][n]] for n in names},
        "run_steps": d0["n_steps"],
    }


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("runs", nargs="+", type=Path)
    p.add_argument("--steps", type=int, default=8000)
    p.add_argument("--preset", default="small")
    p.add_argument("--seed", type=int, default=0, help="the runs' seed")
    p.add_argument("--json", action="store_true")
    args = p.parse_args(argv)
    for run in args.runs:
        res = rechain(run, args.steps, args.preset, args.seed)
        if args.json:
            print(json.dumps(res))
        elif not res["validated"]:
            print(f"{run}: the surrogate did not pass its check; nothing to re-chain")
        else:
            print(
                f"{run}: {res['steps']} steps: {'converged' if res['converged'] else 'NOT converged'}, max τ "
                f"{res['tau_max']:.1f}, max R-hat {res['rhat_max']:.4f}, min ESS {res['ess_min']:.0f}; "
                + "; ".join(f"{n} {v[1]:.3g} [{v[0]:.3g}, {v[2]:.3g}]" for n, v in res["interval"].items())
            )
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
