"""`physics.spring_law=official physics.springs=directed physics.contact=project` against a
reference written by hand from the official Spring-Gaus simulator's equations
(`lib/models/spring_mass/Spring_Mass.py` at 8a86490: `knn`, `compute_force`, `apply_bc`, `step`,
`forward`), in its own array layout ([N, n_k] per-spring arrays, ground as an axis and a
height, float32 like the official PyTorch code). It shares no code with sgdr's float64 twin
(`sgdr/physics/reference.py`), whose conventions once had the same off-by-one as the simulator.

What it pins down, each of which once differed (issue 12):
- the soft vector: n_c ones, then 2 - exp(softplus(κ))^(q / (n_k - n_c)), q = 0..n_k-n_c-1,
  so the first soft spring still has η = 1;
- contact: an anchor whose height is <= the ground (inclusive) is projected, its normal
  velocity zeroed and its tangential velocity multiplied by μ;
- the spring law zeroes stretches |Δl| < 1e-6.
"""

import drjit as dr
import numpy as np
import pytest

from sgdr.physics import Ground, PhysicsConfig, PhysParams, SimState, build_spring_model, rollout

F32 = np.float32
EPS, EDGE = 1e-14, 1e-6  # the official `self.eps`, `self.edge`


def official_knn(x, n_k):
    """knn_points(x, x, K=n_k + 1) with the first hit (the point itself) removed: [N, n_k]."""
    d2 = ((x[:, None, :] - x[None, :, :]) ** 2).sum(-1)
    idx = np.argsort(d2, axis=1, kind="stable")[:, 1 : n_k + 1]
    return np.sqrt(np.take_along_axis(d2, idx, axis=1)).astype(x.dtype), idx


def official_soft_vector(kappa, n_k, n_fix, dtype):
    """`forward`: n_fix ones, then clamp(2 - exp(softplus(κ))^(arange(n_k - n_fix) / (n_k - n_fix)), 0, 1)."""
    soft = np.arange(n_k - n_fix, dtype=dtype) / dtype(n_k - n_fix)
    soft = np.clip(2 - np.power(np.exp(np.log1p(np.exp(dtype(kappa)))), soft), 0, 1)
    return np.concatenate([np.ones(n_fix, dtype=dtype), soft])


class OfficialSpringMass:
    """The official per-frame simulation, DAMPING on with a fixed ζ, ground axis z (BC normal +z)."""

    def __init__(self, x_rest, n_k, n_c, log10_k, kappa, zeta0, mass, g, ground, friction, p_k, dtype=F32):
        self.t = dtype
        self.origin_len, self.knn_index = official_knn(x_rest.astype(dtype), n_k)
        K = np.power(dtype(10), log10_k.astype(dtype))[:, None] * np.ones((1, n_k), dtype)  # FIX_K: per anchor
        K = K / (self.origin_len + dtype(EPS))
        self.K = K * official_soft_vector(kappa, n_k, n_c, dtype)[None, :]
        self.damp = dtype(zeta0) / (self.origin_len + dtype(EPS))
        self.m, self.g, self.ground = dtype(mass), dtype(g), dtype(ground)
        self.fric, self.power = dtype(friction), dtype(p_k)

    def compute_force(self, xyz, v):
        t = self.t
        delta_pos = xyz[self.knn_index] - xyz[:, None, :]  # [N, k, 3]
        curr_len = np.sqrt((delta_pos**2).sum(-1))
        norm_delta_pos = delta_pos / (curr_len[..., None] + t(EPS))
        delta_len = curr_len - self.origin_len
        delta_len[(delta_len > -EDGE) & (delta_len < EDGE)] = 0.0
        force = (delta_len * self.K)[..., None] * norm_delta_pos
        force = force * ((1 + np.abs(curr_len / (self.origin_len + t(EPS)) - 1))[..., None] ** self.power)
        delta_v = v[self.knn_index] - v[:, None, :]
        force = force + (self.damp * (delta_v * norm_delta_pos).sum(-1))[..., None] * norm_delta_pos
        return force.sum(axis=1)

    def apply_bc(self, xyz, v):
        on = np.where(xyz[:, 2] <= self.ground)[0]
        v[on, 0] = self.fric * v[on, 0]
        v[on, 1] = self.fric * v[on, 1]
        v[on, 2] = 0
        xyz[on, 2] = self.ground
        return xyz, v

    def frame(self, xyz, v, dt_frame, n_step):
        t = self.t
        dt = t(dt_frame / n_step)
        for _ in range(n_step):
            force_sum = self.compute_force(xyz, v)
            force_sum[:, 2] += self.m * self.g
            v = v + force_sum * dt / self.m
            xyz = xyz + v * dt
            xyz, v = self.apply_bc(xyz, v)
        return xyz, v


N, N_K, N_C, P_K = 24, 10, 4, 0.5
GROUND = 0.25  # exactly representable: an anchor can sit exactly on it


def scene(case: str):
    """(x_rest, x0, v0, gravity): `drop` falls onto the ground through the frame; `on_plane`
    starts anchor 0 and its n_k neighbours exactly on the ground (z = 0.25), sliding, without
    gravity: anchor 0 feels no vertical force in the first substep and stays exactly on the
    plane, where the official contact applies friction and a strict `<` would not."""
    rng = np.random.default_rng(4)
    if case == "drop":
        x = rng.uniform(0.3, 0.5, (N, 3)).astype(F32)
        v = np.tile(F32([0.4, -0.2, -2.5]), (N, 1))
        return x, x + rng.normal(0, 0.004, x.shape).astype(F32), v, -9.8
    ring = (
        np.stack([np.cos(np.arange(N_K) * 2.4), np.sin(np.arange(N_K) * 2.4)], 1)
        * np.linspace(0.05, 0.09, N_K)[:, None]
    )
    flat = np.concatenate([[[0.4, 0.4]], 0.4 + ring]).astype(F32)
    x_flat = np.concatenate([flat, np.full((N_K + 1, 1), GROUND, F32)], axis=1)
    x_up = rng.uniform(0.3, 0.5, (N - N_K - 1, 3)).astype(F32)
    x_up[:, 2] = rng.uniform(0.45, 0.6, N - N_K - 1).astype(F32)
    x = np.concatenate([x_flat, x_up])
    v = np.zeros_like(x)
    v[:, 0] = 0.8
    x0 = x.copy()
    x0[:, :2] += rng.normal(0, 0.003, (N, 2)).astype(F32)  # strained in the plane only
    return x, x0, v, 0.0


def run_sgdr(case, log10_k, kappa, n_frames, n_step, dt_frame=1 / 30):
    x_rest, x0, v0, g = scene(case)
    cfg = PhysicsConfig(
        spring_law="official",
        springs="directed",
        contact="project",
        soft_vector_normalised=True,
        n_c=N_C,
        p_k=P_K,
        zeta0=0.1,
        friction_init=0.6,
        retry_on_nan=False,
    )
    model = build_spring_model(x_rest.astype(np.float64), N_K, cfg)
    params = PhysParams.init(model, cfg, v0=(0, 0, 0), gravity=(0, 0, g))
    params.log10_k = type(params.log10_k)(log10_k.astype(F32))
    params.kappa = type(params.kappa)(F32(kappa))
    dr.make_opaque(params)
    ground = Ground([0, 0, GROUND], [0, 0, 1])
    return model, params, cfg, ground, x0, v0


def _official(case, log10_k, kappa, dtype=F32):
    x_rest, x0, v0, g = scene(case)
    sim = OfficialSpringMass(
        x_rest.astype(dtype), N_K, N_C, log10_k.astype(dtype), kappa, 0.1, 1.0, g, GROUND, 0.6, P_K, dtype
    )
    return sim, x0.astype(dtype), v0.astype(dtype)


def _log10_k():
    return np.random.default_rng(2).uniform(2.2, 2.8, N).astype(F32)


@pytest.mark.parametrize("case", ["drop", "on_plane"])
def test_official_variant_matches_the_official_equations(case):
    log10_k, kappa, n_frames, n_step = _log10_k(), 1.3, 4, 40
    model, params, cfg, ground, x0, v0 = run_sgdr(case, log10_k, kappa, n_frames, n_step)
    # same springs, same order (the soft vector weights them by rank)
    sim, x, v = _official(case, log10_k, kappa)
    j = model.numpy()["spring_j"].reshape(N, N_K)
    np.testing.assert_array_equal(j, sim.knn_index)
    assert (official_soft_vector(kappa, N_K, N_C, F32) < 1).sum() == N_K - N_C - 1  # the soft part is engaged

    states = rollout(
        model, params, SimState.from_numpy(x0, v0), ground, n_frames, 1 / 30, cfg, grad_mode="full", n_substeps=n_step
    )
    size = float(np.ptp(x0, axis=0).max())
    touched = 0
    for f in range(1, n_frames):
        x, v = sim.frame(x, v, 1 / 30, n_step)
        touched = max(touched, int((x[:, 2] <= GROUND).sum()))
        xs, vs = states[f].numpy()
        print(f"{case} frame {f}: |Δx| / size {np.abs(xs - x).max() / size:.2g}, |Δv| {np.abs(vs - v).max():.2g}")
        assert np.abs(xs - x).max() <= 2e-5 * size, f"frame {f}: positions differ"
        assert np.abs(vs - v).max() <= 2e-4 * max(1.0, np.abs(v).max()), f"frame {f}: velocities differ"
    assert touched >= 3  # contact is exercised
    if case == "on_plane":
        # anchor 0 slid on the plane under friction: the strict `<` would have kept it at 0.8
        assert abs(states[1].numpy()[1][0, 0]) < 0.5


def test_official_variant_gradient_matches_finite_differences_of_the_official_equations():
    """d/dδ of a weighted sum of frame-1 positions, log10 k_i + δ for every anchor (the global
    stiffness shift): sgdr's AD against central differences of the official equations in float64."""
    log10_k, kappa, n_step = _log10_k(), 1.3, 40
    model, params, cfg, ground, x0, v0 = run_sgdr("drop", log10_k, kappa, 2, n_step)
    w = np.random.default_rng(9).normal(size=(N, 3))
    dr.enable_grad(params.log10_k)
    states = rollout(
        model, params, SimState.from_numpy(x0, v0), ground, 2, 1 / 30, cfg, grad_mode="full", n_substeps=n_step
    )
    x = states[1].x
    t = type(params.log10_k)
    loss = dr.sum(x[0] * t(w[:, 0]) + x[1] * t(w[:, 1]) + x[2] * t(w[:, 2]))
    dr.backward(loss)
    grad = float(dr.sum(dr.grad(params.log10_k)).numpy()[0])

    def official_loss(delta):
        sim, x, v = _official("drop", log10_k.astype(np.float64) + delta, kappa, np.float64)
        x, _ = sim.frame(x, v, 1 / 30, n_step)
        return float((x * w).sum())

    h = 1e-4
    fd = (official_loss(h) - official_loss(-h)) / (2 * h)
    assert abs(fd) > 1e-3
    assert grad == pytest.approx(fd, rel=5e-3)
