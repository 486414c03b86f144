"""Which of the global search's candidates the asset should start from: a study on finished runs.

    python -m evaluation.studies.search_choice outputs/torus_small_s0 outputs/cross_small_s0 ...

For each run folder whose dynamic stage searched (dynamics.json `search`), the candidates that fit
within `--tolerance` (relative) of the best loss (at most `--top-k`, best first) are rolled out
from frame 0 to the sequence's last frame with the asset's physics (the batched integrator), their
Gaussian centres bound by the asset's binding, and each one's future Chamfer distance (x1e3, the
evaluation's own `chamfer_distance`, frames n_fit .. n_frames-1) scored against the sequence's
ground-truth particles. Printed per run: every such candidate's values, fit loss and future CD,
and which one `recon.search.choose` = best / medoid would pick (the medoid: least summed mean
distance of the centres of mass to the others' after the fit window, as `Landscape`). One JSON
object per run on stdout with `--json`.

The per-anchor field is the candidate's uniform level (the local stage is not redone), so for a
run whose prior choice kept the field this scores the start of its local stage, not its asset.
The truth is never used to choose: this only measures the rules.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

import sgdr.backend as backend

# Dr.Jit and the sgdr modules that import it: inside the functions, after `main` calls
# `sgdr.backend.init` (Dr.Jit reads DRJIT_LIBLLVM_PATH, which init sets, when it is first imported).


def study(run: Path, tolerance: float, top_k: int) -> dict:
    from sgdr.asset.predict import physical_params
    from sgdr.asset.store import load_asset
    from sgdr.data import load_sequence
    from sgdr.evaluate.geometry import chamfer_distance
    from sgdr.physics import Ground
    from sgdr.physics.batched import batched_centres, batched_rollout

    dyn = json.loads((run / "dynamics" / "dynamics.json").read_text())
    search = dyn.get("search") or {}
    if not search:
        raise SystemExit(f"{run}: dynamics.json has no global search (recon.search.parameters was empty)")
    seq_dir = json.loads((run / "RUN.json").read_text())["sequence"]
    seq = load_sequence(seq_dir)
    asset = load_asset(run / "asset")
    model, binding = asset.build()
    names = list(search["names"])
    cand = np.asarray(search["candidates"], float)
    loss = np.asarray(search["losses"], float)
    keep = [i for i in range(loss.size) if loss[i] <= loss[0] * (1.0 + tolerance)][:top_k]
    level0 = float(np.mean(asset.values["log10_k"]))
    base = physical_params(model, asset.physics, asset.values)
    samples = {}
    for j, n in enumerate(names):
        samples["dlog10_k" if n == "log10_k" else n] = cand[keep, j] - (level0 if n == "log10_k" else 0.0)
    if "log10_k" in names:  # a uniform level: flatten the asset's field first
        base = physical_params(model, asset.physics, {**asset.values, "log10_k": np.full(len(asset.anchors), level0)})
    ground = Ground(asset.ground_point, asset.ground_normal)
    roll = batched_rollout(
        model, base, samples, ground, asset.n_frames, 1.0 / asset.fps, asset.n_substeps, asset.physics
    )
    centres = batched_centres(binding, roll.positions)  # [K, T, M, 3]
    future = range(asset.n_fit, asset.n_frames)
    cds = [
        float(np.mean([chamfer_distance(centres[k, f], seq.gt_particles(f)) for f in future]))
        if roll.stable[k]
        else float("nan")
        for k in range(len(keep))
    ]
    com = centres[:, asset.n_fit :].mean(axis=2)  # [K, T_future, 3]
    d = np.linalg.norm(com[:, None] - com[None, :], axis=-1).mean(axis=-1)  # [K, K]
    medoid = int(np.argmin(d.sum(axis=1)))
    return {
        "run": str(run),
        "names": names,
        "candidates": cand[keep].tolist(),
        "losses": loss[keep].tolist(),
        "future_cd": cds,
        "best": 0,
        "medoid": medoid,
        "future_cd_best": cds[0],
        "future_cd_medoid": cds[medoid],
        "future_cd_run": json.loads((run / "metrics.json").read_text()).get("future_cd"),
    }


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("runs", nargs="+", type=Path)
    ap.add_argument(
        "--tolerance", type=float, default=0.05, help="relative fit-loss tolerance (recon.search.equivalent_tolerance)"
    )
    ap.add_argument("--top-k", type=int, default=8, help="at most this many candidates (recon.search.top_k)")
    ap.add_argument("--json", action="store_true", help="one JSON object per run on stdout")
    ap.add_argument("--threads", type=int, default=0, help="Dr.Jit threads (0: every core)")
    a = ap.parse_args(argv)
    backend.init("llvm", threads=a.threads or None)
    for run in a.runs:
        r = study(run, a.tolerance, a.top_k)
        if a.json:
            print(json.dumps(r), flush=True)
            continue
        print(f"{run}: {len(r['losses'])} candidates within {a.tolerance:g} of the best fit loss")
        for k, (c, loss, cd) in enumerate(zip(r["candidates"], r["losses"], r["future_cd"])):
            mark = " <- best" if k == r["best"] else ""
            mark += " <- medoid" if k == r["medoid"] else ""
            values = ", ".join(f"{n} {v:.3f}" for n, v in zip(r["names"], c))
            print(f"  {k}: {values}; fit loss {loss:.5f}; future CD {cd:.3f}{mark}")
        print(
            f"  best {r['future_cd_best']:.3f}, medoid {r['future_cd_medoid']:.3f}; the run's asset {r['future_cd_run']}"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
