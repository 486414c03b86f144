"""The swappable pieces of the simulator, chosen by name from `PhysicsConfig` through one
registry each: spring law (Eq. 8), symmetric-spring stiffness, soft vector (Eq. 15) and ground
contact (Eq. 13). Each entry is a pure Dr.Jit function; `sgdr.physics.reference` holds their
float64 NumPy twins, written separately.
"""

from __future__ import annotations

import math
from typing import Callable

import drjit as dr

from sgdr.physics.model import PhysicsInputError


class Registry(dict):
    """name -> function, with a decorator to register and an error listing the known names."""

    def __init__(self, what: str):
        super().__init__()
        self.what = what

    def register(self, name: str) -> Callable:
        def deco(fn):
            self[name] = fn
            return fn

        return deco

    def get_named(self, name: str, setting: str):
        if name not in self:
            raise PhysicsInputError(f"{setting}={name!r} is not a known {self.what}; choose from {sorted(self)}")
        return self[name]


# --------------------------------------------------------------------------------------------
# Spring laws (Eq. 8): F_k = -η_j k_ij g(Δl) d̂ with Δl = |x_i - x_j| - l_ij.
# Each takes (Δl, 1 / l_ij, p_k, eps) and returns g(Δl) (scene units): k_ij g(Δl) is a force.
# --------------------------------------------------------------------------------------------
SPRING_LAWS = Registry("spring law")


def _pow(a, p: float):
    """a^p for a > 0 and a Python-float exponent (sqrt when p = 0.5, the paper's p_k)."""
    if p == 0.0:
        return 1.0
    if p == 1.0:
        return a
    if p == 0.5:
        return dr.sqrt(a)
    return dr.power(a, p)


@SPRING_LAWS.register("paper")
def law_paper(dl, inv_l, p_k: float, eps: float):
    """Eq. 8 as printed: g = Δl |Δl|^p_k (|Δl| floored at eps so the gradient stays finite)."""
    return dl * _pow(dr.maximum(dr.abs(dl), eps), p_k)


@SPRING_LAWS.register("official")
def law_official(dl, inv_l, p_k: float, eps: float):
    """Official code: g = Δl (1 + |Δl| / l_ij)^p_k, i.e. Hookean times (1 + |strain|)^p_k."""
    return dl * _pow(1.0 + dr.abs(dl) * inv_l, p_k)


# --------------------------------------------------------------------------------------------
# Stiffness of a symmetric spring (i, j) from the two anchors' k_i, k_j (Eq. 16 divides by l_ij).
# --------------------------------------------------------------------------------------------
SYMMETRIC_STIFFNESS = Registry("symmetric-spring stiffness")


@SYMMETRIC_STIFFNESS.register("harmonic")
def stiffness_harmonic(k_i, k_j):
    """2 k_i k_j / (k_i + k_j): two half-springs of stiffness 2 k_i and 2 k_j in series."""
    return 2.0 * k_i * k_j / (k_i + k_j)


@SYMMETRIC_STIFFNESS.register("arithmetic")
def stiffness_arithmetic(k_i, k_j):
    """(k_i + k_j) / 2."""
    return 0.5 * (k_i + k_j)


# --------------------------------------------------------------------------------------------
# Soft vector (Eq. 15): η_j = 1 for j <= n_c, else clamp(2 - exp(softplus(κ))^e_j, 0, 1),
# j = 1..n_k the rank of the spring (nearest first). Official: e_j = (j - n_c) / (n_k - n_c);
# paper as printed: e_j = j - n_c.
# --------------------------------------------------------------------------------------------


def softplus(a):
    """log(1 + e^a), smooth everywhere (its derivative at 0 is 1/2: κ = 0 is the default, so
    no max/abs kinks here), = a above 20 where log1p(e^a) - a underflows in float32."""
    return dr.select(a > 20.0, a, dr.log(1.0 + dr.exp(dr.minimum(a, 20.0))))


def soft_vector_exponent(rank, n_k: int, n_c: int, normalised: bool):
    """e_j for 0-based spring ranks `rank` (Float, any width); <= 0 means full weight."""
    j = rank + 1.0
    if normalised:
        return (j - n_c) / float(max(n_k - n_c, 1))
    return j - float(n_c)


def soft_vector_eta(softplus_kappa, exponent):
    """η = clamp(2 - exp(softplus(κ) e_j), 0, 1) where e_j > 0, else 1 (Eq. 15)."""
    eta = dr.clip(2.0 - dr.exp(softplus_kappa * exponent), 0.0, 1.0)
    return dr.select(exponent > 0, eta, 1.0)


# --------------------------------------------------------------------------------------------
# Ground contact B (Eq. 13), applied after every substep's position update.
# Signature: (x, v, point, normal, params, dt, g_norm, cfg) -> (x, v); point/normal Array3f [1].
# --------------------------------------------------------------------------------------------
CONTACTS = Registry("contact model")


@CONTACTS.register("project")
def contact_project(x, v, point, normal, params, dt: float, g_norm, cfg):
    """Official: an anchor below the plane is projected onto it, its normal velocity zeroed and
    its tangential velocity multiplied by μ (every substep, so the effective friction depends on
    n_t; restitution is unused)."""
    phi = dr.dot(x - point, normal)  # signed height above the plane
    below = phi < 0
    v_n = dr.dot(v, normal)
    x = dr.select(below, x - phi * normal, x)
    v = dr.select(below, params.friction * (v - v_n * normal), v)
    return x, v


@CONTACTS.register("coulomb")
def contact_coulomb(x, v, point, normal, params, dt: float, g_norm, cfg):
    """Impulse contact with restitution e and Coulomb friction μ, independent of n_t.

    An anchor below the plane is projected onto it. If it approaches (v_n < 0) the normal
    velocity becomes e |v_n| (0 below the resting speed rest_speed_factor |g| dt, so a body at
    rest does not jitter) and the tangential speed drops by μ times the normal impulse
    (1 + e) |v_n|, never below zero: per unit time that is μ times the normal force, whatever
    the substep.
    """
    phi = dr.dot(x - point, normal)
    below = phi < 0
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


LN10 = math.log(10.0)
