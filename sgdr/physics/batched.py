"""Batched forward rollouts: S parameter samples of one asset in one Dr.Jit program.

The dynamic stage's global search scores a population of S candidates per call, and a posterior
sampler (emcee with `vectorize=True`) asks for the likelihood of S parameter vectors at once:
this is the one batched integrator both use. Instead of S rollouts of N_A anchors, `batched_rollout` runs one rollout of
S x N_A anchors: `replicate_model` stacks S copies of the asset's `SpringModel` (copy s holds
anchors s N_A .. (s+1) N_A - 1, its springs point into its own copy only, so the copies never
interact), and every parameter that differs between samples becomes a per-anchor array of
width S x N_A holding sample s's value on copy s. The substeps are the simulator's own
(`sgdr.physics.simulate`: `frame_constants`, the `ADJOINTS` stepper, `substep`, the `SPRINGS`
and `CONTACTS` registries), so every registered spring law, springs variant, symmetric
stiffness and contact model runs here without a second implementation. The per-anchor arrays
line up with the anchor arrays inside them: the spring sums read sp = softplus(κ) and ζ0 at
the anchor whose loop runs (in the symmetric variant's incoming loop the spring's source is in
the same copy, so the same sample's value), and the contact reads μ and e per anchor.

What a sample varies (`SAMPLE_FIELDS`; a field left out takes `base_params`' value):
- `dlog10_k` [S]: a global shift Δ of the identified field, log10 k_i = log10 k_i^base + Δ
  (in float32, as the simulator stores it); for a single-k model this is the global k;
- `dlog10_k_anchor` [S, N_A]: a shift per anchor, added to the global one (the global search's
  spatial modes of the field);
- `kappa` [S] (κ of the soft vector), `friction` [S] (μ), `restitution` [S] (e), `zeta0` [S]
  (ζ0), `v0` [S, 3] (initial velocity).
Shared by all samples: the topology (kNN springs, rest lengths, masses, soft-vector ranks),
gravity, the ground plane, n_substeps and the physics config.

Frozen frames. Each frame's substeps run through one `dr.freeze`-recorded function (`_frozen_frame`):
the first frame of a given batch width is traced and recorded, later frames and later calls of the
same width replay its kernels without tracing the substeps again in Python. At the tiny preset the
tracing was most of a rollout's time (5-10x faster replayed, identical positions; see `_frozen_frame`
for when it re-records); `freeze=False` runs the plain stepper (the reference,
tests/test_physics_batched.py).

Forward only (`dr.suspend_grad`). A batched sample equals the single `sgdr.physics.rollout`
with the same parameters and n_substeps to float32 rounding (tests/test_physics_batched.py).
Unlike `rollout`, a batch never retries with more substeps (one n_t for all samples); an
unstable sample is flagged instead, and does not disturb the others (no springs join copies).
The posterior's "batched" rollout (`sgdr.posterior.rollouts`) re-runs the flagged samples in
batches of their own with doubled substeps, as `rollout` would.
"""

from __future__ import annotations

from dataclasses import dataclass
from types import SimpleNamespace

import drjit as dr
import numpy as np

from sgdr.arrays import array3_to_points, to_numpy
from sgdr.backend import ad, frozen
from sgdr.physics.config import PhysicsConfig
from sgdr.physics.model import Ground, PhysicsInputError, PhysParams, SimState, SpringModel
from sgdr.physics.simulate import ADJOINTS, CONTACTS, SPRINGS, frame_constants, stable_substeps
from sgdr.skin.binding import IDWBinding, anchor_transpose

# one recording per input layout (batch width, physics settings, first frame or not); least recently
# used ones dropped past `limit`, so many batch widths do not pile up kernels. Measured (Dr.Jit 1.5,
# tiny): calls of one width replay after three calls (8 ms against 40-90 ms traced); calls whose
# width changes from one call to the next record again (one frozen function per width did the
# same), which costs about what tracing costs: sampling with emcee's moves, whose batch widths vary,
# gained 1.4x (486 -> 351 s for one tiny posterior).
_frozen_frame = frozen(ADJOINTS.get_named("recorded"), limit=16, warn_after=10**6)

SAMPLE_FIELDS = {
    "dlog10_k": (),
    "dlog10_k_anchor": ("N_A",),
    "kappa": (),
    "friction": (),
    "restitution": (),
    "zeta0": (),
    "v0": (3,),
}
"""Per-sample fields `batched_rollout` accepts, with the trailing shape of one sample's value ("N_A": one
value per anchor)."""


def replicate_model(model: SpringModel, n_samples: int) -> SpringModel:
    """The S-fold `SpringModel` of `model`: S x N_A anchors, copy s = anchors s N_A .. (s+1) N_A - 1
    with the same kNN topology (spring indices offset by s N_A, rest lengths, masses, soft-vector
    ranks), no springs between copies. Spring s' = (s N_A + i) n_k + r of the replica is spring
    i n_k + r of copy s, so the simulator's `s // n_k` source lookup and rank `s - a n_k` hold.
    Cached on `model` per S (the topology never changes)."""
    t = ad()
    S = int(n_samples)
    if S < 1:
        raise PhysicsInputError(f"n_samples={n_samples!r} must be a positive integer")
    cache = model.__dict__.setdefault("_replicas", {})
    if S in cache:
        return cache[S]
    n, n_k = model.n_anchors, model.n_k
    copy = np.arange(S, dtype=np.int64)[:, None]
    j = to_numpy(model.spring_j, np.int64)[None, :] + copy * n  # [S, N_A n_k]
    in_spring = to_numpy(model.in_spring, np.int64)[None, :] + copy * (n * n_k)
    in_offset = to_numpy(model.in_offset, np.int64)  # [N_A + 1], in_offset[-1] = N_A n_k
    in_offset = np.concatenate([(in_offset[:-1][None, :] + copy * (n * n_k)).reshape(-1), [S * n * n_k]])
    x_rest = to_numpy(model.x_rest, np.float32)  # [3, N_A]
    replica = SpringModel(
        x_rest=t.Array3f(*np.tile(x_rest, (1, S))),
        spring_j=t.UInt32(j.reshape(-1).astype(np.uint32)),
        spring_rest_length=t.Float(np.tile(to_numpy(model.spring_rest_length, np.float32), S)),
        particle_mass=t.Float(np.tile(to_numpy(model.particle_mass, np.float32), S)),
        in_spring=t.UInt32(in_spring.reshape(-1).astype(np.uint32)),
        in_offset=t.UInt32(in_offset.astype(np.uint32)),
        n_k=n_k,
        n_c=model.n_c,
        n_anchors=S * n,
    )
    cache[S] = replica
    return replica


def _sample_values(base_params: PhysParams, samples: dict) -> tuple[int, dict]:
    """(S, per-sample float64 arrays of every field of SAMPLE_FIELDS), base values filled in."""
    unknown = sorted(set(samples) - set(SAMPLE_FIELDS))
    if unknown:
        raise PhysicsInputError(f"samples: unknown field(s) {unknown}; known: {sorted(SAMPLE_FIELDS)}")
    if not samples:
        raise PhysicsInputError(f"samples must hold at least one of {sorted(SAMPLE_FIELDS)}")
    arrays = {name: np.asarray(a, dtype=np.float64) for name, a in samples.items()}
    sizes = {name: a.shape[0] if a.ndim else 0 for name, a in arrays.items()}
    S = next(iter(sizes.values()))
    n_anchors = int(to_numpy(base_params.log10_k).size)
    for name, a in arrays.items():
        shape = (S, *(n_anchors if d == "N_A" else d for d in SAMPLE_FIELDS[name]))
        if a.shape != shape or S < 1:
            raise PhysicsInputError(f"samples[{name!r}] has shape {a.shape}, expected {shape} (S={S} samples)")
    base = {
        "dlog10_k": np.zeros(1),
        "dlog10_k_anchor": np.zeros((1, n_anchors)),
        "kappa": to_numpy(base_params.kappa).reshape(1),
        "friction": to_numpy(base_params.friction).reshape(1),
        "restitution": to_numpy(base_params.restitution).reshape(1),
        "zeta0": to_numpy(base_params.zeta0).reshape(1),
        "v0": to_numpy(base_params.v0).reshape(1, 3),
    }
    out = {name: arrays[name] if name in arrays else np.repeat(b, S, axis=0) for name, b in base.items()}
    return S, out


@dataclass
class BatchedRollout:
    """Result of `batched_rollout`.

    positions: [S, T, N_A, 3] float64 anchor positions per sample and frame (frame 0 = rest),
      NaN for every frame of an unstable sample;
    stable: [S] bool, False where the sample is unstable (the sampler's log-probability -inf);
    cfl_ok: [S] bool, the stability bound dt <= physics.cfl_factor sqrt(m_i / k_eff,i) held;
    finite: [S] bool, all positions and velocities stayed finite through the rollout;
    n_substeps: the substeps per frame every sample used;
    need_substeps: [S] int, the fewest substeps the sample's stability bound allows
      (`sgdr.physics.simulate.stable_substeps`; NEVER for NaN/inf parameters)."""

    positions: np.ndarray
    stable: np.ndarray
    cfl_ok: np.ndarray
    finite: np.ndarray
    n_substeps: int
    need_substeps: np.ndarray


NEVER = np.iinfo(np.int64).max  # need_substeps of a sample no substep count makes stable


def batched_rollout(
    model: SpringModel,
    base_params: PhysParams,
    samples: dict,
    ground: Ground,
    n_frames: int,
    dt_frame: float,
    n_substeps: int | None,
    cfg: PhysicsConfig,
    freeze: bool = True,
) -> BatchedRollout:
    """Anchor positions of S parameter samples over n_frames frames, simulated together.

    model / base_params: the asset (N_A anchors) and its identified parameters; samples: a
    dict of per-sample arrays (`SAMPLE_FIELDS`, module docstring), the fields left out taken
    from base_params; gravity always from base_params. Every frame runs n_substeps substeps
    (default physics.n_substeps) of dt_frame / n_substeps, from the rest positions moving with
    the sample's v0 (as `rollout` from `SimState.at_rest(model, v0)`).

    A sample is unstable (stable[s] = False) when
    - its parameters violate the stability bound the single rollout checks before running
      (`sgdr.physics.simulate.stable_substeps`: dt <= physics.cfl_factor sqrt(m_i / k_eff,i) for
      every anchor, k_eff from its log10 k field and κ), or
    - any of its anchors' positions or velocities is NaN/inf at any frame;
    a sample given NaN/inf parameters is unstable as well. Unstable samples are still simulated
    (their copy cannot reach the others), and their positions are returned as NaN.
    freeze: replay each frame's recorded kernels (`_frozen_frame`); False: trace every substep.
    """
    t = ad()
    n_sub = int(n_substeps or cfg.n_substeps)
    if n_frames < 1:
        raise PhysicsInputError(f"n_frames={n_frames} must be >= 1")
    if not (dt_frame > 0 and np.isfinite(dt_frame)):
        raise PhysicsInputError(f"dt_frame={dt_frame} must be a positive number of seconds")
    base_params.validate(model)
    S, val = _sample_values(base_params, samples)
    n = model.n_anchors
    SPRINGS.get_named(cfg.springs, "physics.springs")  # fail early, naming the setting
    CONTACTS.get_named(cfg.contact, "physics.contact")
    ADJOINTS.get_named(cfg.adjoint, "physics.adjoint")  # forward only: every adjoint steps the same way
    stepper = _frozen_frame if freeze else ADJOINTS.get_named("recorded")

    base_log10_k = to_numpy(base_params.log10_k, np.float32)
    shift = val["dlog10_k"][:, None] + val["dlog10_k_anchor"]  # [S, N_A]
    log10_k = base_log10_k[None, :] + shift.astype(np.float32)  # [S, N_A] float32
    finite_params = np.isfinite(log10_k).all(axis=1)
    for name in ("kappa", "friction", "restitution", "zeta0", "v0"):
        finite_params &= np.isfinite(val[name].reshape(S, -1)).all(axis=1)
    # the single rollout's pre-check, per sample (effective_stiffness reads log10_k and kappa only)
    need = np.full(S, NEVER, dtype=np.int64)
    for s in np.flatnonzero(finite_params):
        view = SimpleNamespace(log10_k=log10_k[s].astype(np.float64), kappa=float(val["kappa"][s]))
        need[s] = stable_substeps(model, view, dt_frame, cfg)
    cfl_ok = need <= n_sub
    # NaN/inf parameters would still run harmlessly in their own copy; zeros keep them finite
    safe = {name: np.where(np.isfinite(a), a, 0.0) for name, a in val.items()}
    log10_k = np.where(np.isfinite(log10_k), log10_k, np.float32(0.0))

    replica = replicate_model(model, S)

    def per_anchor(a):  # one value per sample -> Float [S N_A], sample s on copy s
        return t.Float(np.repeat(a.astype(np.float32), n))

    with dr.suspend_grad():
        params = PhysParams(
            log10_k=t.Float(log10_k.reshape(-1)),
            kappa=per_anchor(safe["kappa"]),
            v0=t.Array3f(*np.repeat(safe["v0"].astype(np.float32), n, axis=0).T),
            friction=per_anchor(safe["friction"]),
            restitution=per_anchor(safe["restitution"]),
            zeta0=per_anchor(safe["zeta0"]),
            gravity=t.Array3f(*to_numpy(base_params.gravity, np.float32).reshape(3, 1)),
        )
        dr.eval(params.gravity)  # width 1: evaluated, so it is never resized to S N_A in place
        state = SimState(x=t.Array3f(replica.x_rest), v=params.v0)
        dt = float(dt_frame) / n_sub
        positions = np.empty((n_frames, 3, S * n), dtype=np.float64)
        finite = np.ones(S, dtype=bool)
        positions[0] = to_numpy(state.x)
        for f in range(1, n_frames):
            state = stepper(replica, params, state, frame_constants(replica, params, ground, cfg), dt, n_sub, cfg)
            positions[f] = to_numpy(state.x)
            v = to_numpy(state.v)
            finite &= np.isfinite(positions[f]).reshape(3, S, n).all(axis=(0, 2))
            finite &= np.isfinite(v).reshape(3, S, n).all(axis=(0, 2))
    # [T, 3, S N_A] -> [S, T, N_A, 3]
    positions = positions.reshape(n_frames, 3, S, n).transpose(2, 0, 3, 1).copy()
    stable = finite_params & cfl_ok & finite
    positions[~stable] = np.nan
    return BatchedRollout(
        positions=positions, stable=stable, cfl_ok=cfl_ok, finite=finite, n_substeps=n_sub, need_substeps=need
    )


def batched_centres(binding, positions: np.ndarray) -> np.ndarray:
    """Gaussian centres [S, T, M, 3] float64 from anchor positions [S, T, N_A, 3] through an
    `sgdr.skin.IDWBinding` (its `apply`, Eq. 14, so both binding forms), all S x T frames of
    anchors bound in one call: the frames are stacked as S T copies of the binding (anchor
    indices offset per copy). NaN positions (unstable samples) give NaN centres."""

    t = ad()
    positions = np.asarray(positions, dtype=np.float64)
    n = dr.width(binding.anchors_rest)
    if positions.ndim != 4 or positions.shape[2:] != (n, 3):
        raise PhysicsInputError(f"positions must have shape [S, T, N_A={n}, 3], got {positions.shape}")
    S, T = positions.shape[:2]
    c, m = S * T, binding.count
    idx = to_numpy(binding.anchor_index, np.int64)[None, :] + np.arange(c, dtype=np.int64)[:, None] * n
    pair_offset, pair = anchor_transpose(idx, c * n)
    stacked = IDWBinding(
        anchor_index=t.UInt32(idx.reshape(-1).astype(np.uint32)),
        weight=t.Float(np.tile(to_numpy(binding.weight, np.float32), c)),
        rest_centres=t.Array3f(*np.tile(to_numpy(binding.rest_centres, np.float32), (1, c))),
        anchors_rest=t.Array3f(*np.tile(to_numpy(binding.anchors_rest, np.float32), (1, c))),
        n_b=binding.n_b,
        form=binding.form,
        pair_offset=t.UInt32(pair_offset),
        pair=t.UInt32(pair),
    )
    x = positions.reshape(c * n, 3).astype(np.float32)
    with dr.suspend_grad():
        centres = stacked.apply(t.Array3f(*x.T))
    return array3_to_points(centres).reshape(S, T, m, 3)
