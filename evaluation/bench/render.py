"""Renderer benchmark: `python -m evaluation.bench render` (or `make bench BENCH=render`).

Scenes: N isotropic Gaussians (σ = 0.01, opacity 0.7, random colours) filling a ball of
radius 0.2 in the unit cube, seen from 1.2 units with a 40° field of view (the object spans
about half the frame). Timings are medians over repeats after a warm-up call; the first
call's extra time (tracing + LLVM compilation) is reported separately. fwd+bwd = render,
loss = Σ rgb² + Σ alpha, dr.backward to means/log-scales/colours/opacities, gradients evaluated.

Reference measured in the same run: Mitsuba 3's ray-traced Gaussians (`ellipsoids` +
`volprim_rf_basic`, 1 spp, box filter), forward and forward+backward of the same loss w.r.t.
the same parameters. mitsuba_ratio = Mitsuba fwd+bwd / ours fwd+bwd at 256x256 / 10k.

static_fit_small_s: one static fit at the `small` preset (10 views of 128x128 of a known
blob rendered by our renderer; the preset's n_init, s0 and iterations), wall-clock seconds
including compilation, and per step (static_fit_small_ms_per_step = seconds / iterations).
"""

from __future__ import annotations

import sys
import time

import numpy as np

import sgdr.backend

# Dr.Jit and the sgdr modules that import it: inside the functions, after `sgdr.backend.init`
# (evaluation/bench/__init__.py says why).


def _scene(n: int, seed: int = 0):
    from sgdr.gaussians.model import Gaussians

    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    pts = 0.5 + 0.2 * d * rng.uniform(0, 1, (n, 1)) ** (1 / 3)
    return Gaussians.isotropic(pts, 0.01, rng.uniform(0.05, 0.95, (n, 3)), 0.7)


def _camera(res: int):
    from sgdr.cameras import Camera

    return Camera.look_at([0.5, -0.7, 0.8], [0.5, 0.5, 0.5], [0, 0, 1], 40, res, res)


def _time(fn, repeats: int) -> tuple[float, float, float]:
    """(first call ms, median wall ms, median process CPU ms) of `repeats` later calls; fn must
    synchronise. CPU time sums all threads: on an otherwise idle 2-core machine with perfect
    scaling, wall ≈ CPU / 2; under load from other processes the wall time grows, CPU not much."""
    t0 = time.perf_counter()
    fn()
    first = 1e3 * (time.perf_counter() - t0)
    wall, cpu = [], []
    for _ in range(repeats):
        c0, t0 = time.process_time(), time.perf_counter()
        fn()
        wall.append(1e3 * (time.perf_counter() - t0))
        cpu.append(1e3 * (time.process_time() - c0))
    return first, float(np.median(wall)), float(np.median(cpu))


def _ours(g, cam, cfg, backward: bool):
    import drjit as dr

    from sgdr.render.splat import render

    fields = (g.means, g.log_scales, g.color_logits, g.opacity_logits)

    def run():
        if backward:
            dr.enable_grad(*fields)
        out = render(g, cam, cfg)
        if backward:
            loss = dr.sum(out.rgb * out.rgb, axis=None) + dr.sum(out.alpha, axis=None)
            dr.backward(loss)
            dr.eval(*(dr.grad(f) for f in fields))
            for f in fields:
                dr.disable_grad(f)
        else:
            dr.eval(out.rgb, out.alpha)
        dr.sync_thread()

    return run


def _mitsuba(g, cam, backward: bool):
    import drjit as dr
    import mitsuba as mi

    from sgdr.render.mitsuba_ref import mitsuba_scene

    scene = mitsuba_scene(g, cam, spp=1)
    params = mi.traverse(scene)
    keys = [k for k in params.keys() if k.endswith(("data", "opacities", "sh_coeffs"))]

    def run():
        if backward:
            for k in keys:
                dr.enable_grad(params[k])
            params.update()
        img = mi.render(scene, params, seed=0, spp=1)
        if backward:
            dr.backward(dr.sum(img * img, axis=None))
            dr.eval(*(dr.grad(params[k]) for k in keys))
            for k in keys:
                dr.disable_grad(params[k])
        else:
            dr.eval(img)
        dr.sync_thread()

    return run


def _static_fit_small() -> tuple[float, float, int]:
    from sgdr.cameras import Camera
    from sgdr.config import compose
    from sgdr.evaluate import psnr
    from sgdr.gaussians.model import Gaussians
    from sgdr.render.config import RenderConfig
    from sgdr.render.splat import render
    from sgdr.static_fit.config import StaticFitConfig
    from sgdr.static_fit.fit import fit_static

    cfg = compose(["preset=small"])
    fit_cfg, rcfg = StaticFitConfig(**cfg.static_fit), RenderConfig(**cfg.render)
    res, n_views = int(cfg.synth.resolution), int(cfg.synth.n_views)
    rng = np.random.default_rng(0)
    d = rng.normal(size=(600, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    pts = 0.5 + 0.15 * d * rng.uniform(0, 1, (600, 1)) ** (1 / 3)
    truth = Gaussians.isotropic(pts, fit_cfg.s0, np.clip(0.2 + 0.6 * (pts - 0.35) / 0.3, 0.05, 0.95), 0.9)
    cams = []
    for i in range(n_views + 1):  # the last view is held out
        az, el = 2 * np.pi * (i + 0.5 * (i == n_views)) / n_views, (0.3 if i % 2 else -0.2)
        eye = 0.5 + 1.3 * np.array([np.cos(az) * np.cos(el), np.sin(az) * np.cos(el), np.sin(el)])
        cams.append(Camera.look_at(eye, [0.5, 0.5, 0.5], [0, 0, 1], 40, res, res, name=f"v{i}"))
    images = []
    for c in cams:
        out = render(truth, c, rcfg)
        images.append(np.concatenate([np.asarray(out.rgb), np.asarray(out.alpha)[..., None]], -1))
    t0 = time.perf_counter()
    g = fit_static(images[:n_views], cams[:n_views], fit_cfg, rcfg, box=None, seed=0, progress=False)
    seconds = time.perf_counter() - t0
    held_out = psnr(np.asarray(render(g, cams[-1], rcfg).rgb), images[-1][..., :3])
    return seconds, held_out, int(fit_cfg.iterations)


def run() -> dict:
    backend = sgdr.backend.init("llvm")
    import drjit as dr

    from sgdr.render.config import RenderConfig

    cfg = RenderConfig()
    result: dict = {"threads": backend.threads}
    g10k, cam256 = _scene(10_000), _camera(256)
    g2k, cam128 = _scene(2_000, seed=1), _camera(128)

    for key, (g, cam, backward) in {
        "fwd_ms_256_10k": (g10k, cam256, False),
        "fwd_bwd_ms_256_10k": (g10k, cam256, True),
        "fwd_ms_128_2k": (g2k, cam128, False),
        "fwd_bwd_ms_128_2k": (g2k, cam128, True),
    }.items():
        first, wall, cpu = _time(_ours(g, cam, cfg, backward), 15)
        result[key] = round(wall, 2)
        result[key.replace("_ms_", "_cpu_ms_")] = round(cpu, 2)
        result[key.replace("_ms_", "_compile_ms_")] = round(first - wall, 1)
    print("render: ours done, timing Mitsuba", file=sys.stderr)

    _, mi_fwd, mi_fwd_cpu = _time(_mitsuba(g10k, cam256, backward=False), 5)
    _, mi_bwd, mi_bwd_cpu = _time(_mitsuba(g10k, cam256, backward=True), 5)
    result.update(
        mitsuba_fwd_ms_256_10k=round(mi_fwd, 2),
        mitsuba_fwd_bwd_ms_256_10k=round(mi_bwd, 2),
        mitsuba_fwd_bwd_cpu_ms_256_10k=round(mi_bwd_cpu, 2),
        mitsuba_ratio=round(mi_bwd / result["fwd_bwd_ms_256_10k"], 2),
        mitsuba_cpu_ratio=round(mi_bwd_cpu / result["fwd_bwd_cpu_ms_256_10k"], 2),
        mitsuba_fwd_ratio=round(mi_fwd / result["fwd_ms_256_10k"], 2),
    )
    print("render: timing the small static fit", file=sys.stderr)
    c0 = time.process_time()
    seconds, held_out_psnr, iterations = _static_fit_small()
    result.update(
        static_fit_small_s=round(seconds, 1),
        static_fit_small_cpu_s=round(time.process_time() - c0, 1),
        static_fit_small_iterations=iterations,
        # per step, so a slower step shows even when the preset's iteration count changes
        static_fit_small_ms_per_step=round(1e3 * seconds / max(iterations, 1), 2),
        static_fit_small_held_out_psnr=round(held_out_psnr, 2),
    )
    dr.sync_thread()
    return result
