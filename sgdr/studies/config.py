"""Typed config schema of the studies (group key `oracle`: `experiments/oracle.py`)."""

from __future__ import annotations

from dataclasses import dataclass, field

from sgdr.checks import at_least, finite, list_of


@dataclass
class OracleConfig:
    """`experiments/oracle.py`: the model fitted to the generator's particle tracks (an upper
    bound on what identification from images can reach; `sgdr.studies.oracle`)."""

    iterations: int = 60  # Adam steps, each a full-gradient rollout over the fit frames
    log10_k_init: float = 3.3  # uniform start of log10 k_i (the small torus's grid choice)
    contact_margin: float = -1.0  # ground raised by this along its normal, scene units (< 0 =
    #                               half the generator's MPM cell: its collider band)
    k_offsets: list = field(
        default_factory=lambda: [-0.12, -0.09, -0.06, -0.045, -0.03, -0.015, 0.0, 0.015, 0.03, 0.06]
    )  # after the fit: rollouts with
    #                               the identified log10 k field shifted by each offset ([] = none)
    ensemble_tol: float = 1.25  # ensemble = the offsets whose fit error is within this x the best


# Allowed values, checked before any work (sgdr.checks).
CHECKS = {
    "iterations": at_least(1),
    "log10_k_init": finite(),
    "contact_margin": finite(),
    "k_offsets": list_of(finite()),
    "ensemble_tol": at_least(1.0),
}
