"""Typed config schema of the spring-mass simulator (Hydra group key `physics`).

Variant names (`spring_law`, `springs`, `symmetric_stiffness`, `contact`, `adjoint`) are
looked up in the registries of `sgdr.physics.laws` / `sgdr.physics.simulate`; an unknown name
raises an error that lists the known ones. How a rollout's frames are chained for gradients
("full" | "truncated") is not a setting: it is `rollout`'s argument `grad_mode`, chosen by
each caller (the dynamic stage's `recon.mode`, the oracle, the benchmarks).
"""

from __future__ import annotations

from dataclasses import dataclass

from sgdr.checks import at_least, between, choice, finite, non_negative, positive


@dataclass
class PhysicsConfig:
    spring_law: str = "official"  # "official": (1+|strain|)^p_k factor; "paper": |Δl|^p_k (Eq. 8)
    springs: str = "directed"  # "directed" (official, force on i uses k_i) | "symmetric" (Newton 3)
    symmetric_stiffness: str = "harmonic"  # k of a symmetric spring from k_i, k_j: "harmonic" | "arithmetic"
    soft_vector_normalised: bool = (
        True  # Eq. 15 exponent: (r - n_c)/(n_k - n_c), 0-based r (official) | j - n_c, 1-based j
    )
    soft_vector: bool = True  # false: the ablation without soft vector: η_j = 1 for all n_k springs
    #                           (the model's n_c = n_k, physics.n_c unused) and κ is not learned
    contact: str = "project"  # "project" (official, per-substep μ) | "coulomb" (restitution e, μ)
    rest_speed_factor: float = 2.0  # "coulomb": approach speeds below this x |g| dt are resting contact (no bounce)
    n_substeps: int = 100  # n_t, Euler substeps per frame (the dynamic stage scales it by recon.substep_growth)
    max_substeps: int = 400  # upper limit when retrying an unstable rollout with more substeps
    retry_on_nan: bool = True  # the official remedy, the only one: an unstable frame is redone with 2x substeps
    cfl_factor: float = 1.4  # stability bound checked before running: dt <= cfl_factor * sqrt(m / k_eff)
    adjoint: str = "gather"  # how a rollout is differentiated: "gather" (one custom op per frame, hand-written gather-only backward; default) | "recorded" (recorded AD of every substep, the reference)
    m0: float = 1.0  # anchor mass m_i = m0
    zeta0: float = 0.1  # ζ0, damping coefficient (ζ_ij = ζ0 / l_ij, Eq. 17)
    p_k: float = 0.5  # exponent of the nonlinear spring factor (Eq. 8)
    n_c: int = 16  # springs with full weight η_j = 1 in the soft vector (Eq. 15)
    log10_k_init: float = 3.0  # initial log10 k_i for every anchor
    kappa_init: float = 0.0  # initial soft-vector κ
    friction_init: float = 0.9  # μ: "project": tangential factor per substep; "coulomb": coefficient
    restitution_init: float = 0.0  # e in [0, 1] ("coulomb" contact only)
    min_length: float = 1.0e-9  # scene units; guards |x_i - x_j| and |Δl| against 0 (NaN gradients)
    # --- model extensions (sgdr.physics.extensions): each one's default is the base model
    air_drag: float = 0.0  # linear air drag rate c, 1/s: v <- (v + dt a) / (1 + c dt) every substep
    gravity_scale: float = 1.0  # the gravity used is the sequence's times this
    ground_offset: float = 0.0  # the ground plane moved along its normal by this, scene units
    ground_tilt_deg: float = 0.0  # the ground's normal tilted by this angle, degrees
    ground_tilt_azimuth_deg: float = 0.0  # the in-plane direction it tilts towards, degrees (sgdr.physics.extensions)
    contact_restitution: float = 0.0  # "project" contact: impacts faster than resting rebound with this e; 0 = official
    plastic_yield_strain: float = 0.0  # spring plasticity: rest lengths yield to keep |strain| <= this; 0 = elastic


# Allowed values, checked before any work (sgdr.checks; names against their registries).
CHECKS = {
    "spring_law": choice("sgdr.physics.laws:SPRING_LAWS"),
    "springs": choice("sgdr.physics.simulate:SPRINGS"),
    "symmetric_stiffness": choice("sgdr.physics.laws:SYMMETRIC_STIFFNESS"),
    "contact": choice("sgdr.physics.laws:CONTACTS"),
    "rest_speed_factor": non_negative(),
    "n_substeps": at_least(1),
    "max_substeps": at_least(1),
    "cfl_factor": positive(),
    "adjoint": choice("sgdr.physics.simulate:ADJOINTS"),
    "m0": positive(),
    "zeta0": non_negative(),
    "p_k": finite(),
    "n_c": non_negative(),
    "log10_k_init": finite(),
    "kappa_init": finite(),
    "air_drag": non_negative("1/s; 0: no drag"),
    "gravity_scale": positive(),
    "ground_offset": finite(),
    "ground_tilt_deg": between(-45.0, 45.0),
    "ground_tilt_azimuth_deg": finite(),
    "plastic_yield_strain": between(0.0, 0.95),
    "contact_restitution": between(0.0, 1.0),
    "friction_init": non_negative(),
    "restitution_init": between(0.0, 1.0),
    "min_length": positive(),
}
