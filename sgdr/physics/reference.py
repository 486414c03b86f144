"""Slow float64 NumPy reference of the simulator (spring force, contact, substep, frame, rollout),
written independently of the Dr.Jit code from the same equations. Used only by tests and by
the benchmark's reference timing; never by the pipeline.

Arrays: x, v [N_A, 3] float64 world; spring_j [N_A, n_k] int; spring_rest_length [N_A, n_k];
params as a dict of float64 (`params_numpy`).
"""

from __future__ import annotations

import numpy as np

from sgdr.arrays import array3_to_points, scalar, to_numpy
from sgdr.physics.config import PhysicsConfig
from sgdr.physics.extensions import ground_plane


def params_numpy(params) -> dict:
    """PhysParams -> dict of float64 arrays/scalars (log10_k [N_A], v0 [3], gravity [3])."""

    return {
        "log10_k": to_numpy(params.log10_k),
        "kappa": scalar(params.kappa),
        "v0": array3_to_points(params.v0)[0],
        "friction": scalar(params.friction),
        "restitution": scalar(params.restitution),
        "zeta0": scalar(params.zeta0),
        "gravity": array3_to_points(params.gravity)[0],
    }


def model_numpy(model) -> dict:
    """SpringModel -> dict: x_rest [N_A,3], spring_j / spring_rest_length [N_A, n_k], mass [N_A]."""
    d = model.numpy()
    n, n_k = model.n_anchors, model.n_k
    d["spring_j"] = d["spring_j"].reshape(n, n_k)
    d["spring_rest_length"] = d["spring_rest_length"].reshape(n, n_k)
    return d


def soft_vector(kappa: float, n_k: int, n_c: int, normalised: bool) -> np.ndarray:
    """η for the springs of 0-based rank r = 0..n_k-1 (Eq. 15). Official (`normalised`): n_c
    ones, then 2 - exp(softplus(κ))^(q / (n_k - n_c)) for q = 0..n_k-n_c-1 (its first soft spring
    still has η = 1); paper as printed: exponent j - n_c for the 1-based rank j = r + 1."""
    eta = np.ones(n_k)
    base = np.exp(np.log1p(np.exp(kappa)))  # exp(softplus(κ))
    for r in range(n_c, n_k):
        e = (r - n_c) / (n_k - n_c) if normalised else float(r + 1 - n_c)
        eta[r] = min(max(2.0 - base**e, 0.0), 1.0)
    return eta


def spring_force(m: dict, p: dict, x: np.ndarray, v: np.ndarray, cfg: PhysicsConfig) -> np.ndarray:
    """Total spring + damping force on every anchor (Eqs. 8, 9, 15-17), [N_A, 3]."""
    j, l = m["spring_j"], m["spring_rest_length"]
    n_k = j.shape[1]
    eta = soft_vector(p["kappa"], n_k, m["n_c"], cfg.soft_vector_normalised)[None, :]
    k = 10.0 ** p["log10_k"]
    d = x[:, None, :] - x[j]  # [N, n_k, 3] from j to i
    length = np.sqrt(np.maximum((d * d).sum(-1), cfg.min_length**2))
    d_hat = d / length[..., None]
    dl = length - l
    if cfg.spring_law == "paper":
        g = dl * np.maximum(np.abs(dl), cfg.min_length) ** cfg.p_k
    elif cfg.spring_law == "official":
        dl = np.where(np.abs(dl) < 1e-6, 0.0, dl)  # the official dead zone
        g = dl * (1.0 + np.abs(dl) / l) ** cfg.p_k
    else:
        raise ValueError(cfg.spring_law)
    if cfg.springs == "directed":
        k_s = np.broadcast_to(k[:, None], j.shape)
    elif cfg.symmetric_stiffness == "harmonic":
        k_s = 2.0 * k[:, None] * k[j] / (k[:, None] + k[j])
    else:
        k_s = 0.5 * (k[:, None] + k[j])
    rel_v = ((v[:, None, :] - v[j]) * d_hat).sum(-1)
    f = (-(k_s * eta * g + p["zeta0"] * rel_v) / l)[..., None] * d_hat  # on i from spring i->j
    force = f.sum(axis=1)
    if cfg.springs == "symmetric":
        np.add.at(force, j.reshape(-1), -f.reshape(-1, 3))
    return force


def contact(x, v, point, normal, p: dict, dt: float, cfg: PhysicsConfig):
    """Ground contact B (Eq. 13), per anchor in a plain loop."""
    x, v = x.copy(), v.copy()
    g_norm = np.linalg.norm(p["gravity"])
    for a in range(x.shape[0]):
        phi = float(np.dot(x[a] - point, normal))
        if phi > 0:  # on the plane (phi == 0) counts as touching
            continue
        x[a] = x[a] - phi * normal
        v_n = float(np.dot(v[a], normal))
        v_t = v[a] - v_n * normal
        if cfg.contact == "project":
            u = -v_n
            rebound = cfg.contact_restitution * u if u > cfg.rest_speed_factor * g_norm * dt else 0.0
            v[a] = p["friction"] * v_t + rebound * normal
        elif cfg.contact == "coulomb":
            if v_n >= 0:
                continue
            u = -v_n
            bounce = p["restitution"] * u if u > cfg.rest_speed_factor * g_norm * dt else 0.0
            speed_t = max(np.linalg.norm(v_t), cfg.min_length)
            scale = max(1.0 - p["friction"] * (u + bounce) / speed_t, 0.0)
            v[a] = scale * v_t + bounce * normal
        else:
            raise ValueError(cfg.contact)
    return x, v


def substep(m: dict, p: dict, x, v, ground, dt: float, cfg: PhysicsConfig):
    """Semi-implicit Euler (Eqs. 10-12) then contact (Eq. 13), with the model extensions
    (`sgdr.physics.extensions`: gravity scale, implicit air drag, moved / tilted ground, spring
    plasticity, which updates m["spring_rest_length"] in place)."""

    p = dict(p, gravity=float(cfg.gravity_scale) * np.asarray(p["gravity"], dtype=np.float64))
    f = spring_force(m, p, x, v, cfg)
    v = (v + dt * (f / m["particle_mass"][:, None] + p["gravity"][None, :])) / (1.0 + float(cfg.air_drag) * dt)
    x = x + dt * v
    point, normal = ground_plane(ground.point, ground.normal, cfg)
    x, v = contact(x, v, point, normal, p, dt, cfg)
    eps = float(cfg.plastic_yield_strain)
    if eps != 0.0:  # plasticity: the rest lengths (m's, updated in place) yield to keep |strain| <= eps
        length = np.sqrt(np.maximum(((x[:, None, :] - x[m["spring_j"]]) ** 2).sum(-1), cfg.min_length**2))
        m["spring_rest_length"] = np.clip(m["spring_rest_length"], length / (1.0 + eps), length / (1.0 - eps))
    return x, v


def simulate_frame(m: dict, p: dict, x, v, ground, dt_frame: float, n_substeps: int, cfg: PhysicsConfig):
    dt = dt_frame / n_substeps
    for _ in range(n_substeps):
        x, v = substep(m, p, x, v, ground, dt, cfg)
    return x, v


def rollout(
    m: dict, p: dict, ground, n_frames: int, dt_frame: float, n_substeps: int, cfg: PhysicsConfig, x0=None, v0=None
):
    """[(x, v)] for frames 0..n_frames-1 from rest positions (or x0) moving with p["v0"] (or v0).
    With plasticity m's rest lengths evolve: the rollout works on a copy of m."""
    m = dict(m, spring_rest_length=np.array(m["spring_rest_length"], dtype=np.float64))
    x = m["x_rest"].copy() if x0 is None else np.array(x0, dtype=np.float64)
    v = np.broadcast_to(p["v0"], x.shape).copy() if v0 is None else np.array(v0, dtype=np.float64)
    out = [(x, v)]
    for _ in range(1, n_frames):
        x, v = simulate_frame(m, p, x, v, ground, dt_frame, n_substeps, cfg)
        out.append((x, v))
    return out
