"""The swappable pieces of the simulator, chosen by name from `PhysicsConfig` through one
`sgdr.registry.Registry` each: spring law (Eq. 8), symmetric-spring stiffness, soft vector
(Eq. 15) and ground contact (Eq. 13). Each entry is a pure Dr.Jit function; `sgdr.physics.reference` holds their
float64 NumPy references, written separately.
"""

from __future__ import annotations

import math

import drjit as dr

from sgdr.physics.model import PhysicsInputError
from sgdr.registry import Registry

# --------------------------------------------------------------------------------------------
# Spring laws (Eq. 8): F_k = -η_j k_ij g(Δl) d̂ with Δl = |x_i - x_j| - l_ij.
# Each takes (Δl, 1 / l_ij, p_k, eps) and returns g(Δl) (scene units): k_ij g(Δl) is a force.
# --------------------------------------------------------------------------------------------
SPRING_LAWS = Registry("spring law", "physics.spring_law", PhysicsInputError)


def _pow(a, p: float):
    """a^p for a > 0 and a Python-float exponent (sqrt when p = 0.5, the paper's p_k)."""
    if p == 0.0:
        return 1.0
    if p == 1.0:
        return a
    if p == 0.5:
        return dr.sqrt(a)
    return dr.power(a, p)


def _pow_and_slope(a, p: float):
    """(a^p, d(a^p)/da) for a > 0 and a Python-float exponent, the same operations as `_pow`."""
    if p == 0.0:
        return 1.0, 0.0
    if p == 1.0:
        return a, 1.0
    if p == 0.5:
        r = dr.sqrt(a)
        return r, 0.5 * dr.rcp(r)
    r = dr.power(a, p)
    return r, p * r * dr.rcp(a)


@SPRING_LAWS.register("paper")
def law_paper(dl, inv_l, p_k: float, eps: float):
    """Eq. 8 as printed: g = Δl |Δl|^p_k (|Δl| floored at eps so the gradient stays finite)."""
    return dl * _pow(dr.maximum(dr.abs(dl), eps), p_k)


OFFICIAL_STRETCH_DEAD_ZONE = 1.0e-6
"""Scene units. The official `compute_force` zeroes a spring whose |Δl| is below this (its
`self.edge`): part of the official model, not a tuning knob."""


def _official_dead_zone(dl):
    """Δl, set to 0 where |Δl| < OFFICIAL_STRETCH_DEAD_ZONE (strict, as the official code)."""
    return dr.select(dr.abs(dl) < OFFICIAL_STRETCH_DEAD_ZONE, 0.0, dl)


@SPRING_LAWS.register("official")
def law_official(dl, inv_l, p_k: float, eps: float):
    """Official code: g = Δl (1 + |Δl| / l_ij)^p_k, i.e. Hookean times (1 + |strain|)^p_k, with
    Δl = 0 inside the dead zone |Δl| < 1e-6."""
    dl = _official_dead_zone(dl)
    return dl * _pow(1.0 + dr.abs(dl) * inv_l, p_k)


# (g, dg/dΔl) of each law, for the hand-written adjoint (sgdr/physics/adjoint.py); same arguments.
SPRING_LAW_SLOPES = Registry("spring law", "physics.spring_law", PhysicsInputError)


@SPRING_LAW_SLOPES.register("paper")
def law_paper_slope(dl, inv_l, p_k: float, eps: float):
    """g = Δl m^p_k with m = max(|Δl|, eps): g' = m^p_k + |Δl| p_k m^(p_k - 1) where |Δl| > eps."""
    a = dr.abs(dl)
    m_p, m_p_slope = _pow_and_slope(dr.maximum(a, eps), p_k)
    return dl * m_p, m_p + dr.select(a > eps, a * m_p_slope, 0.0)


@SPRING_LAW_SLOPES.register("official")
def law_official_slope(dl, inv_l, p_k: float, eps: float):
    """g = Δl q^p_k with q = 1 + |Δl| / l_ij: g' = q^p_k + |Δl| / l_ij p_k q^(p_k - 1); g = g' = 0
    inside the dead zone (g is constant there)."""
    dead = dr.abs(dl) < OFFICIAL_STRETCH_DEAD_ZONE
    dl = _official_dead_zone(dl)
    a = dr.abs(dl)
    q_p, q_p_slope = _pow_and_slope(1.0 + a * inv_l, p_k)
    return dl * q_p, dr.select(dead, 0.0, q_p + a * inv_l * q_p_slope)


# --------------------------------------------------------------------------------------------
# Stiffness of a symmetric spring (i, j) from the two anchors' k_i, k_j (Eq. 16 divides by l_ij).
# --------------------------------------------------------------------------------------------
SYMMETRIC_STIFFNESS = Registry("symmetric-spring stiffness", "physics.symmetric_stiffness", PhysicsInputError)


@SYMMETRIC_STIFFNESS.register("harmonic")
def stiffness_harmonic(k_i, k_j):
    """2 k_i k_j / (k_i + k_j): two half-springs of stiffness 2 k_i and 2 k_j in series."""
    return 2.0 * k_i * k_j / (k_i + k_j)


@SYMMETRIC_STIFFNESS.register("arithmetic")
def stiffness_arithmetic(k_i, k_j):
    """(k_i + k_j) / 2."""
    return 0.5 * (k_i + k_j)


# Whether the springs variant (`physics.springs`, its force sums are `SPRINGS` in
# sgdr/physics/simulate.py) makes spring s = (i -> j) push its target j back (Newton's third
# law): what the hand-written adjoint and the stability bound need to know of each variant.
SPRING_REACTION = Registry(
    "springs variant", "physics.springs", PhysicsInputError, {"directed": False, "symmetric": True}
)


# (∂k_s/∂k_i, ∂k_s/∂k_j) of each symmetric stiffness, for the hand-written adjoint.
SYMMETRIC_STIFFNESS_PARTIALS = Registry("symmetric-spring stiffness", "physics.symmetric_stiffness", PhysicsInputError)


@SYMMETRIC_STIFFNESS_PARTIALS.register("harmonic")
def stiffness_harmonic_partials(k_i, k_j):
    """(2 k_j² / (k_i + k_j)², 2 k_i² / (k_i + k_j)²)."""
    w = 2.0 * dr.square(dr.rcp(k_i + k_j))
    return w * dr.square(k_j), w * dr.square(k_i)


@SYMMETRIC_STIFFNESS_PARTIALS.register("arithmetic")
def stiffness_arithmetic_partials(k_i, k_j):
    """(1/2, 1/2)."""
    return 0.5, 0.5


# --------------------------------------------------------------------------------------------
# Soft vector (Eq. 15): η = clamp(2 - exp(softplus(κ))^e, 0, 1) where e > 0, else 1, for the
# spring of 0-based rank r (nearest first). Official (`normalised`): e_r = (r - n_c) / (n_k - n_c),
# so ranks r <= n_c keep η = 1 (the official code concatenates n_c ones with
# arange(n_k - n_c) / (n_k - n_c)); paper as printed, with the 1-based j = r + 1: e_j = j - n_c.
# --------------------------------------------------------------------------------------------


def softplus(a):
    """log(1 + e^a), smooth everywhere (its derivative at 0 is 1/2: κ = 0 is the default, so
    no max/abs kinks here), = a above 20 where log1p(e^a) - a underflows in float32."""
    return dr.select(a > 20.0, a, dr.log(1.0 + dr.exp(dr.minimum(a, 20.0))))


def soft_vector_exponent(rank, n_k: int, n_c: int, normalised: bool):
    """The exponent e for 0-based spring ranks `rank` (Float or NumPy, any width); <= 0 means
    full weight. Works on NumPy arrays too (the stability bound and the reference use it)."""
    if normalised:
        return (rank - float(n_c)) / float(max(n_k - n_c, 1))
    return rank + 1.0 - float(n_c)


def soft_vector_eta(softplus_kappa, exponent):
    """η = clamp(2 - exp(softplus(κ) e_j), 0, 1) where e_j > 0, else 1 (Eq. 15)."""
    eta = dr.clip(2.0 - dr.exp(softplus_kappa * exponent), 0.0, 1.0)
    return dr.select(exponent > 0, eta, 1.0)


def soft_vector_eta_slope(softplus_kappa, exponent):
    """dη/d softplus(κ) = -e_j exp(softplus(κ) e_j) where η is strictly inside (0, 1), else 0."""
    p = dr.exp(softplus_kappa * exponent)
    inside = (exponent > 0) & (p > 1.0) & (p < 2.0)
    return dr.select(inside, -exponent * p, 0.0)


# --------------------------------------------------------------------------------------------
# Ground contact B (Eq. 13), applied after every substep's position update.
# Signature: (x, v, point, normal, params, dt, g_norm, cfg) -> (x, v); point/normal Array3f [1].
# --------------------------------------------------------------------------------------------
CONTACTS = Registry("contact model", "physics.contact", PhysicsInputError)


@CONTACTS.register("project")
def contact_project(x, v, point, normal, params, dt: float, g_norm, cfg):
    """Official: an anchor on or below the plane (height <= 0, inclusive as the official
    `apply_bc`) is projected onto it, its normal velocity zeroed and its tangential velocity
    multiplied by μ (every substep, so the effective friction depends on n_t; the learned
    restitution is unused). The extension `physics.contact_restitution` e (0: the official law)
    gives an anchor that hits faster than the resting speed (rest_speed_factor |g| dt) the
    normal velocity e times its approach speed. An anchor lying exactly on the plane is touching: float32 rounding puts anchors
    there often (a projected anchor whose tiny normal step x + dt v rounds back to x)."""
    phi = dr.dot(x - point, normal)  # signed height above the plane
    below = phi <= 0
    v_n = dr.dot(v, normal)
    x = dr.select(below, x - phi * normal, x)
    v_new = params.friction * (v - v_n * normal)
    e = float(cfg.contact_restitution)
    if e != 0.0:  # extension (sgdr.physics.extensions): an impact faster than resting rebounds with e
        u = -v_n
        rebound = dr.select(u > cfg.rest_speed_factor * g_norm * dt, dr.opaque(type(u), e) * u, 0.0)
        v_new = v_new + rebound * normal
    v = dr.select(below, v_new, v)
    return x, v


@CONTACTS.register("coulomb")
def contact_coulomb(x, v, point, normal, params, dt: float, g_norm, cfg):
    """Impulse contact with restitution e and Coulomb friction μ, independent of n_t.

    An anchor on or below the plane is projected onto it. If it approaches (v_n < 0) the normal
    velocity becomes e |v_n| (0 below the resting speed rest_speed_factor |g| dt, so a body at
    rest does not jitter) and the tangential speed drops by μ times the normal impulse
    (1 + e) |v_n|, never below zero: per unit time that is μ times the normal force, whatever
    the substep.
    """
    phi = dr.dot(x - point, normal)
    below = phi <= 0
    v_n = dr.dot(v, normal)
    approach = below & (v_n < 0)
    u = -v_n  # approach speed (> 0 when approaching)
    bounce = dr.select(u > cfg.rest_speed_factor * g_norm * dt, params.restitution * u, 0.0)
    j_n = u + bounce  # normal impulse per unit mass
    v_t = v - v_n * normal
    speed_t = dr.sqrt(dr.maximum(dr.squared_norm(v_t), cfg.min_length * cfg.min_length))
    scale_t = dr.maximum(1.0 - params.friction * j_n / speed_t, 0.0)
    v_new = scale_t * v_t + bounce * normal
    x = dr.select(below, x - phi * normal, x)
    v = dr.select(approach, v_new, v)
    return x, v


# The boundary parameters Θ(B) each contact model uses (the ones the dynamic stage learns).
CONTACT_PARAMETERS = Registry(
    "contact model",
    "physics.contact",
    PhysicsInputError,
    {"project": ("friction",), "coulomb": ("friction", "restitution")},
)


LN10 = math.log(10.0)
