"""MLS-MPM physics checks on tiny grids (24³): conservation, free fall, contact, plasticity."""

from functools import cache

import numpy as np
import pytest
from scipy.linalg import polar
from scipy.spatial import cKDTree

from sgdr.backend import ad
from sgdr.synth import mpm
from sgdr.synth.generate import free_flight
from sgdr.synth.linalg import sym_eig3

N_GRID = 24
DX = 1.0 / N_GRID
FPS = 24.0
RHO, NU = 1.0e3, 0.3


def cube(side=0.2, centre=(0.5, 0.5, 0.5)):
    s = DX / 2
    g = np.arange(-side / 2 + s / 2, side / 2, s)
    x = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3) + centre
    return x, s**3


@cache
def drop(E=2e5, collider="slip", v0=(0.0, 0.0, -1.0), yield_stress=0.0, drag=0.0, n_frames=12,
         ground_z=0.25, substeps=0):  # fmt: skip
    """Drop a 0.2-wide cube (centre at 0.5) on a plane at ground_z; returns (x0, frames, model)."""
    x, vol = cube()
    sub = substeps or mpm.cfl_substeps(1 / FPS, DX, E, NU, RHO, 0.3, 4.0)
    model = mpm.create_model(
        x, vol, RHO, N_GRID, DX, (0.0, 0.0, ground_z - 4 * DX), 1 / FPS / sub, "neo_hookean",
        collider, 0.5, (0.5, 0.5, ground_z), (0, 0, 1), plastic=yield_stress > 0,
    )  # fmt: skip
    params = mpm.MPMParams.create(E, NU, (0, 0, -9.8), drag=drag, yield_stress=yield_stress)
    frames, _ = mpm.simulate(model, params, mpm.MPMState.at_rest(x, v0), n_frames, sub)
    return x, frames, model


def chamfer(a, b):
    """Mean squared nearest-neighbour distance, both directions, summed."""
    return cKDTree(b).query(a)[0].__pow__(2).mean() + cKDTree(a).query(b)[0].__pow__(2).mean()


# ---------------------------------------------------------------------------- conservation
def test_grid_mass_equals_particle_mass_before_and_after_impact():
    x, vol = cube()
    model = mpm.create_model(x, vol, RHO, N_GRID, DX, (0, 0, 0.25 - 4 * DX), 1e-3, "neo_hookean",
                             "friction", 0.5, (0.5, 0.5, 0.25), (0, 0, 1))  # fmt: skip
    params = mpm.MPMParams.create(2e4, NU, (0, 0, -9.8))
    state = mpm.MPMState.at_rest(x, (0.3, 0.1, -2.0))
    total = len(x) * RHO * vol
    for step in range(160):  # through the impact (the cube reaches the ground at ~step 70)
        if step % 40 == 0:
            grid_m, _ = mpm.p2g(model, params, state)
            assert np.sum(grid_m.numpy(), dtype=np.float64) == pytest.approx(total, rel=2e-6)
        state = mpm.substep(model, params, state)
    assert state.x.numpy().T[:, 2].min() < 0.25 + DX  # it did touch the ground
    np.testing.assert_allclose(model.particle_mass.numpy(), np.float32(RHO * vol), rtol=1e-6)


# ---------------------------------------------------------------------------- free fall
@pytest.mark.parametrize("drag", [0.0, 1.5])
def test_centre_of_mass_in_free_fall(drag):
    v0 = (0.3, -0.2, 0.5)
    x0, frames, model = drop(v0=v0, drag=drag, ground_z=0.2, n_frames=8, substeps=100)
    com = frames.mean(1).astype(np.float64)
    t = np.arange(len(frames))[:, None] / FPS
    in_air = frames[:, :, 2].min(1) > 0.2 + 1.5 * DX  # no stencil node in the contact band
    assert in_air.sum() >= 6
    flight = free_flight(x0.mean(0), v0, (0, 0, -9.8), drag, model.dt, 100, len(frames))
    np.testing.assert_allclose(com[in_air], flight[in_air], atol=2e-5)
    if drag == 0.0:
        parabola = x0.mean(0) + np.array(v0) * t + 0.5 * np.array([0, 0, -9.8]) * t**2
        assert np.abs(com - parabola)[in_air].max() < 1e-3
    else:  # drag visibly slows the fall compared with the drag-free run
        _, free, _ = drop(v0=v0, drag=0.0, ground_z=0.2, n_frames=8, substeps=100)
        assert np.abs(free.mean(1) - com)[in_air].max() > 5e-3


# ---------------------------------------------------------------------------- contact
def test_stiff_elastic_cube_bounces_and_recovers_its_shape():
    x0, frames, _ = drop(E=2e5, collider="slip", n_frames=12)
    z = frames[:, :, 2].mean(1)
    lowest = int(np.nonzero(np.diff(z) > 0)[0][0])  # first turning point: the impact
    apex = lowest + int(np.argmax(z[lowest:]))
    assert 0 < lowest < apex
    assert z[apex] > z[lowest] + 0.05  # it goes back up: a bounce
    rest = x0 - x0.mean(0)
    squashed = frames[lowest] - frames[lowest].mean(0)
    up = frames[apex] - frames[apex].mean(0)
    assert chamfer(up, rest) < 0.1 * DX**2  # near its rest shape (compare: one cell = DX²)
    assert chamfer(up, rest) < 0.3 * chamfer(squashed, rest)
    np.testing.assert_allclose(np.ptp(up, axis=0), np.ptp(rest, axis=0), rtol=0.06)


def test_slip_and_sticky_ground_differ_in_tangential_motion():
    v0 = (0.4, 0.0, -1.0)
    runs = {c: drop(E=2e4, collider=c, v0=v0, n_frames=10)[1] for c in ("slip", "sticky", "friction")}
    f = runs["slip"]
    contact = int(np.argmin(f[:, :, 2].min(1) > 0.25 + 1.5 * DX))  # first frame in contact
    bottom = f[contact, :, 2] < f[contact, :, 2].min() + DX  # the layer touching the ground

    def slide(c):
        return runs[c][-1, bottom, 0].mean() - runs[c][contact, bottom, 0].mean()

    travel = v0[0] * (len(f) - 1 - contact) / FPS
    assert slide("slip") > 0.7 * travel  # slides on
    assert slide("sticky") < 0.3 * slide("slip")  # held by the ground
    assert slide("sticky") < slide("friction") < slide("slip")  # Coulomb in between


def test_plastic_yield_leaves_a_permanent_deformation():
    x0, elastic, _ = drop(E=2e4, collider="slip", n_frames=12)
    _, plastic, _ = drop(E=2e4, collider="slip", yield_stress=1500.0, n_frames=12)
    h0 = np.ptp(x0[:, 2])
    h_el, h_pl = np.ptp(elastic[-3:, :, 2], axis=1), np.ptp(plastic[-3:, :, 2], axis=1)
    assert np.all(h_pl < 0.75 * h0)  # flattened for good
    assert np.all(h_el > 0.9 * h0)  # the elastic cube got its height back
    assert np.ptp(plastic[-1, :, 0]) > 1.1 * np.ptp(x0[:, 0])  # and spread sideways


# ---------------------------------------------------------------------------- time step
def test_cfl_violations_raise_clear_errors():
    with pytest.raises(mpm.MPMError, match="CFL bound.*synth.substeps"):
        mpm.check_cfl(1e-2, DX, 2e4, NU, RHO, 0.3, 0.0)
    mpm.check_cfl(1e-4, DX, 2e4, NU, RHO, 0.3, 0.0)
    n = mpm.cfl_substeps(1 / FPS, DX, 2e4, NU, RHO, 0.3, 2.0)
    mpm.check_cfl(1 / FPS / n, DX, 2e4, NU, RHO, 0.3, 2.0)
    with pytest.raises(mpm.MPMError):
        mpm.check_cfl(1 / FPS / (n - 1), DX, 2e4, NU, RHO, 0.3, 2.0)
    with pytest.raises(mpm.MPMError, match="cells per substep"):  # too fast for its time step
        drop(E=2e2, v0=(0.0, 0.0, -40.0), n_frames=2, substeps=2)


def test_unknown_names_are_rejected():
    x, vol = cube()
    with pytest.raises(mpm.MPMError, match="synth.ground"):
        mpm.create_model(x, vol, RHO, N_GRID, DX, (0, 0, 0), 1e-3, "neo_hookean", "ice", 0.5,
                         (0, 0, 0.2), (0, 0, 1))  # fmt: skip
    with pytest.raises(mpm.MPMError, match="outside the MPM domain"):
        mpm.create_model(x + 0.45, vol, RHO, N_GRID, DX, (0, 0, 0), 1e-3, "neo_hookean", "slip",
                         0.5, (0, 0, 0.2), (0, 0, 1))  # fmt: skip


# ---------------------------------------------------------------------------- material laws
def random_F(rng, n=64, spread=0.3):
    F = np.eye(3) + spread * rng.normal(size=(n, 3, 3))
    F[np.linalg.det(F) < 0.2] = np.eye(3)
    return F


def to_dr(F):
    return ad().Matrix3f(np.ascontiguousarray(F.transpose(1, 2, 0).astype(np.float32)))


def from_dr(M):
    return np.asarray(M.numpy()).transpose(2, 0, 1)


def test_kirchhoff_stresses_match_numpy(rng):
    F = random_F(rng)
    mu, lam = mpm.lame(1.0e4, NU)
    I = np.eye(3)
    J = np.linalg.det(F)
    nh = mu * (F @ F.transpose(0, 2, 1) - I) + lam * np.log(J)[:, None, None] * I
    np.testing.assert_allclose(from_dr(mpm.kirchhoff_neo_hookean(to_dr(F), mu, lam)), nh, rtol=1e-4, atol=0.5)
    R = np.stack([polar(f)[0] for f in F])
    fc = 2 * mu * (F - R) @ F.transpose(0, 2, 1) + (lam * (J - 1) * J)[:, None, None] * I
    out = from_dr(mpm.kirchhoff_fixed_corotated(to_dr(F), mu, lam))
    np.testing.assert_allclose(out, fc, rtol=1e-3, atol=2.0)
    for law in mpm.CONSTITUTIVE.values():  # stress free at rest
        assert np.abs(from_dr(law(to_dr(np.stack([I] * 4)), mu, lam))).max() < 1e-3


def test_symmetric_eigensolver_matches_numpy(rng):
    A = rng.normal(size=(200, 3, 3))
    A = A @ A.transpose(0, 2, 1)
    lam, Q = sym_eig3(to_dr(A))
    lam = np.stack([np.asarray(v.numpy()) for v in lam], 1)
    np.testing.assert_allclose(np.sort(lam, 1), np.linalg.eigvalsh(A), rtol=1e-4, atol=1e-4)
    Qn = from_dr(Q)
    np.testing.assert_allclose(Qn @ (lam[:, :, None] * Qn.transpose(0, 2, 1)), A, atol=1e-4)


def test_von_mises_return_mapping_lands_on_the_yield_surface(rng):
    F = random_F(rng, spread=0.25)
    mu, tau_y = 5000.0, 4000.0
    t = ad()
    Fp = from_dr(mpm.von_mises_return(to_dr(F), t.Float(mu), t.Float(tau_y)))

    def dev_norm(M):
        eps = 0.5 * np.log(np.linalg.eigvalsh(M @ M.transpose(0, 2, 1)))
        return np.linalg.norm(eps - eps.mean(1, keepdims=True), axis=1)

    before, after = 2 * mu * dev_norm(F), 2 * mu * dev_norm(Fp)
    yielded = before > tau_y
    assert yielded.sum() > 10 and (~yielded).sum() > 5
    np.testing.assert_allclose(after[yielded], tau_y, rtol=2e-3)
    np.testing.assert_allclose(Fp[~yielded], F[~yielded], atol=1e-5)
    np.testing.assert_allclose(np.linalg.det(Fp), np.linalg.det(F), rtol=1e-4)  # volume kept


def test_frozen_substep_matches_the_traced_one_across_particle_counts():
    """dr.freeze replays kernels; a changed particle count must not reuse stale sizes."""
    results = {}
    for side in (0.2, 0.15, 0.2):
        x, vol = cube(side)
        model = mpm.create_model(x, vol, RHO, N_GRID, DX, (0, 0, 0.25 - 4 * DX), 2e-3, "neo_hookean",
                                 "sticky", 0.5, (0.5, 0.5, 0.25), (0, 0, 1), plastic=True)  # fmt: skip
        params = mpm.MPMParams.create(2e4, NU, (0, 0, -9.8), yield_stress=1500.0)
        state = mpm.MPMState.at_rest(x, (0.2, 0.0, -2.0))
        for frozen in (True, False):
            frames, _ = mpm.simulate(model, params, state, 4, 20, frozen=frozen)
            results[side, frozen] = frames
        np.testing.assert_allclose(results[side, True], results[side, False], atol=1e-6)
        assert frames[-1, :, 2].min() < 0.25 + DX  # the run reached the ground (all paths used)
