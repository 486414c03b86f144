"""Typed config schema of the studies run through Hydra: sgdr's `Config` plus the studies'
sections (group key `oracle`: `experiments/oracle.py`, `evaluation.studies.oracle`).

sgdr's own schema knows nothing of the studies: a study's driver registers `StudyConfig` as the
schema in its place (`register`, before `@hydra.main` runs) and checks a composed config with
`validate` (sgdr's checks and rules, and the studies' sections' `CHECKS`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from hydra.core.config_store import ConfigStore

import sgdr.config
from sgdr.checks import at_least, finite, list_of


@dataclass
class OracleConfig:
    """`experiments/oracle.py`: the model fitted to the generator's particle tracks (an upper
    bound on what identification from images can reach; `evaluation.studies.oracle`)."""

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


@dataclass
class StudyConfig(sgdr.config.Config):
    """sgdr's config and the studies' sections."""

    oracle: OracleConfig = field(default_factory=OracleConfig)  # experiments/oracle.py (evaluation.studies.oracle)


# every section's checks: sgdr's and the studies'
SECTION_CHECKS = {**sgdr.config.SECTION_CHECKS, "oracle": CHECKS}


def register() -> None:
    """Store `StudyConfig` as `config_schema` in Hydra's ConfigStore (idempotent): what
    `sgdr.config.register` does for sgdr's schema, which a study's driver calls instead."""
    ConfigStore.instance().store(name="config_schema", node=StudyConfig)


def validate(cfg) -> None:
    """`sgdr.config.validate` with the studies' sections checked too: one `ConfigError` listing
    every problem, each naming its key. cfg: a composed `StudyConfig` (instance or DictConfig)."""
    sgdr.config.validate(cfg, SECTION_CHECKS)


def split_extra(argv: list[str]) -> tuple[dict, list[str]]:
    """A study driver's arguments: the `+key=value` ones its own (key -> value), the rest config
    overrides."""
    extra = {a.split("=", 1)[0][1:]: a.split("=", 1)[1] for a in argv if a.startswith("+")}
    return extra, [a for a in argv if not a.startswith("+")]
