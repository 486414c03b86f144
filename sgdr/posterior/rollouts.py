"""Rollouts of many parameter samples of one asset: the contract the posterior's likelihood calls.

`loop_rollout(model, base_params, samples, ground, n_frames, dt_frame, n_substeps, cfg)` returns
(positions [S, T, N_A, 3] float64, stable [S] bool), the same contract as the batched
`sgdr.physics.batched.batched_rollout`, implemented by one `sgdr.physics.rollout` per sample
(correct on any backend, slower). `base_params` is the asset's plain parameter values
(`Asset.values`: log10_k [N_A], kappa, friction, restitution, v0 [3], gravity [3]); `samples` a
dict of per-sample arrays:

    "log10_k_shift" [S]  added to every anchor's identified log10 k_i (a global stiffness shift)
    "kappa" [S], "friction" [S], "restitution" [S]   replace the identified values
    "zeta0" [S] (optional)   replaces physics.zeta0 (damping)
    "v0" [S, 3] (optional)   replaces the identified initial velocity

A sample whose rollout is unstable even after the retries `cfg` allows (physics.retry_on_nan up
to physics.max_substeps) has stable False and NaN positions; the likelihood gives it zero
probability instead of stopping the sampler.
"""

from __future__ import annotations

import numpy as np

from sgdr.arrays import array3_to_points
from sgdr.asset.predict import physical_params
from sgdr.physics import SimState, SimulationUnstable, rollout
from sgdr.physics.batched import batched_rollout
from sgdr.physics.simulate import doubled_substeps
from sgdr.registry import Registry

SAMPLE_KEYS = ("log10_k_shift", "kappa", "friction", "restitution", "zeta0", "v0")

# How the sampler's S samples per call are simulated (posterior.rollout): "batched", S x N_A
# anchors in one Dr.Jit program (`sgdr.physics.batched`; ~2x faster per sample on 2 CPU cores,
# docs/benchmarks.md); "loop", one single rollout per sample (the reference; it retries an
# unstable sample with doubled substeps as physics.retry_on_nan allows, the batched one does not).
ROLLOUTS = Registry("posterior rollout", "posterior.rollout", ValueError)


def sample_count(samples: dict) -> int:
    """S, checking that every array in `samples` has it and every key is known."""
    unknown = sorted(set(samples) - set(SAMPLE_KEYS))
    if unknown:
        raise ValueError(f"rollout samples: unknown keys {unknown} (known: {list(SAMPLE_KEYS)})")
    sizes = {k: np.asarray(v).shape[0] for k, v in samples.items()}
    if len(set(sizes.values())) != 1:
        raise ValueError(f"rollout samples: arrays of different lengths {sizes}")
    return next(iter(sizes.values()))


def sample_values(base_params: dict, samples: dict, i: int) -> dict:
    """The plain parameter values of sample i (`physical_params`'s input)."""
    values = dict(base_params)
    values["log10_k"] = np.asarray(base_params["log10_k"], float) + float(
        np.asarray(samples.get("log10_k_shift", np.zeros(i + 1)))[i]
    )
    for key in ("kappa", "friction", "restitution", "zeta0"):
        if key in samples:
            values[key] = float(np.asarray(samples[key])[i])
    if "v0" in samples:
        values["v0"] = np.asarray(samples["v0"], float)[i].reshape(3)
    return values


@ROLLOUTS.register("loop")
def loop_rollout(model, base_params: dict, samples: dict, ground, n_frames: int, dt_frame: float, n_substeps: int, cfg):
    """(positions [S, T, N_A, 3], stable [S]): one forward rollout from rest per sample."""
    import drjit as dr

    s = sample_count(samples)
    out = np.full((s, int(n_frames), model.n_anchors, 3), np.nan)
    stable = np.zeros(s, bool)
    with dr.suspend_grad():
        for i in range(s):
            p = physical_params(model, cfg, sample_values(base_params, samples, i))
            try:
                states = rollout(
                    model,
                    p,
                    SimState.at_rest(model, p.v0),
                    ground,
                    int(n_frames),
                    float(dt_frame),
                    cfg,
                    n_substeps=int(n_substeps),
                )
            except SimulationUnstable:
                continue
            out[i] = np.stack([array3_to_points(st.x) for st in states])
            stable[i] = bool(np.all(np.isfinite(out[i])))
    return out, stable


BATCH = 32  # samples per Dr.Jit program; more gains nothing on 2 cores (docs/benchmarks.md)


@ROLLOUTS.register("batched")
def batched_samples_rollout(
    model, base_params: dict, samples: dict, ground, n_frames: int, dt_frame: float, n_substeps: int, cfg
):
    """(positions [S, T, N_A, 3], stable [S]): the same contract through
    `sgdr.physics.batched.batched_rollout`, at most `BATCH` samples per program.

    One batched program runs every sample at the asset's n_t and does not retry: a sample stiffer
    than n_t's stability bound comes back unstable. On the small torus the identified asset sits
    at that bound (every sample with a log10 k shift above ~ +0.07 was unstable), which would
    cut the posterior off at the MAP's stiffness. The unstable samples are therefore re-run,
    batched again, with the single rollout's remedy (`sgdr.physics.simulate.rollout`): n_t
    doubled while physics.retry_on_nan and physics.max_substeps allow, each sample from the
    first doubling its stability bound allows, again when it still blows up. So both rollouts
    give the same answer for every sample (a sample unstable there too stays unstable). Before,
    these samples went through `loop_rollout` one by one: the tiny SBC case with the stiffest
    truth took 2-3x as long as the others."""

    s = sample_count(samples)
    params = physical_params(model, cfg, base_params)
    mapped = {("dlog10_k" if k == "log10_k_shift" else k): np.asarray(v, float) for k, v in samples.items()}
    run = (model, params, ground, int(n_frames), float(dt_frame), cfg)
    positions, stable, need = _batches(run, mapped, np.arange(s), int(n_substeps), pad=False)
    n_sub = int(n_substeps)
    while cfg.retry_on_nan and not stable.all() and (more := doubled_substeps(n_sub, cfg)):
        n_sub = more
        redo = np.flatnonzero(~stable & (need <= n_sub))
        if redo.size:
            positions[redo], stable[redo], _ = _batches(run, mapped, redo, n_sub, pad=True)
    return positions, stable


def _batches(run: tuple, mapped: dict, idx: np.ndarray, n_substeps: int, pad: bool):
    """positions, stable and need_substeps of the samples `idx` of `mapped`, `BATCH` per
    program. pad: a last, partial batch is padded (repeating its last sample) to the next power
    of two, so that retries of a varying few samples replay a handful of recorded widths
    instead of recording one per count (the sampler's own calls have one width)."""

    model, params, ground, n_frames, dt_frame, cfg = run
    out = [], [], []
    for lo in range(0, idx.size, BATCH):
        chunk = idx[lo : lo + BATCH]
        width = min(BATCH, 1 << int(np.ceil(np.log2(chunk.size)))) if pad else chunk.size
        padded = np.concatenate([chunk, np.full(width - chunk.size, chunk[-1])])
        res = batched_rollout(
            model, params, {k: v[padded] for k, v in mapped.items()}, ground, n_frames, dt_frame, n_substeps, cfg
        )
        for acc, a in zip(out, (res.positions, res.stable, res.need_substeps)):
            acc.append(a[: chunk.size])
    return tuple(np.concatenate(a) for a in out)
