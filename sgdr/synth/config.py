"""Typed config schema of the benchmark generator (group key `synth`)."""

from __future__ import annotations

from dataclasses import dataclass, field

from sgdr.checks import any_text, at_least, between, choice, finite, non_negative, or_none, positive, vector

OWN = "the object's own, sgdr.synth.objects"


@dataclass
class EffectsConfig:
    """Effects the spring-mass model lacks, injected into the MPM ground truth.

    Every entry's default is "off" (the plain elastic benchmark); the values used are written
    to `gt/effects.json`. The ground type (sticky / slip / friction, the "slippery vs sticky
    ground" effect) is `SynthConfig.ground`, recorded there too.
    """

    plastic_yield: float = 0.0  # von Mises yield stress on the Hencky Kirchhoff stress, Pa; 0 = elastic
    air_drag: float = 0.0  # linear air drag rate c (dv/dt = -c v), 1/s; 0 = none
    stiff_ratio: float | None = None  # E of the second region / E of the first; 1 = homogeneous;
    #                                   null = the object's own (1 but for torus_hetero)
    stiff_axis: int | None = None  # world axis (0 x, 1 y, 2 z) whose upper half of the object is region 2;
    #                                null = the object's own
    gravity: float = 9.8  # magnitude of gravity, scene units / s² (direction -z); the sequence records 9.8
    ground_offset: float = 0.0  # the true ground lies this far above the recorded one (scene units); 0 = none
    ground_tilt_deg: float = 0.0  # the true ground's normal is tilted by this angle about the world x axis; 0 = none


@dataclass
class SynthConfig:
    object: str = "torus"  # torus | cross | cream | apple | paste | chess | banana | torus_hetero
    resolution: int = 128  # image width = height, pixels
    n_views: int = 10  # cameras on the upper hemisphere
    n_frames: int = 30  # frames rendered
    n_fit: int = 20  # frames 0..n_fit-1 are for fitting, the rest are the future
    fps: float = 24.0  # frames per second
    spp: int = 64  # Mitsuba samples per pixel
    mpm_grid: int = 64  # MPM grid cells per scene unit (the grid spans a unit cube)
    particles_per_cell: int = 8  # MPM particle sampling density
    E: float | None = None  # Young's modulus, Pa; null = the object's own (docs/benchmark-objects.md)
    nu: float | None = None  # Poisson ratio; null = the object's own
    density: float = 1.0e3  # kg / scene unit³
    ground: str = "friction"  # MPM collider: sticky | slip | friction
    ground_friction: float = 0.5  # Coulomb μ for the "friction" collider
    surface_grid: int = 96  # density grid for marching cubes (cells per scene unit)
    effects: EffectsConfig = field(default_factory=EffectsConfig)  # injected effects
    # --- simulation
    material: str = "neo_hookean"  # constitutive law: neo_hookean | fixed_corotated
    cfl: float = 0.3  # time step = cfl * dx / (elastic wave speed + max particle speed bound)
    substeps: int = 0  # MPM substeps per frame; 0 = the fewest the CFL bound allows
    hit_frame: int = 5  # the object first touches the ground during this frame
    v0: list | None = None  # initial velocity [3], units/s; null = the object's own
    wall_cells: int = 3  # grid cells at each side of the MPM domain acting as slip walls
    # --- surface and appearance
    surface_sigma: float = 0.6  # Gaussian kernel of the particle density, in surface cells
    surface_level: float = 0.42  # iso-level of the density relative to the interior density
    pattern_scale: float = 12.0  # spatial frequency of the colour pattern, 1 / scene unit
    # --- cameras and lights
    camera_radius: float = 1.1  # distance of the cameras from the look-at target
    camera_fov: float = 40.0  # horizontal field of view, degrees
    camera_elevation: list = field(default_factory=lambda: [15.0, 60.0])  # min, max, degrees
    camera_target: list = field(default_factory=lambda: [0.55, 0.52, 0.32])  # look-at point, world
    env_radiance: float = 0.35  # constant environment emitter radiance
    light_radiance: float = 12.0  # area light radiance
    light_size: float = 0.6  # area light side length, scene units
    light_height: float = 2.0  # area light height above the target
    max_depth: int = 4  # path tracer maximum path depth
    # --- output
    out: str = ""  # sequence folder; "" = <data_dir>/<object>; object "all" = the eight objects
    overwrite: bool = False  # regenerate sequences that are already complete


# Allowed values, checked before any work (sgdr.checks; names against their registries).
EFFECTS_CHECKS = {
    "plastic_yield": non_negative("0: elastic"),
    "air_drag": non_negative("0: none"),
    "stiff_ratio": or_none(positive(), OWN),
    "stiff_axis": or_none(choice((0, 1, 2)), OWN),
    "gravity": positive(),
    "ground_offset": finite(),
    "ground_tilt_deg": between(-30.0, 30.0),
}
CHECKS = {
    "object": choice("sgdr.synth.objects:OBJECTS", also=("all",)),
    "resolution": at_least(8),
    "n_views": at_least(1),
    "n_frames": at_least(2),
    "n_fit": at_least(1),
    "fps": positive(),
    "spp": at_least(1),
    "mpm_grid": at_least(8),
    "particles_per_cell": at_least(1),
    "E": or_none(positive(), OWN),
    "nu": or_none(between(0.0, 0.5, hi_open=True), OWN),
    "density": positive(),
    "ground": choice("sgdr.synth.mpm:COLLIDERS"),
    "ground_friction": non_negative(),
    "surface_grid": at_least(8),
    "material": choice("sgdr.synth.mpm:CONSTITUTIVE"),
    "cfl": between(0.0, 1.0, lo_open=True),
    "substeps": non_negative("0: the fewest the CFL bound allows"),
    "hit_frame": at_least(1),
    "v0": or_none(vector(3), OWN),
    "wall_cells": at_least(1),
    "surface_sigma": positive(),
    "surface_level": positive(),
    "pattern_scale": non_negative(),
    "camera_radius": positive(),
    "camera_fov": between(0.0, 180.0, lo_open=True, hi_open=True),
    "camera_elevation": vector(2, each=between(-90.0, 90.0)),
    "camera_target": vector(3),
    "env_radiance": non_negative(),
    "light_radiance": non_negative(),
    "light_size": positive(),
    "light_height": finite(),
    "max_depth": at_least(1),
    "out": any_text("the sequence folder; empty: <data_dir>/<object>"),
}
