"""Spring forces, semi-implicit Euler substeps, frames and rollouts (Eqs. 8-13), and how they
are differentiated.

One substep (Eqs. 10-13), for all anchors i at once:
    F_i  = Σ_j F_k(i, j) + F_ζ(i, j)                                    (Eqs. 8, 9)
    v_i ← v_i + dt (F_i / m_i + g)                                     (Eq. 11)
    x_i ← x_i + dt v_i                                                 (Eq. 12)
    (x_i, v_i) ← B(x_i, v_i)   ground contact                          (Eq. 13)
with dt = dt_frame / n_t. The spring sum is a per-anchor `dr.while_loop` over the anchor's
springs (a "sum loop", `max_iterations=-1`): the whole substep is one kernel, gathers only, and
`dr.eval(x, v)` once per substep materialises the state.

Springs (config `physics.springs`):
- `directed` (official): anchor i feels its n_k springs i->j with k_ij = k_i / l_ij (Eq. 16);
  j is not pushed back (no Newton's third law; momentum is not conserved).
- `symmetric`: every kNN spring s = (i -> j) acts on both ends with equal and opposite forces
  and stiffness k_s = combine(k_i, k_j) / l_ij (`physics.symmetric_stiffness`: harmonic mean,
  the default = two half-springs in series, or arithmetic mean). If j is also among i's
  neighbours the pair is joined by two springs. Anchor i sums its outgoing springs and, through
  the incoming lists of `SpringModel`, the springs that point at it, each computed with the
  same floating-point operations from the spring's source, so momentum is conserved to
  rounding.
Damping (Eq. 9) uses ζ_ij = ζ0 / l_ij (Eq. 17) along the spring direction, without η.

Gradients (how a frame is differentiated): `physics.adjoint`
-----------------------------------------------------------
k_i = 10^log10_k_i and softplus(κ) are always recorded AD (once per frame). The substeps:
- `gather` (default): the n_t substeps of a frame are one `dr.CustomOp`
  (sgdr/physics/adjoint.py). Its forward keeps each substep's x, v and spring force f; its
  backward walks the substeps in reverse: the Euler update and contact by recorded AD of a
  throw-away graph on the taped values (a few elementwise operations), the spring sum by a
  hand-written adjoint: for each anchor, a per-anchor sum loop over its outgoing springs and a
  second one over the springs that point at it (`in_spring` / `in_offset` lists), each
  recomputing the spring's local adjoint from x, v, k: gathers only, no atomics. sp =
  softplus(κ), ζ0, g, μ, e enter the op broadcast to N_A so that their per-anchor adjoints
  are reduced by Dr.Jit's broadcast, once per frame. The outer AD graph holds one node per
  frame; a custom op per substep (the first version) made Dr.Jit's graph traversal grow
  faster than the number of frames.
- `recorded` (the reference, tests compare the two): recorded AD through every substep.
  Dr.Jit differentiates a `max_iterations=-1` loop by re-running its body in the backward
  pass, so the per-spring intermediates are never stored either; but it runs 7-8 loop-sized
  reverse kernels per substep at 2048 x 256 (apparently one replay per differentiable input
  the loop reads), each turning the gathers of x_j, v_j (and k_j) into atomic scatter-adds.
  With gradients enabled it evaluates f together with x, v once per substep (`dr.eval(x, v,
  f)`): the contact's backward re-reads the pre-contact x, v, and with f unevaluated it re-ran
  and re-compiled the spring loop for every substep of the backward. Without gradients a
  substep is one kernel and f is never stored.

Memory: per anchor and substep the tape keeps x, v and f (36 bytes; the gather op's own tape;
tests/test_physics_memory.py measures 36-40 B marginal on LLVM for both adjoints), nothing per spring, so independent of n_k. A `full` gradient therefore costs about
n_frames x n_t x N_A x 40 B: 164 MB at paper scale for 20 frames x 100 substeps x 2048 anchors
(490 MB at 30 x 200); the process peak is measured by evaluation/bench/sim.py (docs/benchmarks.md,
"Simulator"), far under the 4 GiB bar. So no per-frame checkpointing is needed for memory.

`truncated` (official) starts every frame after the first from the detached previous state:
the gradient is Σ_f ∂L/∂x_f · ∂Φ(θ, stop_grad(x_{f-1}))/∂θ, and frame 1 still starts from
`state0` as given, so v0 receives the gradient of the first frame. Its tape is the same size
as long as the loss over all frames is built before `dr.backward` (as the pipeline does).

Cost: measured gradient / forward at 2048 x 256 for both adjoints: docs/benchmarks.md, "Simulator".
"""

from __future__ import annotations

from collections.abc import Callable

import drjit as dr
import numpy as np

from sgdr.arrays import scalar, to_numpy
from sgdr.backend import ad
from sgdr.physics.adjoint import frame_gather
from sgdr.physics.config import PhysicsConfig
from sgdr.physics.extensions import drag_factor, ground_plane
from sgdr.physics.laws import (
    CONTACTS,
    LN10,
    SPRING_LAWS,
    SPRING_REACTION,
    SYMMETRIC_STIFFNESS,
    Registry,
    soft_vector_eta,
    soft_vector_exponent,
    softplus,
)
from sgdr.physics.model import Ground, PhysicsInputError, PhysParams, SimState, SpringModel


class SimulationUnstable(RuntimeError):
    """The explicit integrator blew up or would blow up; the message names the setting."""


# --------------------------------------------------------------------------------------------
# Spring forces
# --------------------------------------------------------------------------------------------


def _pair_force(xa, xb, va, vb, l, k_s, eta, zeta0, law, cfg: PhysicsConfig):
    """Force on the source a of the spring a -> b (Eqs. 8, 9): Array3f.

    k_s: stiffness of the spring before the 1 / l_ij of Eq. 16; eta: soft-vector weight."""
    d = xa - xb
    inv_length = dr.rsqrt(dr.maximum(dr.squared_norm(d), cfg.min_length * cfg.min_length))
    length = dr.squared_norm(d) * inv_length
    inv_l = dr.rcp(l)
    g = law(length - l, inv_l, cfg.p_k, cfg.min_length)
    # one division per spring: F = -(k_s η g + ζ0 (v_a - v_b)·d̂) / l · d̂,  d̂ = d / |d|
    return (-(k_s * eta * g + zeta0 * dr.dot(va - vb, d) * inv_length) * inv_l * inv_length) * d


SPRINGS = Registry("springs variant", "physics.springs", PhysicsInputError)


@SPRINGS.register("directed")
def springs_directed(model: SpringModel, x, v, k, sp, zeta0, cfg: PhysicsConfig, rest=None):
    """Σ_r force of spring i -> j_r on anchor i, k_ij = k_i / l_ij (official). Array3f [N_A].
    rest: the springs' rest lengths when plasticity has moved them (`SimState.rest`), else the model's."""
    t = ad()
    rest = model.spring_rest_length if rest is None else rest
    n, n_k = model.n_anchors, model.n_k
    law = SPRING_LAWS.get_named(cfg.spring_law, "physics.spring_law")
    base = dr.arange(t.UInt32, n) * n_k

    def body(r, f):
        s = base + r
        j = dr.gather(t.UInt32, model.spring_j, s)
        l = dr.gather(t.Float, rest, s)
        eta = soft_vector_eta(sp, soft_vector_exponent(t.Float(r), n_k, model.n_c, cfg.soft_vector_normalised))
        xj = dr.gather(t.Array3f, x, j)
        vj = dr.gather(t.Array3f, v, j)
        return r + 1, f + _pair_force(x, xj, v, vj, l, k, eta, zeta0, law, cfg)

    _, f = dr.while_loop(
        state=(dr.zeros(t.UInt32, n), dr.zeros(t.Array3f, n)),
        cond=lambda r, f: r < n_k,
        body=body,
        labels=("r", "f"),
        label="springs_directed",
        max_iterations=-1,
    )
    return f


@SPRINGS.register("symmetric")
def springs_symmetric(model: SpringModel, x, v, k, sp, zeta0, cfg: PhysicsConfig, rest=None):
    """Outgoing springs i -> j plus the reaction of incoming springs a -> i. Array3f [N_A].
    rest: as `springs_directed`."""
    t = ad()
    rest = model.spring_rest_length if rest is None else rest
    n, n_k = model.n_anchors, model.n_k
    law = SPRING_LAWS.get_named(cfg.spring_law, "physics.spring_law")
    combine = SYMMETRIC_STIFFNESS.get_named(cfg.symmetric_stiffness, "physics.symmetric_stiffness")
    i = dr.arange(t.UInt32, n)
    base = i * n_k

    def eta_of(rank):
        return soft_vector_eta(sp, soft_vector_exponent(t.Float(rank), n_k, model.n_c, cfg.soft_vector_normalised))

    def body_out(r, f):
        s = base + r
        j = dr.gather(t.UInt32, model.spring_j, s)
        l = dr.gather(t.Float, rest, s)
        k_s = combine(k, dr.gather(t.Float, k, j))
        xj = dr.gather(t.Array3f, x, j)
        vj = dr.gather(t.Array3f, v, j)
        return r + 1, f + _pair_force(x, xj, v, vj, l, k_s, eta_of(r), zeta0, law, cfg)

    _, f_out = dr.while_loop(
        state=(dr.zeros(t.UInt32, n), dr.zeros(t.Array3f, n)),
        cond=lambda r, f: r < n_k,
        body=body_out,
        labels=("r", "f"),
        label="springs_symmetric_out",
        max_iterations=-1,
    )

    q_end = dr.gather(t.UInt32, model.in_offset, i + 1)

    def body_in(q, f):
        s = dr.gather(t.UInt32, model.in_spring, q)
        a = s // n_k  # source anchor of spring s
        l = dr.gather(t.Float, rest, s)
        k_s = combine(dr.gather(t.Float, k, a), k)
        xa = dr.gather(t.Array3f, x, a)
        va = dr.gather(t.Array3f, v, a)
        return q + 1, f - _pair_force(xa, x, va, v, l, k_s, eta_of(s - a * n_k), zeta0, law, cfg)

    # A separate accumulator: a sum loop must not take a differentiable input as its state.
    _, f_in = dr.while_loop(
        state=(dr.gather(t.UInt32, model.in_offset, i), dr.zeros(t.Array3f, n)),
        cond=lambda q, f: q < q_end,
        body=body_in,
        labels=("q", "f"),
        label="springs_symmetric_in",
        max_iterations=-1,
    )
    return f_out + f_in


# --------------------------------------------------------------------------------------------
# Checks
# --------------------------------------------------------------------------------------------


def soft_vector_numpy(kappa: float, n_k: int, n_c: int, normalised: bool) -> np.ndarray:
    """η for the spring ranks r = 0..n_k-1 as float64 NumPy (Eq. 15), for the stability bound."""
    e = soft_vector_exponent(np.arange(n_k, dtype=np.float64), n_k, n_c, normalised)
    sp = np.logaddexp(0.0, kappa)
    return np.where(e > 0, np.clip(2.0 - np.exp(sp * e), 0.0, 1.0), 1.0)


def effective_stiffness(model: SpringModel, params: PhysParams, cfg: PhysicsConfig) -> np.ndarray:
    """k_eff,i = Σ over the springs acting on anchor i of η k_s / l (linear part, strain 0),
    float64 [N_A]: the diagonal of the stiffness matrix that bounds the stable substep."""
    host = model_host(model)
    k = 10.0 ** to_numpy(params.log10_k)
    eta = soft_vector_numpy(scalar(params.kappa), model.n_k, model.n_c, cfg.soft_vector_normalised)
    j, l = host["spring_j"], host["spring_rest_length"]
    if not SPRING_REACTION.get_named(cfg.springs):
        return k * (eta[None, :] / l).sum(axis=1)
    combine = SYMMETRIC_STIFFNESS.get_named(cfg.symmetric_stiffness, "physics.symmetric_stiffness")
    k_s = combine(k[:, None], k[j]) * eta[None, :] / l  # the registry's functions work on NumPy too
    return k_s.sum(axis=1) + np.bincount(j.reshape(-1), weights=k_s.reshape(-1), minlength=model.n_anchors)


def model_host(model: SpringModel) -> dict:
    """NumPy copies of the topology, cached on the model (static, never traced)."""
    cache = model.__dict__.get("_host")
    if cache is None:
        cache = {
            "spring_j": to_numpy(model.spring_j, np.int64).reshape(model.n_anchors, model.n_k),
            "spring_rest_length": to_numpy(model.spring_rest_length).reshape(model.n_anchors, model.n_k),
            "particle_mass": to_numpy(model.particle_mass),
        }
        model.__dict__["_host"] = cache
    return cache


def stable_substeps(model: SpringModel, params: PhysParams, dt_frame: float, cfg: PhysicsConfig) -> int:
    """Smallest n_t with dt_frame / n_t <= cfl_factor sqrt(m_i / k_eff,i) for every anchor."""
    host = model_host(model)
    k_eff = effective_stiffness(model, params, cfg)
    dt_max = cfg.cfl_factor * float(np.min(np.sqrt(host["particle_mass"] / np.maximum(k_eff, 1e-30))))
    return int(np.ceil(dt_frame / dt_max))


def check_inputs(
    model: SpringModel, params: PhysParams, state: SimState, dt_frame: float, n_substeps: int, cfg: PhysicsConfig
) -> None:
    """Sizes, finiteness and the stability bound; raises naming the field / setting."""
    params.validate(model)
    for name in ("x", "v"):
        a = getattr(state, name)
        if dr.width(a) != model.n_anchors:
            raise PhysicsInputError(f"SimState.{name} has {dr.width(a)} entries, expected N_A={model.n_anchors}")
        if not bool(dr.all(dr.isfinite(dr.detach(a)), axis=None)):
            raise PhysicsInputError(f"SimState.{name} contains NaN/inf")
    if not (dt_frame > 0 and np.isfinite(dt_frame)):
        raise PhysicsInputError(f"dt_frame={dt_frame} must be a positive number of seconds")
    if not (isinstance(n_substeps, (int, np.integer)) and n_substeps >= 1):
        raise PhysicsInputError(f"n_substeps={n_substeps!r} must be a positive integer (physics.n_substeps)")
    if np.any(model_host(model)["particle_mass"] <= 0):
        raise PhysicsInputError("SpringModel.particle_mass must be positive (physics.m0)")
    need = stable_substeps(model, params, dt_frame, cfg)
    if n_substeps < need:
        k_max = float(np.max(to_numpy(params.log10_k)))
        raise SimulationUnstable(
            f"dt = dt_frame / n_substeps = {dt_frame / n_substeps:.3g} s is too large for max log10_k = "
            f"{k_max:.3g}: stability needs dt <= physics.cfl_factor ({cfg.cfl_factor}) x sqrt(m / k_eff), "
            f"i.e. n_substeps >= {need} (now {n_substeps}); raise physics.n_substeps or lower the stiffness"
        )


# --------------------------------------------------------------------------------------------
# Substep, frame, rollout
# --------------------------------------------------------------------------------------------


def frame_constants(model: SpringModel, params: PhysParams, ground: Ground, cfg: PhysicsConfig):
    """Per-frame values shared by all substeps (AD-attached to params where they depend on it);
    the ground and |g| as the model extensions make them (`sgdr.physics.extensions`)."""
    t = ad()
    point, normal = ground_plane(ground.point, ground.normal, cfg)
    return {
        "k": dr.exp(LN10 * params.log10_k),  # k_i [N_A]
        "sp": softplus(params.kappa),  # softplus(κ) [1]
        "inv_m": dr.rcp(model.particle_mass),  # [N_A]
        "point": t.Array3f(*map(float, point)),
        "normal": t.Array3f(*map(float, normal)),
        "g_norm": dr.opaque(t.Float, float(cfg.gravity_scale) * float(np.linalg.norm(to_numpy(params.gravity)))),
    }


class _Boundary:
    """The contact's view of the parameters (friction μ, restitution e)."""

    def __init__(self, friction, restitution):
        self.friction, self.restitution = friction, restitution


def euler_contact(x, v, f, gravity, friction, restitution, consts, dt: float, cfg: PhysicsConfig):
    """Eqs. 11-13 given the spring force f: semi-implicit Euler, then ground contact.
    consts = (inv_m, plane point, plane normal, |g|) from `frame_constants`."""
    inv_m, point, normal, g_norm = consts
    contact = CONTACTS.get_named(cfg.contact, "physics.contact")
    if cfg.gravity_scale != 1.0:  # extension: gravity's magnitude
        gravity = gravity * dr.opaque(ad().Float, float(cfg.gravity_scale))
    v = v + dt * (f * inv_m + gravity)  # Eq. 11
    if cfg.air_drag != 0.0:  # extension: implicit linear air drag
        v = v * dr.opaque(ad().Float, drag_factor(cfg, dt))
    x = x + dt * v  # Eq. 12
    return contact(x, v, point, normal, _Boundary(friction, restitution), dt, g_norm, cfg)  # Eq. 13


def contact_consts(c: dict):
    return c["inv_m"], c["point"], c["normal"], c["g_norm"]


def substep(
    model: SpringModel, params: PhysParams, state: SimState, ground_c: dict, dt: float, cfg: PhysicsConfig
) -> SimState:
    """One semi-implicit Euler substep (Eqs. 10-13), recorded AD; `ground_c` from `frame_constants`."""
    springs = SPRINGS.get_named(cfg.springs, "physics.springs")
    c = ground_c
    f = springs(model, state.x, state.v, c["k"], c["sp"], params.zeta0, cfg, rest=state.rest)
    x, v = euler_contact(
        state.x, state.v, f, params.gravity, params.friction, params.restitution, contact_consts(c), dt, cfg
    )
    if cfg.plastic_yield_strain != 0.0:
        # the yield gathers the new positions, and a gather evaluates its source: x alone, in a
        # kernel of its own, and then v in another that runs the spring loop again (a plastic
        # rollout took 4x an elastic one at small); x and v are evaluated together first
        dr.eval(x, v, f) if dr.grad_enabled(f) else dr.eval(x, v)
    rest = plastic_rest_lengths(model, x, state.rest, cfg)
    extra = () if rest is None else (rest,)
    if dr.grad_enabled(f):
        # f too, in the same kernel: the contact's backward re-reads the pre-contact x, v, which
        # would otherwise re-run (and re-compile) the spring loop for every substep
        dr.eval(x, v, f, *extra)
    else:
        dr.eval(x, v, *extra)  # no gradient: the whole substep is one kernel and f is never stored
    return SimState(x=x, v=v, rest=rest)


def plastic_rest_lengths(model: SpringModel, x, rest, cfg: PhysicsConfig):
    """Spring plasticity (`physics.plastic_yield_strain` ε, sgdr.physics.extensions): every rest
    length L moves just enough that the spring's strain |x_i - x_j| / L - 1 stays within ±ε, i.e.
    L <- clamp(L, d / (1 + ε), d / (1 - ε)) with d the current length; the yield is permanent.
    None when ε = 0 (elastic: the model's rest lengths, no state)."""
    eps = float(cfg.plastic_yield_strain)
    if eps == 0.0:
        return None
    t = ad()
    rest = model.spring_rest_length if rest is None else rest
    s = dr.arange(t.UInt32, model.n_anchors * model.n_k)
    xi = dr.gather(t.Array3f, x, s // model.n_k)
    xj = dr.gather(t.Array3f, x, dr.gather(t.UInt32, model.spring_j, s))
    d = dr.sqrt(dr.maximum(dr.squared_norm(xi - xj), cfg.min_length * cfg.min_length))
    lo = d * dr.opaque(t.Float, 1.0 / (1.0 + eps))
    hi = d * dr.opaque(t.Float, 1.0 / (1.0 - eps))
    return dr.minimum(dr.maximum(rest, lo), hi)


# How a frame's substeps are differentiated (`physics.adjoint`, see the module docstring):
# (model, params, state, constants, dt, n_substeps, cfg) -> SimState.
ADJOINTS = Registry("spring-mass adjoint", "physics.adjoint", PhysicsInputError)


@ADJOINTS.register("recorded")
def substeps_recorded(model, params, state, c, dt, n_substeps, cfg):
    """Recorded AD through every substep (the reference)."""
    for _ in range(n_substeps):
        state = substep(model, params, state, c, dt, cfg)
    return state


@ADJOINTS.register("gather")
def substeps_gather(model, params, state, c, dt, n_substeps, cfg):
    """One custom op per frame with a hand-written backward (sgdr/physics/adjoint.py)."""
    diff = (state.x, state.v, c["k"], c["sp"], params.zeta0, params.gravity, params.friction, params.restitution)
    if not dr.grad_enabled(*diff):
        return substeps_recorded(model, params, state, c, dt, n_substeps, cfg)
    if cfg.plastic_yield_strain != 0.0:
        raise PhysicsInputError(
            "physics.plastic_yield_strain: the gather adjoint has no backward through the yielding rest "
            "lengths; differentiate with physics.adjoint=recorded (forward rollouts need nothing)"
        )
    springs = SPRINGS.get_named(cfg.springs, "physics.springs")
    CONTACTS.get_named(cfg.contact, "physics.contact")  # fail here, naming the setting
    x, v = frame_gather(model, *diff, contact_consts(c), dt, n_substeps, cfg, springs, euler_contact)
    return SimState(x=x, v=v)


def simulate_frame(
    model: SpringModel,
    params: PhysParams,
    state: SimState,
    ground: Ground,
    dt_frame: float,
    n_substeps: int,
    cfg: PhysicsConfig,
    check: bool = True,
) -> SimState:
    """Advance one frame (dt_frame seconds) with n_substeps substeps; differentiable w.r.t.
    `params` and `state` (recorded AD). check: validate inputs and the stability bound before,
    and finiteness after (raises SimulationUnstable)."""
    # an unevaluated width-1 parameter (e.g. dr.maximum(opt["friction"], 0.0)) is resized in
    # place to N_A by Dr.Jit as soon as it meets an N_A-wide array; evaluated, it stays one value
    dr.eval(params.kappa, params.v0, params.friction, params.restitution, params.zeta0, params.gravity)
    if check:
        check_inputs(model, params, state, dt_frame, n_substeps, cfg)
    dt = float(dt_frame) / int(n_substeps)
    stepper = ADJOINTS.get_named(cfg.adjoint, "physics.adjoint")
    state = stepper(model, params, state, frame_constants(model, params, ground, cfg), dt, int(n_substeps), cfg)
    if check and not bool(dr.all(dr.isfinite(dr.detach(state.x)) & dr.isfinite(dr.detach(state.v)), axis=None)):
        raise SimulationUnstable(
            f"NaN/inf after {n_substeps} substeps of {dt:.3g} s (spring_law={cfg.spring_law}, "
            f"springs={cfg.springs}); raise physics.n_substeps or enable "
            f"physics.retry_on_nan"
        )
    return state


GRAD_MODES = Registry("gradient mode", "grad_mode", PhysicsInputError)
GRAD_MODES["full"] = lambda state: state  # gradients through every frame
GRAD_MODES["truncated"] = SimState.detach  # official: each frame from the detached previous one


def doubled_substeps(n_substeps: int, cfg: PhysicsConfig) -> int | None:
    """The one remedy for an unstable frame (official): n_t doubled. None when
    physics.retry_on_nan is off or 2 n_t would exceed physics.max_substeps. `rollout` and the
    dynamic stage's frame-by-frame schedule (sgdr.identify.dynamics) both use it."""
    if not cfg.retry_on_nan or 2 * int(n_substeps) > cfg.max_substeps:
        return None
    return 2 * int(n_substeps)


class Rollout(list):
    """The states of frames 0..n_frames-1 (a list of SimState), plus the substeps per frame
    the rollout used (`n_substeps`: the requested n_t, or more after the remedy)."""

    n_substeps: int = 0


def rollout(
    model: SpringModel,
    params: PhysParams,
    state0: SimState,
    ground: Ground,
    n_frames: int,
    dt_frame: float,
    cfg: PhysicsConfig,
    grad_mode: str = "full",
    n_substeps: int | None = None,
) -> Rollout:
    """States at frames 0..n_frames-1 (frame 0 = state0), each frame n_substeps substeps
    (default physics.n_substeps).

    grad_mode: how the frames are chained for gradients, chosen by the caller: "full"
    (recorded through every frame, the exact gradient) | "truncated" (official: every frame
    after the first starts from the detached previous state). Without gradients it makes no
    difference.

    With physics.retry_on_nan, too few substeps for the stability bound are doubled up front,
    and a rollout that produces NaN/inf starts again from state0 with twice the substeps (the
    official remedy, `doubled_substeps`), up to physics.max_substeps; the result's
    `n_substeps` says what was used."""
    enter: Callable = GRAD_MODES.get_named(grad_mode)
    n_sub = int(n_substeps or cfg.n_substeps)
    if n_frames < 1:
        raise PhysicsInputError(f"n_frames={n_frames} must be >= 1")
    if cfg.retry_on_nan:
        need = stable_substeps(model, params, dt_frame, cfg)
        while n_sub < need and (more := doubled_substeps(n_sub, cfg)):
            n_sub = more
    while True:
        try:
            states = Rollout([state0])
            for f in range(1, n_frames):
                start = states[-1] if f == 1 else enter(states[-1])
                states.append(simulate_frame(model, params, start, ground, dt_frame, n_sub, cfg))
            states.n_substeps = n_sub
            return states
        except SimulationUnstable as exc:
            more = doubled_substeps(n_sub, cfg)
            if more is None:
                if not cfg.retry_on_nan:
                    raise
                raise SimulationUnstable(
                    f"{exc}; physics.retry_on_nan doubled n_t up to {n_sub}, physics.max_substeps "
                    f"({cfg.max_substeps}) stops it: raise physics.max_substeps or lower the stiffness"
                ) from exc
            n_sub = more  # the official remedy: start again with twice the substeps
