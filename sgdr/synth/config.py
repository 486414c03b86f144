"""Typed config schema of the benchmark generator (group key `synth`)."""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass
class SynthConfig:
    object: str = "torus"  # torus | cross | cream | apple | paste | chess | banana
    resolution: int = 128  # image width = height, pixels
    n_views: int = 10  # cameras on the upper hemisphere
    n_frames: int = 30  # frames rendered
    n_fit: int = 20  # frames 0..n_fit-1 are for fitting, the rest are the future
    fps: float = 24.0  # frames per second
    spp: int = 64  # Mitsuba samples per pixel
    mpm_grid: int = 64  # MPM grid cells per unit-cube side
    particles_per_cell: int = 8  # MPM particle sampling density
    E: float = 2.0e4  # Young's modulus
    nu: float = 0.3  # Poisson ratio
    density: float = 1.0e3  # kg / scene unit³
    ground: str = "friction"  # MPM collider: sticky | slip | friction
    ground_friction: float = 0.5  # Coulomb μ for the "friction" collider
    surface_grid: int = 96  # density grid for marching cubes
    effects: dict = field(default_factory=dict)  # injected effects, name -> magnitude
