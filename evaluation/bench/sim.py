"""Simulator benchmark: `python -m evaluation.bench sim` (or `make bench BENCH=sim`).

Measures, on the active Dr.Jit backend (LLVM by default):
- forward spring-steps per second (anchors x springs x substeps / s) at paper scale
  (2048 x 256) and at 512 x 64: one frame of 100 substeps, after a warm-up call whose time
  (tracing + compilation, or kernel-cache load) is reported separately; median wall time of
  the timed calls, plus the kernels' own execution time from Dr.Jit's kernel history;
- one frame at 512 x 64 with spring plasticity over the elastic one (plastic_over_elastic_small);
- the gather-bound loop (`_gather_bound`): the forward's memory accesses with the least
  arithmetic, the roofline the forward is compared with (`fraction_of_gather_bound`);
- the float64 NumPy twin (sgdr/physics/reference.py) on the same systems in the same run,
  and the ratio;
- gradient cost over forward cost (default `physics.adjoint="gather"`, and `"recorded"` for
  comparison): a `full`-mode rollout (2 frames x 100 substeps) with AD
  recording plus `dr.backward` and the evaluation of the gradient, over the plain forward of the
  same rollout (after one warm-up of each, so kernel compilation is not counted); the same
  for 6 frames with the default adjoint, so a cost that grows faster than the frames shows;
- peak memory of a 20-frame x 100-substep `full` gradient at paper scale, measured in a fresh
  child process as its peak resident set size (`resource.getrusage(RUSAGE_SELF).ru_maxrss`),
  with the child's RSS before the rollout reported next to it.
"""

from __future__ import annotations

import json
import os
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

import sgdr.backend as backend

# Dr.Jit and the sgdr modules that import it: inside the functions, after `sgdr.backend.init`
# (evaluation/bench/__init__.py says why).

ROOT = Path(__file__).resolve().parents[2]  # the repository: the child process's working directory
FPS = 30.0
N_SUB = 100
SEED = 0


def _system(n_anchors: int, n_k: int, **cfg_overrides):
    backend.current()  # the LLVM backend unless a driver chose one
    from sgdr.physics import Ground, PhysicsConfig, PhysParams, SimState, build_spring_model

    rng = np.random.default_rng(SEED)
    x_rest = rng.uniform(0.3, 0.7, (n_anchors, 3))
    cfg = PhysicsConfig(**cfg_overrides)
    model = build_spring_model(x_rest, n_k, cfg)
    params = PhysParams.init(model, cfg, v0=(0.2, 0.0, -1.0))
    ground = Ground([0.0, 0.0, 0.28], [0.0, 0.0, 1.0])
    return cfg, model, params, SimState.at_rest(model, params.v0), ground


def _forward(n_anchors: int, n_k: int, reps: int, **cfg_overrides) -> dict:
    import drjit as dr

    from sgdr.physics import simulate_frame

    cfg, model, params, state, ground = _system(n_anchors, n_k, **cfg_overrides)
    t0 = time.perf_counter()
    simulate_frame(model, params, state, ground, 1 / FPS, N_SUB, cfg)  # warm-up: trace + compile
    first = time.perf_counter() - t0
    walls, kernels = [], []
    for _ in range(reps):
        dr.kernel_history_clear() if hasattr(dr, "kernel_history_clear") else dr.kernel_history()
        dr.set_flag(dr.JitFlag.KernelHistory, True)
        t0 = time.perf_counter()
        simulate_frame(model, params, state, ground, 1 / FPS, N_SUB, cfg)  # ends reading a result
        dr.sync_thread()
        walls.append(time.perf_counter() - t0)
        history = dr.kernel_history()
        dr.set_flag(dr.JitFlag.KernelHistory, False)
        kernels.append(sum(k.get("execution_time", 0.0) for k in history) / 1e3)  # ms -> s
    work = n_anchors * n_k * N_SUB
    wall, kernel = statistics.median(walls), statistics.median(kernels)
    return {
        "steps_per_s": work / wall,
        "kernel_steps_per_s": work / kernel,
        "first_call_s": first,
        "wall_s": wall,
        "kernel_s": kernel,
    }


def _gather_bound(n_anchors: int, n_k: int, reps: int) -> float:
    """Spring-steps per second of the least a substep must do: the same per-anchor sum loop over
    the same springs with the same memory accesses as the simulator's forward (gather j and l_ij
    at the spring, x_j and v_j at j: 8 floats gathered per spring) and the least arithmetic (a
    Hookean spring plus damping; no soft vector, no law, no contact), then the Euler update and
    one `dr.eval(x, v)`. Same system, same timing as `_forward`: the roofline of this machine for
    this loop, measured rather than estimated from the gather's instruction tables."""
    import drjit as dr

    from sgdr.backend import ad

    t = ad()
    cfg, model, params, state, ground = _system(n_anchors, n_k)
    k = dr.opaque(t.Float, 300.0)
    dt = dr.opaque(t.Float, 1.0 / (FPS * N_SUB))
    g = t.Array3f(0.0, 0.0, -9.8)
    base = dr.arange(t.UInt32, n_anchors) * n_k

    def forces(x, v):
        def body(r, f):
            s = base + r
            j = dr.gather(t.UInt32, model.spring_j, s)
            l = dr.gather(t.Float, model.spring_rest_length, s)
            xj, vj = dr.gather(t.Array3f, x, j), dr.gather(t.Array3f, v, j)
            d = x - xj
            inv = dr.rsqrt(dr.maximum(dr.squared_norm(d), 1e-12))
            return r + 1, f - (k * (dr.squared_norm(d) * inv - l) + 0.1 * dr.dot(v - vj, d) * inv) * inv * d

        _, f = dr.while_loop(
            state=(dr.zeros(t.UInt32, n_anchors), dr.zeros(t.Array3f, n_anchors)),
            cond=lambda r, f: r < n_k,
            body=body,
            max_iterations=-1,
        )
        return f

    def frame(x, v):
        for _ in range(N_SUB):
            v = v + dt * (forces(x, v) + g)
            x = x + dt * v
            dr.eval(x, v)
        dr.sync_thread()

    x0, v0 = dr.detach(state.x), dr.detach(state.v)
    frame(x0, v0)  # warm-up: trace + compile
    walls = []
    for _ in range(reps):
        t0 = time.perf_counter()
        frame(x0, v0)
        walls.append(time.perf_counter() - t0)
    return n_anchors * n_k * N_SUB / statistics.median(walls)


def _numpy_twin(n_anchors: int, n_k: int, n_steps: int) -> float:
    """Spring-steps per second of the float64 NumPy twin (median over single substeps)."""
    from sgdr.physics import reference as R

    cfg, model, params, state, ground = _system(n_anchors, n_k)
    m, p = R.model_numpy(model), R.params_numpy(params)
    x, v = state.numpy()
    dt = 1 / (FPS * N_SUB)
    times = []
    for _ in range(n_steps + 1):
        t0 = time.perf_counter()
        x, v = R.substep(m, p, x, v, ground, dt, cfg)
        times.append(time.perf_counter() - t0)
    return n_anchors * n_k / statistics.median(times[1:])


def _gradient_ratio(n_anchors: int, n_k: int, n_frames: int, adjoint: str) -> dict:
    import drjit as dr

    from sgdr.physics import SimState, rollout

    cfg, model, params, state, ground = _system(n_anchors, n_k, adjoint=adjoint)

    def run(grad: bool):
        p = params.detach()
        if grad:
            dr.enable_grad(p)
        t0 = time.perf_counter()
        states = rollout(
            model,
            p,
            SimState.at_rest(model, p.v0),
            ground,
            n_frames + 1,
            1 / FPS,
            cfg,
            grad_mode="full",
            n_substeps=N_SUB,
        )
        dr.sync_thread()
        t1 = time.perf_counter()
        if grad:
            loss = 0.0
            for s in states[1:]:
                loss = loss + dr.sum(dr.squared_norm(s.x))
            dr.backward(loss)
            dr.eval(dr.grad(p.log10_k))
        dr.sync_thread()  # LLVM kernels run asynchronously: wait before reading the clock
        t2 = time.perf_counter()
        return t1 - t0, t2 - t1

    run(False), run(True)  # warm-up both (the backward's kernels compile here)
    fwd = statistics.median(run(False)[0] for _ in range(3))
    rec, bwd = run(True)
    return {"forward_s": fwd, "forward_recording_s": rec, "backward_s": bwd, "grad_over_forward": (rec + bwd) / fwd}


def peak_memory_child(n_anchors: int, n_k: int, n_frames: int) -> dict:
    """Run in a fresh process: a full-mode gradient of an n_frames x 100-substep rollout."""
    import drjit as dr

    from sgdr.arrays import to_numpy
    from sgdr.physics import SimState, rollout

    cfg, model, params, state, ground = _system(n_anchors, n_k)
    rss_before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20
    dr.enable_grad(params)
    t0 = time.perf_counter()
    states = rollout(
        model,
        params,
        SimState.at_rest(model, params.v0),
        ground,
        n_frames + 1,
        1 / FPS,
        cfg,
        grad_mode="full",
        n_substeps=N_SUB,
    )
    loss = 0.0
    for s in states[1:]:
        loss = loss + dr.sum(dr.squared_norm(s.x))
    dr.backward(loss)
    g = to_numpy(dr.grad(params.log10_k))  # reading it runs the backward kernels
    return {
        "peak_rss_gib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20,
        "rss_before_gib": rss_before,
        "seconds": time.perf_counter() - t0,
        "grad_finite": bool(np.isfinite(g).all()),
    }


def _peak_memory(n_anchors: int, n_k: int, n_frames: int) -> dict:
    code = (
        "import json, evaluation.bench.sim as b; "
        f"print(json.dumps(b.peak_memory_child({n_anchors}, {n_k}, {n_frames})))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        check=True,
        cwd=ROOT,
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


def run() -> dict:
    b = backend.current()
    log = lambda msg: print(f"[bench sim] {msg}", file=sys.stderr, flush=True)  # noqa: E731
    log("forward 2048 x 256")
    big = _forward(2048, 256, reps=3)
    log("forward 512 x 64")
    small = _forward(512, 64, reps=5)
    log("forward 512 x 64 with spring plasticity (physics.plastic_yield_strain=0.1)")
    plastic = _forward(512, 64, reps=5, plastic_yield_strain=0.1)
    log("the gather-bound loop at 2048 x 256 (the roofline reference)")
    bound = _gather_bound(2048, 256, reps=3)
    log("numpy twin")
    np_big = _numpy_twin(2048, 256, n_steps=3)
    np_small = _numpy_twin(512, 64, n_steps=5)
    log("gradient / forward (2 frames x 100 substeps, full), gather adjoint (default)")
    grad = _gradient_ratio(2048, 256, n_frames=2, adjoint="gather")
    log("gradient / forward (6 frames x 100 substeps, full), gather adjoint")
    grad6 = _gradient_ratio(2048, 256, n_frames=6, adjoint="gather")
    log("gradient / forward, recorded AD of the spring loop (the reference)")
    grad_rec = _gradient_ratio(2048, 256, n_frames=2, adjoint="recorded")
    log("peak memory (20 frames x 100 substeps, full, child process)")
    mem = _peak_memory(2048, 256, n_frames=20)
    return {
        "spring_steps_per_s": big["steps_per_s"],
        "spring_steps_per_s_small": small["steps_per_s"],
        "numpy_ratio": big["steps_per_s"] / np_big,
        # the same loop's memory accesses with the least arithmetic, same run: what this CPU allows
        "gather_bound_spring_steps_per_s": bound,
        "fraction_of_gather_bound": big["steps_per_s"] / bound,
        "grad_over_forward": grad["grad_over_forward"],
        "peak_memory_gib": mem["peak_rss_gib"],
        "peak_memory_method": "ru_maxrss of a fresh child process running the 20x100 full gradient",
        "rss_before_rollout_gib": mem["rss_before_gib"],
        "peak_memory_run_s": mem["seconds"],
        "kernel_spring_steps_per_s": big["kernel_steps_per_s"],
        "kernel_spring_steps_per_s_small": small["kernel_steps_per_s"],
        "first_call_s": big["first_call_s"],
        "first_call_s_small": small["first_call_s"],
        "numpy_spring_steps_per_s": np_big,
        "numpy_ratio_small": small["steps_per_s"] / np_small,
        # a plastic frame over an elastic one, same system (the yield's own kernel: ~1.3; 4 when
        # gathering the new positions evaluated x alone and the spring loop ran twice)
        "plastic_over_elastic_small": plastic["wall_s"] / small["wall_s"],
        "forward_s": grad["forward_s"],
        "forward_recording_s": grad["forward_recording_s"],
        "backward_s": grad["backward_s"],
        "grad_over_forward_6_frames": grad6["grad_over_forward"],
        "backward_s_6_frames": grad6["backward_s"],
        "grad_over_forward_recorded": grad_rec["grad_over_forward"],
        "backward_s_recorded": grad_rec["backward_s"],
        "forward_recording_s_recorded": grad_rec["forward_recording_s"],
        "threads": b.threads,
        "load_avg_1min": os.getloadavg()[0],
    }
