"""PAC-NeRF candidate rollouts: `python -m evaluation.bench pacnerf` (or `make bench BENCH=pacnerf`).

What the PAC-NeRF baseline's E, ν search pays per round (docs/baselines.md): MLS-MPM rollouts
of S candidates of one object. The object: the benchmark torus's volume (`placed_sdf`, no
rendering) filled at the small preset's spacing (16 MPM cells across the object, 2 particles
per cell and axis), dropped onto a sticky ground 0.02 below it at v0 = (0.15, 0.05, -0.5),
N_FRAMES frames at 24 fps, a fixed number of substeps (the CFL bound of the stiffest candidate
the range allows, E = 10^4.5 Pa, ν = 0.4). For S = 1, 5, 15 (15 = the small preset's 5 x 3 grid) on the active
Dr.Jit backend it measures
- `sgdr.baselines.pacnerf.rollout` of the S candidates in one batched program (each on its own
  grid block);
- the same S candidates as S single rollouts, one after the other, in the same run;
and reports candidate rollouts per second of each and the speed-up (single time / batched
time), after a warm-up call each (tracing), median over REPS calls, batched and single calls
interleaved. The largest difference between a batched candidate and its single rollout is
reported too (`max_abs_diff`, scene units).
"""

from __future__ import annotations

import statistics
import sys
import time

import numpy as np

import sgdr.backend as backend

# Dr.Jit and the sgdr modules that import it: inside the functions, after `sgdr.backend.init`
# (evaluation/bench/__init__.py says why).

N_FRAMES, FPS, SIZES, REPS = 4, 24.0, (1, 5, 15), 2
LOG10_E, NU = (3.0, 4.5), (0.05, 0.4)  # the candidates' range (its stiffest sets the substeps)


def _scene():
    backend.current()  # the LLVM backend unless a driver chose one
    from sgdr.baselines import pacnerf as pn
    from sgdr.baselines.config import PacNerfConfig
    from sgdr.synth.objects import placed_sdf

    sdf = placed_sdf("torus")
    g = np.linspace(0.25, 0.75, 201)
    probe = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
    inside = probe[sdf(probe) < 0]
    extent = float((inside.max(0) - inside.min(0)).max())
    spacing = extent / 16 / 2
    axes = [np.arange(inside[:, a].min(), inside[:, a].max(), spacing) for a in range(3)]
    lattice = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    particles = lattice[sdf(lattice) < 0]
    ground = (0.5, 0.5, float(particles[:, 2].min()) - 0.02)
    scene = pn.plan_scene(particles, spacing, (0.15, 0.05, -0.5), (0, 0, -9.8), ground, (0, 0, 1), 1 / FPS, N_FRAMES)
    cfg = PacNerfConfig()
    cfg.substeps = pn.substeps_for(scene, cfg, 10 ** LOG10_E[1], NU[1], N_FRAMES)
    return pn, scene, cfg


def run() -> dict:
    pn, scene, cfg = _scene()
    rng = np.random.default_rng(0)
    out = {
        "particles": len(scene.particles),
        "mpm_grid": scene.n_grid,
        "substeps_per_frame": cfg.substeps,
        "frames": N_FRAMES,
        "reps": REPS,
    }
    for S in SIZES:
        E = 10 ** rng.uniform(*LOG10_E, S)
        nu = rng.uniform(*NU, S)
        print(f"pacnerf bench: S = {S}", file=sys.stderr, flush=True)
        pn.rollout(scene, cfg, E, nu, 2)  # warm-up: tracing of both programs
        pn.rollout(scene, cfg, E[:1], nu[:1], 2)
        t_batch, t_single, diff = [], [], 0.0
        for _ in range(REPS):
            t0 = time.perf_counter()
            batch = pn.rollout(scene, cfg, E, nu, N_FRAMES)
            t_batch.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            singles = [pn.rollout(scene, cfg, E[s : s + 1], nu[s : s + 1], N_FRAMES)[0] for s in range(S)]
            t_single.append(time.perf_counter() - t0)
            diff = max(diff, float(np.abs(batch - np.stack(singles)).max()))
        tb, ts = statistics.median(t_batch), statistics.median(t_single)
        out[f"S{S}"] = {
            "batched_s": tb,
            "single_s": ts,
            "batched_rollouts_per_s": S / tb,
            "single_rollouts_per_s": S / ts,
            "speedup": ts / tb,
            "batched_s_each": t_batch,
            "single_s_each": t_single,
            "max_abs_diff": diff,
        }
    return out
