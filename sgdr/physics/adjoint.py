"""Hand-written, gather-only adjoint of the spring-mass substeps of one frame (Eqs. 8-17).

`frame_gather(...)` runs the n_t substeps of a frame as one `dr.CustomOp` (`_Frame`): the
forward is the ordinary spring sum + Euler + contact on detached inputs, keeping each substep's
x, v and spring force f; the backward walks the substeps in reverse, differentiating the
elementwise Euler update and contact by recorded AD of a small throw-away graph and the spring
sum by `spring_forces_adjoint` below. Its inputs x, v (Array3f [N_A]), k (k_i, Float [N_A]),
sp = softplus(κ), ζ0, g, μ, e (broadcast to N_A) keep whatever AD graph they carry upstream
(the previous frame, exp(ln10 log10 k_i), the softplus, the parameters).

The adjoint of one spring s = (a -> b) with force F_s = c d on its source a (d = x_a - x_b,
c = -(k_s η g(Δl) + ζ0 (v_a - v_b)·d / |d|) / (l |d|), see `_pair_adjoint`) and cotangent
G_s (directed: F̄_a; symmetric, where b feels -F_s: F̄_a - F̄_b) is
    x̄_a += d̄_s, x̄_b -= d̄_s, v̄_a += ū_s, v̄_b -= ū_s,  k̄ via k̄_s, sp̄ via η̄_s, ζ̄0 via ζ̄_s.
Scattering those to b would need atomics. Instead each anchor gathers its own terms in two
per-anchor sum loops, like the forward: over its outgoing springs (it is a; these also give
the per-anchor partial sums of sp̄ and ζ̄0, reduced with `dr.sum`) and, through the incoming
lists `in_spring` / `in_offset`, over the springs that point at it (it is b). Every spring's
local adjoint is thus computed twice, once from each end, but there are no scatters at all.

Memory: the op's tape is x, v, f per substep (36 bytes per anchor and substep); nothing per
spring.
"""

from __future__ import annotations

from collections.abc import Callable

import drjit as dr

from sgdr.backend import ad
from sgdr.physics.config import PhysicsConfig
from sgdr.physics.laws import (
    SPRING_LAW_SLOPES,
    SPRING_REACTION,
    SYMMETRIC_STIFFNESS,
    SYMMETRIC_STIFFNESS_PARTIALS,
    soft_vector_eta,
    soft_vector_eta_slope,
    soft_vector_exponent,
)
from sgdr.physics.model import SpringModel


def _pair_adjoint(xa, xb, va, vb, l, k_s, eta, zeta0, G, law_slope, cfg: PhysicsConfig):
    """Reverse-mode derivative of `_pair_force` (simulate.py) for the cotangent G of its output.

    Returns (d̄, ū, k̄_s, η̄, ζ̄0): the adjoints of d = x_a - x_b (Array3f), u = v_a - v_b
    (Array3f), the spring stiffness k_s, the soft-vector weight η and ζ0 (Float each). It
    follows the forward's operations step by step, in reverse:
        r2 = |d|², ι = rsqrt(max(r2, ε²)), Δl = r2 ι - l, w = u·d,
        A = k_s η g(Δl) + ζ0 w ι,   c = -A ι / l,   F = c d."""
    d = xa - xb
    r2 = dr.squared_norm(d)
    eps2 = cfg.min_length * cfg.min_length
    iota = dr.rsqrt(dr.maximum(r2, eps2))  # 1 / |d|
    inv_l = dr.rcp(l)
    g, g_slope = law_slope(r2 * iota - l, inv_l, cfg.p_k, cfg.min_length)
    u = va - vb
    w = dr.dot(u, d)
    A = k_s * eta * g + zeta0 * w * iota
    c = -A * inv_l * iota
    # F = c d
    c_bar = dr.dot(G, d)
    d_bar = c * G
    # c = -A ι / l
    A_bar = -c_bar * inv_l * iota
    iota_bar = -c_bar * A * inv_l
    # A = k_s η g + ζ0 w ι
    k_s_bar = A_bar * eta * g
    eta_bar = A_bar * k_s * g
    zeta0_bar = A_bar * w * iota
    w_bar = A_bar * zeta0 * iota
    iota_bar += A_bar * zeta0 * w
    dl_bar = A_bar * k_s * eta * g_slope
    # w = u·d
    u_bar = w_bar * d
    d_bar += w_bar * u
    # Δl = r2 ι - l, ι = rsqrt(max(r2, ε²))
    iota_bar += dl_bar * r2
    r2_bar = dl_bar * iota + dr.select(r2 > eps2, -0.5 * iota * iota * iota * iota_bar, 0.0)
    d_bar += 2.0 * r2_bar * d
    return d_bar, u_bar, k_s_bar, eta_bar, zeta0_bar


def spring_forces_adjoint(model: SpringModel, x, v, k, sp, zeta0, f_bar, cfg: PhysicsConfig):
    """x̄, v̄ (Array3f [N_A]), k̄ (Float [N_A]) of the spring sum for the cotangent f_bar
    (Array3f [N_A]) of its output, and per-anchor partial sums of sp̄, ζ̄0 (Float [N_A]: the
    adjoint of sp, ζ0 is their sum). All inputs detached; sp, ζ0 of width 1 or N_A. The
    results are left lazy: the caller evaluates them together with its own sums."""
    t = ad()
    n, n_k = model.n_anchors, model.n_k
    symmetric = SPRING_REACTION.get_named(cfg.springs)  # spring s also pushes its target back
    law_slope = SPRING_LAW_SLOPES.get_named(cfg.spring_law, "physics.spring_law")
    combine = SYMMETRIC_STIFFNESS.get_named(cfg.symmetric_stiffness, "physics.symmetric_stiffness")
    partials = SYMMETRIC_STIFFNESS_PARTIALS.get_named(cfg.symmetric_stiffness, "physics.symmetric_stiffness")
    i = dr.arange(t.UInt32, n)
    base = i * n_k

    def eta_of(rank):
        e = soft_vector_exponent(t.Float(rank), n_k, model.n_c, cfg.soft_vector_normalised)
        return soft_vector_eta(sp, e), soft_vector_eta_slope(sp, e)

    # ---- outgoing springs i -> j: this anchor is the source a ------------------------------
    def body_out(r, xb, vb, kb, spb, zb):
        s = base + r
        j = dr.gather(t.UInt32, model.spring_j, s)
        l = dr.gather(t.Float, model.spring_rest_length, s)
        xj = dr.gather(t.Array3f, x, j)
        vj = dr.gather(t.Array3f, v, j)
        eta, eta_slope = eta_of(r)
        if symmetric:
            kj = dr.gather(t.Float, k, j)
            k_s, dk = combine(k, kj), partials(k, kj)[0]
            G = f_bar - dr.gather(t.Array3f, f_bar, j)
        else:
            k_s, dk, G = k, 1.0, f_bar
        d_bar, u_bar, k_s_bar, eta_bar, z_bar = _pair_adjoint(x, xj, v, vj, l, k_s, eta, zeta0, G, law_slope, cfg)
        return r + 1, xb + d_bar, vb + u_bar, kb + dk * k_s_bar, spb + eta_slope * eta_bar, zb + z_bar

    zeros3, zeros = dr.zeros(t.Array3f, n), dr.zeros(t.Float, n)
    _, x_out, v_out, k_bar, sp_part, z_part = dr.while_loop(
        state=(dr.zeros(t.UInt32, n), zeros3, zeros3, zeros, zeros, zeros),
        cond=lambda r, *_: r < n_k,
        body=body_out,
        labels=("r", "x_bar", "v_bar", "k_bar", "sp_bar", "zeta0_bar"),
        label="springs_adjoint_out",
        max_iterations=-1,
    )

    # ---- incoming springs a -> i: this anchor is the target b ------------------------------
    q_end = dr.gather(t.UInt32, model.in_offset, i + 1)

    def body_in(q, xb, vb, kb):
        s = dr.gather(t.UInt32, model.in_spring, q)
        a = s // n_k
        l = dr.gather(t.Float, model.spring_rest_length, s)
        xa = dr.gather(t.Array3f, x, a)
        va = dr.gather(t.Array3f, v, a)
        ka = dr.gather(t.Float, k, a)
        eta, _ = eta_of(s - a * n_k)
        G = dr.gather(t.Array3f, f_bar, a)
        if symmetric:
            k_s, dk = combine(ka, k), partials(ka, k)[1]
            G = G - f_bar
        else:
            k_s, dk = ka, 0.0  # a directed spring's stiffness is its source's
        d_bar, u_bar, k_s_bar, _, _ = _pair_adjoint(xa, x, va, v, l, k_s, eta, zeta0, G, law_slope, cfg)
        return q + 1, xb - d_bar, vb - u_bar, kb + dk * k_s_bar

    _, x_in, v_in, k_in = dr.while_loop(
        state=(dr.gather(t.UInt32, model.in_offset, i), zeros3, zeros3, zeros),
        cond=lambda q, *_: q < q_end,
        body=body_in,
        labels=("q", "x_bar", "v_bar", "k_bar"),
        label="springs_adjoint_in",
        max_iterations=-1,
    )
    x_bar, v_bar = x_out + x_in, v_out + v_in
    k_bar = k_bar + k_in if symmetric else k_bar
    return x_bar, v_bar, k_bar, sp_part, z_part


class _Frame(dr.CustomOp):
    """The n_t substeps of one frame as one custom op.

    Forward: the substeps on detached inputs, keeping each substep's (x, v, f) as the tape.
    Backward, substep by substep in reverse: the Euler update and contact (elementwise, a few
    operations per anchor) by recorded AD of a throw-away graph on the taped values, then the
    spring sum by `spring_forces_adjoint`; the adjoint state and the per-anchor parameter
    accumulators are evaluated once per substep. The outer AD graph thus holds one node per
    frame instead of dozens per substep: a per-substep op made the traversal itself grow
    faster than the number of frames (2 frames 4.9 s, 3 frames 12 s of backward at 256 x 32,
    kernels ~1 s of it)."""

    def eval(self, x, v, k, sp, zeta0, gravity, friction, restitution, model, consts, dt, n_sub, cfg, forces, step):
        self.model, self.consts, self.dt, self.cfg, self.step = model, consts, dt, cfg, step
        self.params = (k, sp, zeta0, gravity, friction, restitution)
        dr.eval(k, sp, zeta0, gravity, friction, restitution)
        self.tape = []
        for _ in range(n_sub):
            f = forces(model, x, v, k, sp, zeta0, cfg)
            x_next, v_next = step(x, v, f, gravity, friction, restitution, consts, dt, cfg)
            dr.eval(x_next, v_next, f)
            self.tape.append((x, v, f))
            x, v = x_next, v_next
        return x, v

    def forward(self):
        raise NotImplementedError(
            "physics.adjoint='gather' implements reverse mode only; use physics.adjoint='recorded' for forward-mode AD"
        )

    def backward(self):
        t = ad()
        n = self.model.n_anchors
        zeros3, zeros = dr.zeros(t.Array3f, n), dr.zeros(t.Float, n)
        x_bar, v_bar = self.grad_out()
        x_bar, v_bar = x_bar + zeros3, v_bar + zeros3  # an unused output's cotangent is a literal 0
        k, sp, zeta0, gravity, friction, restitution = self.params
        k_bar, sp_bar, z_bar, g_bar, mu_bar, e_bar = zeros, zeros, zeros, zeros3, zeros, zeros
        for x, v, f in reversed(self.tape):
            with dr.isolate_grad():
                xs, vs, fs, gs, mus, es = (dr.detach(a) for a in (x, v, f, gravity, friction, restitution))
                dr.enable_grad(xs, vs, fs, gs, mus, es)
                x_next, v_next = self.step(xs, vs, fs, gs, mus, es, self.consts, self.dt, self.cfg)
                dr.backward_from(dr.dot(x_next, x_bar) + dr.dot(v_next, v_bar))
                gx, gv, f_bar, gg, gmu, ge = (dr.grad(a) for a in (xs, vs, fs, gs, mus, es))
            dr.eval(f_bar)  # the adjoint loops gather it at the neighbours
            sx, sv, sk, ssp, sz = spring_forces_adjoint(self.model, x, v, k, sp, zeta0, f_bar, self.cfg)
            x_bar, v_bar = gx + sx, gv + sv
            k_bar, sp_bar, z_bar = k_bar + sk, sp_bar + ssp, z_bar + sz
            g_bar, mu_bar, e_bar = g_bar + gg, mu_bar + gmu, e_bar + ge
            dr.eval(x_bar, v_bar, k_bar, sp_bar, z_bar, g_bar, mu_bar, e_bar)
        self.tape = []
        for name, value in (
            ("x", x_bar),
            ("v", v_bar),
            ("k", k_bar),
            ("sp", sp_bar),
            ("zeta0", z_bar),
            ("gravity", g_bar),
            ("friction", mu_bar),
            ("restitution", e_bar),
        ):
            self.set_grad_in(name, value)

    def name(self):
        return "SpringMassFrame"


def frame_gather(
    model: SpringModel,
    x,
    v,
    k,
    sp,
    zeta0,
    gravity,
    friction,
    restitution,
    consts,
    dt: float,
    n_sub: int,
    cfg: PhysicsConfig,
    forces: Callable,
    step: Callable,
):
    """(x, v) after n_sub substeps, differentiable in every array argument through `_Frame`.

    forces(model, x, v, k, sp, zeta0, cfg) -> f is the forward spring sum; step(x, v, f, gravity,
    friction, restitution, consts, dt, cfg) -> (x, v) the Euler update and contact. The width-1
    parameters enter broadcast to N_A, so that the op hands back per-anchor adjoints and Dr.Jit's
    broadcast reduces them (width-1 adjoints made Dr.Jit compile a kernel per call)."""
    t = ad()
    wide, wide3 = dr.zeros(t.Float, model.n_anchors), dr.zeros(t.Array3f, model.n_anchors)
    return dr.custom(
        _Frame,
        x,
        v,
        k,
        sp + wide,
        zeta0 + wide,
        gravity + wide3,
        friction + wide,
        restitution + wide,
        model,
        consts,
        dt,
        n_sub,
        cfg,
        forces,
        step,
    )
