"""Batched-rollout benchmark: `python -m evaluation.bench posterior` (or `make bench BENCH=posterior`).

What a posterior sampler pays per likelihood: forward rollouts of S parameter samples of one
asset. At the small preset (N_A = 512 anchors, n_k = 64 springs each, n_t = 100 substeps,
30 frames at 24 fps; directed springs, official law, project contact: the default physics)
it measures, for S = 1, 8, 16, 32, on the active Dr.Jit backend (LLVM by default):
- `sgdr.physics.batched.batched_rollout` of the S samples in one S x N_A program;
- the same S samples as S single `sgdr.physics.rollout` calls, one after the other (no
  gradients, positions read back per frame as the batch does), in the same run;
and reports rollouts per second of each and the speed-up (single time / batched time). Both
are timed after a 2-frame warm-up call each (tracing + compilation, reported as
`*_warmup_2_frames_s`), median over REPS calls, the batched and the single calls interleaved
(the machine may be shared: a load change then hits both alike). A rollout is N_FRAMES frames,
frame 0 the rest state, so N_FRAMES - 1 simulated frames. Every call's time is reported
(`*_s_each`), and the speed-up of the fastest calls (`speedup_of_minima`) next to the one of
the medians: on a loaded machine the minima are the closer estimate of the unloaded cost. The asset: anchors sampled (farthest points) from points inside the benchmark
torus (`sgdr.synth.objects.placed_sdf`, no rendering), log10 k = 3 (physics.log10_k_init),
falling onto a ground 0.02 below it at v0 = (0.2, 0, -1); the samples perturb log10 k, κ, μ,
ζ0 and v0 around that (all within the stability bound). The largest difference between a
batched sample and its single rollout is reported too (`max_abs_diff`, scene units; the
torus is about 0.35 wide). `past_bound_S8`: the sampler's rollout contract on 8 samples, 2 of
them stiffer than n_t allows, "batched" (re-run batched with doubled n_t) against "loop".
"""

from __future__ import annotations

import os
import statistics
import sys
import time

import numpy as np

import sgdr.backend as backend

# Dr.Jit and the sgdr modules that import it: inside the functions, after `sgdr.backend.init`
# (evaluation/bench/__init__.py says why).

N_ANCHORS, N_K, N_SUB, N_FRAMES, FPS = 512, 64, 100, 30, 24.0
SIZES = (1, 8, 16, 32)  # issue 34 asks for S = 16
REPS = 3
SEED = 0


def _asset():
    backend.current()  # the LLVM backend unless a driver chose one
    from sgdr.anchors.sampling import sample_anchors
    from sgdr.physics import Ground, PhysicsConfig, PhysParams, build_spring_model
    from sgdr.synth.objects import placed_sdf

    rng = np.random.default_rng(SEED)
    sdf = placed_sdf("torus")
    points = rng.uniform(0.0, 1.0, (400_000, 3))
    points = points[sdf(points) < 0]
    anchors = sample_anchors(points, N_ANCHORS, "fps", 0.01, SEED)
    cfg = PhysicsConfig(n_substeps=N_SUB)
    model = build_spring_model(anchors, N_K, cfg)
    params = PhysParams.init(model, cfg, v0=(0.2, 0.0, -1.0))
    ground = Ground([0.0, 0.0, float(anchors[:, 2].min()) - 0.02], [0.0, 0.0, 1.0])
    return cfg, model, params, ground


def _samples(n: int, rng: np.random.Generator) -> dict:
    return {
        "dlog10_k": rng.uniform(-0.2, 0.2, n),
        "kappa": rng.uniform(-1.0, 1.0, n),
        "friction": rng.uniform(0.5, 1.0, n),
        "zeta0": rng.uniform(0.05, 0.2, n),
        "v0": np.array([0.2, 0.0, -1.0]) + rng.normal(0.0, 0.2, (n, 3)),
    }


def _singles(cfg, model, params, ground, samples: dict, n_frames: int = N_FRAMES) -> np.ndarray:
    """The S samples as S single rollouts: positions [S, T, N_A, 3]."""
    import drjit as dr

    from sgdr.arrays import to_numpy
    from sgdr.physics import SimState, rollout

    t = backend.ad()
    out = []
    base_k = to_numpy(params.log10_k, np.float32)
    with dr.suspend_grad():
        for s in range(len(samples["kappa"])):
            p = params.detach()
            p.log10_k = t.Float(base_k + np.float32(samples["dlog10_k"][s]))
            for name in ("kappa", "friction", "zeta0"):
                setattr(p, name, t.Float(float(samples[name][s])))
            p.v0 = t.Array3f(*map(float, samples["v0"][s]))
            dr.make_opaque(p)
            states = rollout(model, p, SimState.at_rest(model, p.v0), ground, n_frames, 1 / FPS, cfg, n_substeps=N_SUB)
            out.append(np.stack([st.numpy()[0] for st in states]))
    return np.stack(out)


def _timed_pair(batched, singles) -> tuple[list[float], list[float], object, object]:
    """REPS timed calls of each, interleaved (batched, singles, batched, ...) so that a change
    in the load of a shared machine hits both alike: (batched s, singles s, last results)."""
    tb, ts = [], []
    for _ in range(REPS):
        t0 = time.perf_counter()
        batch = batched()
        tb.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        single = singles()
        ts.append(time.perf_counter() - t0)
    return tb, ts, batch, single


def _past_bound(cfg, model, params, ground, rng, log) -> dict:
    """The sampler's rollout contract (`sgdr.posterior.rollouts.ROLLOUTS`) on S = 8 samples of
    which 2 are stiffer than n_t's stability bound allows (about 1.5 n_t needed): "batched"
    runs the 8, then re-runs the 2 batched with 2 n_t; "loop" runs 8 single rollouts, the 2
    with 2 n_t (the reference). Same timing as above (warm-up call each, then REPS interleaved)."""
    from sgdr.arrays import to_numpy
    from sgdr.physics.simulate import stable_substeps
    from sgdr.posterior.rollouts import ROLLOUTS

    need0 = stable_substeps(model, params, 1 / FPS, cfg)
    base = {
        "log10_k": to_numpy(params.log10_k).astype(float),
        "kappa": float(to_numpy(params.kappa).reshape(-1)[0]),
        "friction": float(to_numpy(params.friction).reshape(-1)[0]),
        "restitution": float(to_numpy(params.restitution).reshape(-1)[0]),
        "v0": to_numpy(params.v0).reshape(-1)[:3].astype(float),
        "gravity": to_numpy(params.gravity).reshape(-1)[:3].astype(float),
    }
    shift = rng.uniform(-0.2, 0.2, 8)
    shift[[2, 5]] = 2 * np.log10(1.5 * N_SUB / need0)  # k x 10^shift: n_t's bound scales by 10^(shift/2)
    samples = {"log10_k_shift": shift, "kappa": np.zeros(8), "friction": rng.uniform(0.5, 1.0, 8)}
    args = (ground, N_FRAMES, 1 / FPS, N_SUB, cfg)
    for name in ("batched", "loop"):
        ROLLOUTS[name](model, base, samples, ground, 2, 1 / FPS, N_SUB, cfg)
    log("S = 8, 2 past the bound: the batched and the loop rollouts")
    b_times, s_times, (pb, sb), (pl, sl) = _timed_pair(
        lambda: ROLLOUTS["batched"](model, base, samples, *args), lambda: ROLLOUTS["loop"](model, base, samples, *args)
    )
    t_b, t_s = statistics.median(b_times), statistics.median(s_times)
    out = {
        "speedup": t_s / t_b,
        "speedup_of_minima": min(s_times) / min(b_times),
        "batched_s_each": b_times,
        "loop_s_each": s_times,
        "need_substeps_base": int(need0),
        "stable_batched": int(sb.sum()),
        "stable_loop": int(sl.sum()),
        "max_abs_diff": float(np.nanmax(np.abs(pb - pl))),
    }
    log(f"past the bound: {out}")
    return out


def run() -> dict:
    b = backend.current()
    from sgdr.physics.batched import batched_rollout

    log = lambda msg: print(f"[bench posterior] {msg}", file=sys.stderr, flush=True)  # noqa: E731
    cfg, model, params, ground = _asset()
    rng = np.random.default_rng(SEED)
    result: dict = {}
    for S in SIZES:
        samples = _samples(S, rng)
        # warm-up: 2 frames trace and compile every kernel of both (the kernels do not depend on S)
        t0 = time.perf_counter()
        batched_rollout(model, params, samples, ground, 2, 1 / FPS, N_SUB, cfg)
        b_first = time.perf_counter() - t0
        t0 = time.perf_counter()
        _singles(cfg, model, params, ground, {k: v[:1] for k, v in samples.items()}, n_frames=2)
        s_first = time.perf_counter() - t0
        log(f"S = {S}: batched and {S} single rollouts, {REPS} times each, interleaved")
        b_times, s_times, batch, single = _timed_pair(
            lambda samples=samples: batched_rollout(model, params, samples, ground, N_FRAMES, 1 / FPS, N_SUB, cfg),
            lambda samples=samples: _singles(cfg, model, params, ground, samples),
        )
        t_b, t_s = statistics.median(b_times), statistics.median(s_times)
        result[f"S{S}"] = {
            "batched_rollouts_per_s": S / t_b,
            "single_rollouts_per_s": S / t_s,
            "speedup": t_s / t_b,
            "speedup_of_minima": min(s_times) / min(b_times),
            "batched_s": t_b,
            "single_s": t_s,
            "batched_s_each": b_times,
            "single_s_each": s_times,
            "batched_warmup_2_frames_s": b_first,
            "single_warmup_2_frames_s": s_first,
            "n_stable": int(batch.stable.sum()),
            "max_abs_diff": float(np.max(np.abs(batch.positions - single))),
        }
        log(f"S = {S}: {result[f'S{S}']}")
    result["past_bound_S8"] = _past_bound(cfg, model, params, ground, rng, log)
    return {
        "speedup_S8": result["S8"]["speedup"],
        "past_bound_speedup_S8": result["past_bound_S8"]["speedup"],
        "speedup_S32": result["S32"]["speedup"],
        "batched_rollouts_per_s_S32": result["S32"]["batched_rollouts_per_s"],
        "single_rollouts_per_s": result["S1"]["single_rollouts_per_s"],
        **result,
        "n_anchors": N_ANCHORS,
        "n_k": N_K,
        "n_substeps": N_SUB,
        "n_frames": N_FRAMES,
        "fps": FPS,
        "reps": REPS,
        "backend": b.name,
        "threads": b.threads,
        "load_avg_1min": os.getloadavg()[0],
    }
