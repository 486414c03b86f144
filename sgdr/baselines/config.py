"""Typed config schema of the baselines (group key `baseline`): the methods the paper compares
Spring-Gaus with, each a `recon.model` choice (`sgdr.pipeline.run.MODELS`, `conf/method/`).

Scale keys (grid sizes, candidate counts, rounds) are set by the presets, method keys (the
ground collider, the search ranges) by the method files; defaults here are the small preset's
scale and PAC-NeRF's method.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from sgdr.checks import Check, at_least, between, choice, non_negative, positive, vector


@dataclass
class PacNerfConfig:
    """PAC-NeRF's assumptions in sgdr's engines (docs/baselines.md): one global Neo-Hookean E
    and ν for MLS-MPM particles filled into the static reconstruction's volume, v0 from the
    shared velocity stage, a sticky ground; E and ν searched derivative-free with batched
    candidate rollouts (the MPM backward through recorded AD is compile-bound)."""

    # --- method
    collider: str = "sticky"  # MPM ground collider: sticky (PAC-NeRF's surface_sticky) | slip | friction
    ground_friction: float = 0.5  # Coulomb μ of the `friction` collider
    material: str = "neo_hookean"  # constitutive law (PAC-NeRF's compressible Neo-Hookean)
    density: float = 1.0e3  # kg / scene unit³ (PAC-NeRF's and the generator's); only E / density acts
    log10_E_range: list[float] = field(default_factory=lambda: [3.0, 5.5])  # the search box of log10 E, Pa
    nu_range: list[float] = field(default_factory=lambda: [0.05, 0.45])  # the search box of ν
    fill_threshold: float = 0.5  # a lattice point is inside when the Gaussians' occupancy there exceeds this
    bind_k: int = 8  # particles each Gaussian centre follows (inverse-distance weights of their displacements)
    cfl: float = 0.3  # MPM time step = cfl Δx / (P-wave speed of the stiffest candidate + a speed bound)
    # --- scale (presets)
    cells_per_size: int = 16  # MPM cells across the object's largest extent (particles: 2 per cell per axis)
    dx: float = 0.0  # MPM cell size, scene units, when > 0 (instead of cells_per_size); particles at dx / 2
    substeps: int = 0  # MPM substeps per frame; 0 = the fewest the CFL bound allows (PAC-NeRF's configs: 200)
    grid_E: int = 5  # candidate log10 E values per search round (>= 3)
    grid_nu: int = 3  # candidate ν values per search round (1: fixed; else >= 3); grid_E x grid_nu rollouts batched
    rounds: int = 5  # search rounds; each centres a grid of half the step on the best candidate so far
    n_views: int = 0  # views the search compares (0 = all; evenly spread otherwise)
    frame_stride: int = 1  # every n-th fit frame is compared in the search
    max_image_size: int = 64  # images compared at most this large (block means, intrinsics scaled)


@dataclass
class BaselineConfig:
    pacnerf: PacNerfConfig = field(default_factory=PacNerfConfig)


def _range(lo: float, hi: float) -> Check:
    inner = vector(2, each=between(lo, hi))
    return Check(lambda v: inner.ok(v) and v[0] < v[1], f"[low, high] with {lo} <= low < high <= {hi}")


PACNERF_CHECKS = {
    "collider": choice("sgdr.synth.mpm:COLLIDERS"),
    "ground_friction": non_negative(),
    "material": choice("sgdr.synth.mpm:CONSTITUTIVE"),
    "density": positive(),
    "log10_E_range": _range(0.0, 9.0),
    "nu_range": _range(0.0, 0.49),
    "fill_threshold": between(0.0, 1.0, lo_open=True, hi_open=True),
    "bind_k": at_least(1),
    "cfl": between(0.0, 1.0, lo_open=True),
    "cells_per_size": at_least(4),
    "dx": non_negative("0: the object's largest extent / cells_per_size"),
    "substeps": non_negative("0: the fewest the CFL bound allows"),
    "grid_E": at_least(3),
    "grid_nu": Check(
        lambda n: isinstance(n, int) and (n == 1 or n >= 3), "1 (ν fixed at the middle of nu_range) or >= 3"
    ),
    "rounds": at_least(1),
    "n_views": non_negative("0: every view"),
    "frame_stride": at_least(1),
    "max_image_size": at_least(8),
}
CHECKS: dict = {}  # BaselineConfig holds sections only
