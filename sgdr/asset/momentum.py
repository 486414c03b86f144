"""Does an edited rollout gain momentum without an external cause? (`experiments/simulate.py`)

The only external forces on the spring-mass body are gravity (M g, M = Σ m_i) and the ground
(normal impulses along its normal, friction impulses tangential to it). The springs are
internal: with Newton's third law (physics.springs=symmetric) their forces cancel and add no
momentum. The directed springs (physics.springs=directed, the official model: spring i -> j
pushes i with k_i, and j is not pushed back) do not cancel: on a frictionless ground an edited
torus can reverse and slide away for ever.

`internal_impulses` re-runs the rollout substep by substep and sums the spring forces (the
momentum they add, exactly as simulated); `momentum_check` balances the momentum of the frames,
P(t) - P(0) = M g t + J_ground(t) + J_springs(t), reports the ground's share (normal and
friction) and warns when J_springs / M exceeds the tolerance. Checking the springs' own sum,
rather than inferring it from the centre of mass's motion, needs no assumption about friction:
friction acts per anchor, so on a deforming or spinning body it can speed up the centre of mass
as well as slow it.
"""

from __future__ import annotations

import numpy as np

from sgdr.arrays import array3_to_points
from sgdr.backend import ad
from sgdr.physics import SimState
from sgdr.physics.simulate import SPRINGS, contact_consts, euler_contact, frame_constants, plastic_rest_lengths


def internal_impulses(model, params, ground, n_frames: int, dt_frame: float, n_substeps: int, cfg) -> np.ndarray:
    """[T, 3] the momentum the springs added up to each frame: Σ over substeps of Σ_i F_i dt.

    Re-runs the forward rollout substep by substep exactly as `sgdr.physics.rollout` does (same
    n_t, same operations: spring force, semi-implicit Euler, contact), summing the spring forces
    of every substep on the way. Internal forces that obey Newton's third law sum to zero, so
    this is the momentum gained without an external cause (0 to rounding for symmetric springs).
    Pass the n_t the rollout ended up using (`Prediction.n_substeps`) to audit that rollout.
    """
    import drjit as dr

    t = ad()
    springs = SPRINGS.get_named(cfg.springs, "physics.springs")
    dt = float(dt_frame) / int(n_substeps)
    out = [np.zeros(3)]
    with dr.suspend_grad():
        p = params.detach()
        dr.eval(p.kappa, p.v0, p.friction, p.restitution, p.zeta0, p.gravity)
        c = frame_constants(model, p, ground, cfg)
        state = SimState.at_rest(model, p.v0)
        x, v, rest = state.x, state.v, None
        for _ in range(1, int(n_frames)):
            total = dr.zeros(t.Array3f, model.n_anchors)  # per anchor: no reduction kernel per substep
            for _ in range(int(n_substeps)):
                f = springs(model, x, v, c["k"], c["sp"], p.zeta0, cfg, rest=rest)
                total = total + f * dt
                x, v = euler_contact(x, v, f, p.gravity, p.friction, p.restitution, contact_consts(c), dt, cfg)
                rest = plastic_rest_lengths(model, x, rest, cfg)
                dr.eval(x, v, total, *(() if rest is None else (rest,)))
            out.append(out[-1] + array3_to_points(total).sum(0))
    return np.stack(out)


def momentum_check(
    velocities: np.ndarray,
    masses: np.ndarray,
    internal: np.ndarray,
    gravity: np.ndarray,
    ground_normal: np.ndarray,
    dt_frame: float,
    springs: str,
    tolerance: float,
) -> dict:
    """Momentum verdict of a rollout: a JSON-ready dict with `gains_momentum` (bool), `warning`
    (a sentence, or None) and the measured impulses, all per unit of total mass (centre-of-mass
    velocities, scene units / s).

    velocities: [T, N_A, 3] anchor velocities per frame; masses [N_A]; internal: [T, 3] the
    springs' cumulative impulse (`internal_impulses`); gravity [3] scene units / s²;
    ground_normal [3]; dt_frame: seconds per frame; springs: physics.springs of the rollout
    (named in the warning); tolerance: scene units / s on the centre of mass's velocity.

    The momentum balance P(t) - P(0) = M g t + J_ground(t) + J_springs(t) gives the ground's
    impulse (normal and friction) as what is left; the verdict is on J_springs alone, the part
    without an external cause: it must stay within `tolerance` x M.
    """
    v = np.asarray(velocities, np.float64)
    m = np.asarray(masses, np.float64).reshape(-1)
    j_int = np.asarray(internal, np.float64)
    g = np.asarray(gravity, np.float64).reshape(3)
    n = np.asarray(ground_normal, np.float64).reshape(3)
    n = n / np.linalg.norm(n)
    if v.ndim != 3 or v.shape[1] != m.shape[0] or j_int.shape != (v.shape[0], 3):
        raise ValueError(f"velocities {v.shape}, masses {m.shape} and internal {j_int.shape} do not match [T, N_A, 3]")
    total_mass = float(m.sum())
    t = np.arange(v.shape[0]) * float(dt_frame)

    def along(a):  # the part tangential to the ground, [..., 3]
        return a - (a @ n)[..., None] * n

    com_v = (m[None, :, None] * v).sum(1) / total_mass  # [T, 3]
    springs_dv = j_int / total_mass  # [T, 3]
    ground_dv = com_v - com_v[0] - t[:, None] * g[None, :] - springs_dv  # what the ground did
    speed_t = np.linalg.norm(along(com_v), axis=1)
    gain = float(np.linalg.norm(springs_dv, axis=1).max())
    gain_t = float(np.linalg.norm(along(springs_dv), axis=1).max())
    gain_n = float(np.abs(springs_dv @ n).max())
    warning = None
    if gain > tolerance:
        cause = (
            "the directed springs (physics.springs=directed, the official model) do not conserve momentum; "
            "physics.springs=symmetric does"
            if springs == "directed"
            else f"physics.springs={springs} should conserve momentum (a bug, or rounding over a very long rollout)"
        )
        warning = (
            f"the edited rollout gains momentum without an external cause: its springs pushed the centre of mass "
            f"by up to {gain_t:.2f} scene units/s along the ground (it moves {speed_t[-1]:.2f} along the ground at the "
            f"end, {speed_t[0]:.2f} at the start) and {gain_n:.2f} along the ground's normal (absorbed by the ground "
            f"while in contact), beyond gravity and the ground: {cause}"
        )
    return {
        "gains_momentum": warning is not None,
        "warning": warning,
        "springs": springs,
        "springs_dv_max": gain,
        "springs_dv_max_along_ground": gain_t,
        "springs_dv_max_along_normal": gain_n,
        "springs_dv_end": springs_dv[-1].tolist(),
        "ground_dv_end": ground_dv[-1].tolist(),
        "ground_dv_end_along_ground": float(np.linalg.norm(along(ground_dv[-1]))),
        "com_speed_along_ground_start": float(speed_t[0]),
        "com_speed_along_ground_end": float(speed_t[-1]),
        "com_speed_along_ground_max": float(speed_t.max()),
        "tolerance": float(tolerance),
    }
