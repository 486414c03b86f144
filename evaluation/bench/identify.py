"""Global-stage benchmark: `python -m evaluation.bench identify` (or `make bench BENCH=identify`).

What the dynamic stage's global search (`sgdr.identify.global_search`) pays per candidate: the
open-loop rollout of the fit frames and its renders on every view. At the small preset's scale
(N_A = 512 anchors of the benchmark torus, n_k = 64, n_t = 150, 20 fit frames at 24 fps, M =
4000 Gaussians bound to them, 10 views at 64 x 64 pixels: the small preset's 128 x 128 images at
recon.search.image_scale 2) it scores a population of S = 8 candidates
- batched: one `PopulationScorer` call (one S x N_A rollout, then the renders and losses of
  `recon.search.images_per_call` images per program: `render_batch`, `image_losses`),
- batched rollout, one render per image: the same call with images_per_call = 1, and
- one at a time: S calls of one candidate each, one render per image,
in the same run, interleaved, after a warm-up call of each (tracing + compilation). Reported:
candidates per second of each, the speed-ups (`batched_over_single`: the first over the last;
`batched_render_over_per_image`: the first over the second), the rollout's share of a batched
call, and the largest difference between the losses (they score the same candidates: float32
rounding only). Median over REPS calls; the minima beside them.
"""

from __future__ import annotations

import statistics
import sys
import time

import numpy as np

import sgdr.backend as backend

# Dr.Jit and the sgdr modules that import it: inside the functions, after `sgdr.backend.init`
# (evaluation/bench/__init__.py says why).

N_ANCHORS, N_K, N_SUB, N_FIT, FPS = 512, 64, 150, 20, 24.0
N_GAUSSIANS, N_VIEWS, RES = 4000, 10, 64
S = 8
REPS = 3
SEED = 0


def _scene():
    backend.current()  # the LLVM backend unless a driver chose one
    from sgdr.anchors.sampling import sample_anchors
    from sgdr.cameras import Camera
    from sgdr.gaussians.model import Gaussians
    from sgdr.identify.config import SearchConfig
    from sgdr.identify.global_search import PopulationScorer
    from sgdr.physics import Ground, PhysicsConfig, PhysParams, SimState, build_spring_model, rollout
    from sgdr.render.config import RenderConfig
    from sgdr.render.images import posed, render_rgb_numpy, to_tensor
    from sgdr.skin import IDWBinding
    from sgdr.synth.objects import placed_sdf

    rng = np.random.default_rng(SEED)
    sdf = placed_sdf("torus")
    points = rng.uniform(0.0, 1.0, (400_000, 3))
    points = points[sdf(points) < 0]
    lo, hi = points.min(0), points.max(0)  # denser samples inside the torus's box
    points = rng.uniform(lo, hi, (400_000, 3))
    points = points[sdf(points) < 0]
    anchors = sample_anchors(points, N_ANCHORS, "fps", 0.01, SEED)
    centres = points[rng.choice(len(points), N_GAUSSIANS, replace=False)]
    colours = 0.2 + 0.6 * (centres - centres.min(0)) / np.ptp(centres, 0)
    cfg = PhysicsConfig(n_substeps=N_SUB, contact="coulomb")
    model = build_spring_model(anchors, N_K, cfg)
    binding = IDWBinding.build(centres, anchors, 16, 2.0, "displacement")
    g = Gaussians.isotropic(centres, 0.012, colours, 0.9)
    ground = Ground([0.0, 0.0, float(anchors[:, 2].min()) - 0.02], [0.0, 0.0, 1.0])
    centre = anchors.mean(0)
    cams = [
        Camera.look_at(centre + 1.2 * np.array([np.cos(a), np.sin(a), 0.5]), centre, [0, 0, 1], 40.0, RES, RES, f"c{i}")
        for i, a in enumerate(np.linspace(0, 2 * np.pi, N_VIEWS, endpoint=False))
    ]
    rcfg = RenderConfig()
    base = PhysParams.init(model, cfg, v0=(0.2, 0.0, -1.0))
    truth = PhysParams.init(model, cfg, v0=(0.2, 0.0, -1.0))
    states = rollout(model, truth, SimState.at_rest(model, (0.2, 0.0, -1.0)), ground, N_FIT, 1 / FPS, cfg)
    targets = [[to_tensor(render_rgb_numpy(posed(g, binding.apply(s.x)), c, rcfg)) for c in cams] for s in states]
    per_call = int(SearchConfig().images_per_call)  # the batched path's own arrays are built at construction
    scorer = PopulationScorer(
        model, binding, g, base, ground, targets, cams, 1 / FPS, N_SUB, cfg, rcfg, 0.05, 1, per_call
    )
    rng = np.random.default_rng(SEED + 1)
    values = {
        "log10_k": rng.uniform(2.6, 3.4, S),
        "kappa": rng.uniform(-1.0, 1.0, S),
        "friction": rng.uniform(0.2, 0.9, S),
        "restitution": rng.uniform(0.0, 0.5, S),
    }
    return scorer, values


def run() -> dict:
    scorer, values = _scene()
    one = [{k: v[i : i + 1] for k, v in values.items()} for i in range(S)]
    per_call = scorer.images_per_call

    def batched():
        scorer.images_per_call = per_call
        return scorer(values)

    def per_image():
        scorer.images_per_call = 1
        return scorer(values)

    def single():
        scorer.images_per_call = 1
        return np.concatenate([scorer(v) for v in one])

    t0 = time.perf_counter()
    lb = batched()
    warm_batched = time.perf_counter() - t0
    t0 = time.perf_counter()
    ls = single()
    warm_single = time.perf_counter() - t0
    lp = per_image()
    tb, ts, tr, tp = [], [], [], []
    for rep in range(REPS):
        print(f"identify bench: rep {rep + 1}/{REPS}", file=sys.stderr)
        t0 = time.perf_counter()
        batched()
        tb.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        single()
        ts.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        per_image()
        tp.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        scorer.rollout(values, N_FIT)
        tr.append(time.perf_counter() - t0)
    mb, ms = statistics.median(tb), statistics.median(ts)
    return {
        "population": S,
        "anchors": N_ANCHORS,
        "gaussians": N_GAUSSIANS,
        "views": N_VIEWS,
        "image_size": RES,
        "fit_frames": N_FIT,
        "n_substeps": N_SUB,
        "batched_candidates_per_s": S / mb,
        "single_candidates_per_s": S / ms,
        "batched_over_single": ms / mb,
        "batched_over_single_of_minima": min(ts) / min(tb),
        "per_image_candidates_per_s": S / statistics.median(tp),
        "batched_render_over_per_image": statistics.median(tp) / mb,
        "images_per_call": per_call,
        "rollout_share_of_batched": statistics.median(tr) / mb,
        "batched_s_each": tb,
        "single_s_each": ts,
        "per_image_s_each": tp,
        "warmup_batched_s": warm_batched,
        "warmup_single_s": warm_single,
        "max_loss_diff": float(np.max(np.abs(lb - ls))),
        "max_loss_diff_per_image": float(np.max(np.abs(lp - ls))),
        "losses": lb.tolist(),
    }
