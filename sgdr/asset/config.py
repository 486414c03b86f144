"""Typed config schema of the what-if simulation of an asset (group key `recon.simulate`)."""

from __future__ import annotations

from dataclasses import dataclass, field

from sgdr.checks import (
    Check,
    any_text,
    choice,
    finite,
    folder_name,
    non_negative,
    positive,
    vector,
)


@dataclass
class SimulateConfig:
    """Edited conditions for `experiments/simulate.py` (the paper's Figs. 6-7).

    The simulation uses the asset's own physics settings (its asset.json), not `physics.*` of
    the command line: the substeps are `n_substeps` / `max_substeps` here."""

    asset: str = ""  # asset folder ("" = <recon.output_dir>/<run name>/asset)
    out_dir: str = ""  # where videos go ("" = <asset>/../simulate/<tag>); an existing folder holding
    #                    another simulation is refused unless overwrite=true
    tag: str = ""  # name of this simulation's output folder ("" = from the edits, e.g.
    #                friction-0_stiffness_scale-0.1; a new folder -2, -3, ... if that one holds another)
    overwrite: bool = False  # replace an explicit tag's / out_dir's folder that holds another simulation
    n_frames: int = 0  # frames to simulate (0 = the sequence's)
    n_substeps: int = 0  # n_t (0 = the value reached in training); the substeps of this run, not physics.n_substeps
    max_substeps: int = 0  # an unstable rollout is redone with 2x substeps up to this
    #                        (0 = the asset's physics.max_substeps)
    ground_height: float = 0.0  # ground plane moved along its normal, scene units
    friction: float = -1.0  # ground friction (< 0 = the identified value); contact=project: the tangential
    #                         velocity factor per substep in [0, 1] (1 = frictionless, 0 = sticky);
    #                         contact=coulomb: the friction coefficient (0 = frictionless)
    restitution: float = -1.0  # bounce e in [0, 1] (< 0 = the identified value); acts only with the asset's
    #                            physics.contact=coulomb: under contact=project nothing bounces, so setting it is
    #                            refused there
    gravity: list[float] = field(default_factory=list)  # [3] m/s² (empty = the identified/sequence's)
    stiffness_scale: float = 1.0  # every k_i multiplied by this (> 0)
    v0: list[float] = field(default_factory=list)  # [3] initial velocity (empty = identified)
    cameras: str = "sequence"  # "sequence" (all views tiled) | "orbit" (one turning camera)
    momentum_tolerance: float = 0.05  # the momentum check's tolerance on the centre of mass's unexplained


# Allowed values, checked before any work (sgdr.checks; names against their registries).
SIMULATE_CHECKS = {
    "asset": any_text("an asset folder; empty: this config's run folder's asset/"),
    "out_dir": any_text("an output folder; empty: <asset>/../simulate/<tag>"),
    "tag": folder_name(empty_ok=True),
    "n_frames": non_negative("0: the sequence's"),
    "n_substeps": non_negative("0: the value reached in training"),
    "max_substeps": non_negative("0: the asset's physics.max_substeps"),
    "ground_height": finite(),
    "friction": finite(),
    "restitution": Check(
        lambda x: finite().ok(x) and x <= 1, "must be a number <= 1 (the bounce e in [0, 1]; < 0: the identified one)"
    ),
    "gravity": vector(3, empty_ok=True),
    "stiffness_scale": positive(),
    "v0": vector(3, empty_ok=True),
    "cameras": choice("sgdr.asset.whatif:SIMULATE_CAMERAS"),
    "momentum_tolerance": positive(),
}
