"""Extensions of the spring-mass model for what it may get wrong (issue 15's catalogue).

Each is a `physics.*` setting whose default is the base model, so the base is nested in every
extension and they act everywhere the simulator runs (the pipeline, `experiments/simulate.py`,
the posterior's rollouts): they enter through `frame_constants` and `euler_contact` of
`sgdr.physics.simulate`, which every caller and both adjoints go through, and the float64 reference
(`sgdr.physics.reference`) applies the same ones.

- `air_drag` c (1/s): linear drag in the Euler update, v <- (v + dt (F/m + g)) / (1 + c dt), the
  implicit form the benchmark's MPM uses, stable for any c dt.
- `gravity_scale` s: gravity s g instead of the sequence's g (its magnitude is wrong).
- `ground_offset` d (scene units) and `ground_tilt_deg` θ towards `ground_tilt_azimuth_deg` φ:
  the ground plane the sequence records is moved along its normal n by d and its normal tilted,
  n' = cos θ n + sin θ (cos φ a + sin φ b), about the moved point, with (a, b) the plane's axes
  from `plane_axes` (a: the world axis least aligned with n, made orthogonal to it; b = n x a).
- `contact_restitution` e: the official "project" contact zeroes the normal velocity of every
  anchor on the ground, so nothing rebounds (README finding 6: the model loses the MPM's
  rebound); with e an anchor that hits faster than the resting speed leaves with e times its
  approach speed (`sgdr.physics.laws.contact_project`). The "coulomb" contact has its own,
  learned restitution.
- `plastic_yield_strain` ε: spring plasticity, the paper's future work. After every substep each
  rest length yields just enough that its spring's strain stays within ±ε
  (`sgdr.physics.simulate.plastic_rest_lengths`); the rest lengths become state (`SimState.rest`).
  Forward and recorded AD; the gather adjoint refuses it when gradients are asked for.
"""

from __future__ import annotations

import numpy as np


def plane_axes(normal) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors (a, b) spanning the plane of the unit `normal` (right-handed: a x b = n)."""
    n = np.asarray(normal, dtype=np.float64)
    e = np.eye(3)[int(np.argmin(np.abs(n)))]
    a = e - np.dot(e, n) * n
    a /= np.linalg.norm(a)
    return a, np.cross(n, a)


def ground_plane(point, normal, cfg) -> tuple[np.ndarray, np.ndarray]:
    """(point [3], unit normal [3]) of the ground the simulator uses: the recorded plane moved by
    `physics.ground_offset` and tilted by `physics.ground_tilt_deg` (module docstring)."""
    n = np.asarray(normal, dtype=np.float64)
    n = n / np.linalg.norm(n)
    p = np.asarray(point, dtype=np.float64) + float(cfg.ground_offset) * n
    theta = np.radians(float(cfg.ground_tilt_deg))
    if theta != 0.0:
        a, b = plane_axes(n)
        phi = np.radians(float(cfg.ground_tilt_azimuth_deg))
        n = np.cos(theta) * n + np.sin(theta) * (np.cos(phi) * a + np.sin(phi) * b)
    return p, n / np.linalg.norm(n)


def drag_factor(cfg, dt: float) -> float:
    """1 / (1 + c dt): the implicit linear drag of one substep (1 without drag)."""
    return 1.0 / (1.0 + float(cfg.air_drag) * float(dt))
