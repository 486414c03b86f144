"""The eight benchmark objects, built procedurally (no downloads), each with its own material.

The seven of the main table (torus cross cream apple paste chess banana) and `torus_hetero`,
the heterogeneous object of the paper's ablation (Table 3, Fig. 9): the torus's shape with two
halves of distinct stiffness. Every object carries its own `Material` (E, ν, v0 and, for the
heterogeneous one, the stiffness ratio of its second region), used by the generator unless
`synth.E / nu / v0 / effects.stiff_ratio / effects.stiff_axis` are set (docs/benchmark-objects.md).

Each object is a signed distance function (SDF, NumPy, negative inside) made of smooth unions
of primitives, in a local frame centred at the origin (z up, scene units). `build_object`
turns it into
- a watertight `trimesh.Trimesh` (marching cubes of the SDF; checked watertight),
- particles sampling its volume (jittered lattice points with SDF < 0, equal rest volumes),
- a procedural two-colour pattern evaluated at the particles' rest positions, so photometric
  losses have texture to work with,
placed with its bounding box centred in the unit cube, inside [0.3, 0.7]^3.

Why SDFs rather than trimesh booleans: trimesh's booleans need an external engine (manifold3d,
Blender) that is not installed; marching cubes of an SDF gives watertight meshes directly and
the same SDF gives an exact inside test for volume sampling.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sgdr.registry import Registry

BOX_LO, BOX_HI = 0.3, 0.7  # the object's bounding box must lie inside [BOX_LO, BOX_HI]^3


class ObjectError(ValueError):
    """Unknown object name or an object that violates the benchmark's geometry rules."""


# ---------------------------------------------------------------------------- SDF primitives
def _len(a, axis=-1):
    return np.linalg.norm(a, axis=axis)


def smooth_union(d1, d2, k):
    """Polynomial smooth minimum of two distances (blend radius k)."""
    h = np.clip(0.5 + 0.5 * (d2 - d1) / k, 0.0, 1.0)
    return d2 * (1 - h) + d1 * h - k * h * (1 - h)


def smooth_subtract(d, cut, k):
    """Smoothly remove the inside of `cut` from `d`."""
    return -smooth_union(-d, cut, k)


def sd_sphere(p, c, r):
    return _len(p - np.asarray(c)) - r


def sd_torus(p, R, r, c=(0, 0, 0)):
    q = p - np.asarray(c)
    return _len(np.stack([_len(q[:, :2]) - R, q[:, 2]], -1)) - r


def sd_box(p, half, rounding=0.0, c=(0, 0, 0)):
    q = np.abs(p - np.asarray(c)) - (np.asarray(half) - rounding)
    return _len(np.maximum(q, 0.0)) + np.minimum(q.max(-1), 0.0) - rounding


def sd_capped_cylinder(p, r, z0, z1, rounding=0.0):
    """Cylinder around the z axis between heights z0 and z1."""
    c = np.array([0.0, 0.0, 0.5 * (z0 + z1)])
    q = p - c
    d = np.stack([_len(q[:, :2]) - (r - rounding), np.abs(q[:, 2]) - (0.5 * (z1 - z0) - rounding)], -1)
    return _len(np.maximum(d, 0.0)) + np.minimum(d.max(-1), 0.0) - rounding


def sd_tapered_tube(p, a, r):
    """Chain of round cones through centreline points a ([S+1, 3]) with radii r ([S+1])."""
    d = np.full(len(p), np.inf)
    for i in range(len(a) - 1):
        pa, ba = p - a[i], a[i + 1] - a[i]
        h = np.clip((pa @ ba) / (ba @ ba), 0.0, 1.0)
        d = np.minimum(d, _len(pa - h[:, None] * ba) - (r[i] + h * (r[i + 1] - r[i])))
    return d


def rotation(axis, deg) -> np.ndarray:
    """[3, 3] rotation about a unit axis by deg degrees (Rodrigues)."""
    axis = np.asarray(axis, dtype=np.float64)
    axis = axis / np.linalg.norm(axis)
    a = np.radians(deg)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(a) * K + (1 - np.cos(a)) * K @ K


# ---------------------------------------------------------------------------- the objects
def sdf_torus(p):
    return sd_torus(p, 0.125, 0.055)


def sdf_cross(p):
    bar1 = sd_box(p, (0.17, 0.05, 0.05), 0.02)
    bar2 = sd_box(p, (0.05, 0.17, 0.05), 0.02)
    return smooth_union(bar1, bar2, 0.02)


def sdf_cream(p):
    d = sd_torus(p, 0.1, 0.055, c=(0, 0, -0.1))
    d = smooth_union(d, sd_sphere(p, (0, 0, -0.1), 0.1), 0.02)
    d = smooth_union(d, sd_torus(p, 0.07, 0.048, c=(0, 0, -0.025)), 0.03)
    d = smooth_union(d, sd_torus(p, 0.04, 0.04, c=(0, 0, 0.04)), 0.03)
    return smooth_union(d, sd_sphere(p, (0, 0, 0.1), 0.035), 0.04)


def sdf_apple(p):
    q = p * np.array([1.0, 1.0, 1.12])
    d = sd_sphere(q, (0, 0, 0), 0.15) / 1.12
    d = smooth_subtract(d, sd_sphere(p, (0, 0, 0.16), 0.05), 0.03)
    d = smooth_subtract(d, sd_sphere(p, (0, 0, -0.165), 0.04), 0.03)
    stem = sd_capped_cylinder(p, 0.018, 0.06, 0.175, 0.006)
    return smooth_union(d, stem, 0.015)


def sdf_paste(p):
    u = np.clip((p[:, 0] + 0.17) / 0.34, 0.0, 1.0)  # 0 at the cap end, 1 at the crimp
    a = 0.065 + 0.03 * u  # half width (y)
    b = 0.065 - 0.035 * u  # half thickness (z)
    ell = (np.sqrt((p[:, 1] / a) ** 2 + (p[:, 2] / b) ** 2) - 1.0) * np.minimum(a, b)
    ends = np.abs(p[:, 0]) - 0.17
    body = np.maximum(ell, ends)
    cap = sd_capped_cylinder(p[:, [1, 2, 0]], 0.032, -0.21, -0.16, 0.008)
    return smooth_union(body, cap, 0.01)


def sdf_chess(p):
    base = sd_capped_cylinder(p, 0.115, -0.18, -0.14, 0.012)
    z = np.linspace(-0.1, 0.06, 5)
    centre = np.stack([np.zeros(5), np.zeros(5), z], -1)
    body = sd_tapered_tube(p, centre, np.array([0.09, 0.065, 0.05, 0.042, 0.04]))
    collar = sd_capped_cylinder(p, 0.07, 0.04, 0.065, 0.01)
    head = sd_sphere(p, (0, 0, 0.12), 0.065)
    d = smooth_union(base, body, 0.03)
    d = smooth_union(d, collar, 0.01)
    return smooth_union(d, head, 0.02)


def sdf_banana(p):
    s = np.linspace(0.0, 1.0, 13)
    ang = np.radians(-60 + 120 * s)
    R = 0.2
    centre = np.stack([R * np.sin(ang), np.zeros_like(s), R * (1 - np.cos(ang)) - 0.05], -1)
    radius = 0.012 + 0.045 * np.sin(np.pi * s) ** 0.6
    return sd_tapered_tube(p, centre, radius)


@dataclass(frozen=True)
class Material:
    """An object's own material and throw for the MPM ground truth.

    E spans 5e3 .. 1e5 Pa over the seven (20x, "various stiffness levels" as the paper's
    benchmark); the stiffest sets the MPM substeps (sgdr.synth.mpm.cfl_substeps), measured in
    docs/benchmark-objects.md. Region 2 (E x stiff_ratio) is the upper half of the object along
    world axis stiff_axis, split at the particles' median (sgdr.synth.generate.simulate_drop).
    """

    E: float  # Young's modulus of region 1 (all of a homogeneous object), Pa
    nu: float  # Poisson ratio
    v0: tuple  # (3,) initial velocity, scene units / s
    stiff_ratio: float = 1.0  # E of region 2 / E of region 1 (1 = homogeneous)
    stiff_axis: int = 0  # world axis (0 x, 1 y, 2 z) whose upper half is region 2


@dataclass(frozen=True)
class ObjectSpec:
    sdf: object  # callable [N, 3] local -> [N] signed distance
    tilt_axis: tuple  # rotation applied before placement (breaks symmetry)
    tilt_deg: float
    colours: tuple  # two linear RGB colours of the pattern
    material: Material  # the object's own material and initial velocity


OBJECTS = Registry(
    "benchmark object",
    "synth.object",
    ObjectError,
    {
        # the torus keeps the material all objects shared before (the demo's measured results)
        "torus": ObjectSpec(
            sdf_torus, (1, 0, 0), 25.0, ((0.8, 0.35, 0.1), (0.95, 0.85, 0.3)), Material(2.0e4, 0.3, (0.15, 0.05, -0.5))
        ),
        "cross": ObjectSpec(
            sdf_cross, (1, 1, 0), 20.0, ((0.15, 0.35, 0.8), (0.9, 0.9, 0.9)), Material(5.0e3, 0.35, (-0.1, 0.1, -0.3))
        ),
        "cream": ObjectSpec(
            sdf_cream, (0, 1, 0), 10.0, ((0.95, 0.9, 0.75), (0.55, 0.3, 0.15)), Material(8.0e3, 0.4, (0.05, -0.1, -0.4))
        ),
        "apple": ObjectSpec(
            sdf_apple, (1, 0, 0), 15.0, ((0.75, 0.08, 0.06), (0.85, 0.75, 0.2)), Material(1.0e5, 0.25, (0.1, 0.0, -0.7))
        ),
        "paste": ObjectSpec(
            sdf_paste, (0, 0, 1), 30.0, ((0.9, 0.9, 0.95), (0.1, 0.4, 0.75)), Material(1.2e4, 0.4, (0.0, 0.15, -0.5))
        ),
        "chess": ObjectSpec(
            sdf_chess, (1, 0, 0), 0.0, ((0.1, 0.1, 0.12), (0.85, 0.8, 0.7)), Material(6.0e4, 0.2, (-0.15, 0.0, -0.6))
        ),
        "banana": ObjectSpec(
            sdf_banana, (1, 0, 0), 15.0, ((0.9, 0.8, 0.15), (0.35, 0.25, 0.05)), Material(3.5e4, 0.3, (0.1, 0.1, -0.2))
        ),
        # the ablation's heterogeneous object: the torus, its +x half 5x stiffer than its -x half
        "torus_hetero": ObjectSpec(
            sdf_torus,
            (1, 0, 0),
            25.0,
            ((0.25, 0.6, 0.3), (0.9, 0.85, 0.6)),
            Material(1.0e4, 0.3, (0.15, 0.05, -0.5), stiff_ratio=5.0, stiff_axis=0),
        ),
    },
)


# ---------------------------------------------------------------------------- building
@dataclass
class SynthObject:
    """A placed object: surface mesh, volume particles and their rest colours."""

    name: str
    mesh: object  # trimesh.Trimesh, watertight, world coordinates
    particles: np.ndarray  # [P, 3] world rest positions
    particle_volume: float  # rest volume of every particle, scene units³
    colours: np.ndarray  # [P, 3] linear RGB in [0, 1]
    sdf: object  # callable [N, 3] world -> [N] signed distance (negative inside)


def pattern(x: np.ndarray, colours, frequency: float) -> np.ndarray:
    """[N, 3] colours: a smooth 3D checker of two colours (plus a mild stripe shading)."""
    c1, c2 = (np.asarray(c, dtype=np.float64) for c in colours)
    s = np.sin(frequency * np.pi * x[:, 0]) * np.sin(frequency * np.pi * x[:, 1])
    s = s * np.sin(frequency * np.pi * x[:, 2] + 0.7)
    w = 0.5 + 0.5 * np.tanh(6.0 * s)
    stripe = 0.85 + 0.15 * np.sin(2.0 * frequency * np.pi * (x[:, 0] + x[:, 2]))
    return np.clip((w[:, None] * c1 + (1 - w[:, None]) * c2) * stripe[:, None], 0.0, 1.0)


def placed_sdf(name: str):
    """The world-space SDF of object `name`, tilted and centred in the unit cube."""
    spec = OBJECTS.get_named(name)
    R = rotation(spec.tilt_axis, spec.tilt_deg)
    # The bounding box centre of the tilted object, found on a probe lattice.
    g = np.linspace(-0.3, 0.3, 121)
    probe = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
    inside = probe[spec.sdf(probe @ R) < 0]  # world offset q = R p  <=>  p = Rᵀ q
    centre = 0.5 * (inside.min(0) + inside.max(0))
    shift = np.array([0.5, 0.5, 0.5]) - centre

    def sdf(x):
        return spec.sdf((np.asarray(x, dtype=np.float64) - shift) @ R)

    return sdf


def build_object(name: str, spacing: float, mesh_cell: float, pattern_frequency: float, seed: int):
    """Build object `name` (see module docstring).

    spacing: particle lattice spacing, scene units (rest volume per particle = spacing³).
    mesh_cell: marching-cubes cell of the reference mesh, scene units.
    pattern_frequency: spatial frequency of the colour pattern, 1 / scene unit.
    """
    import trimesh
    from skimage.measure import marching_cubes

    sdf = placed_sdf(name)
    lo, hi = BOX_LO - 0.05, BOX_HI + 0.05
    n = int(np.ceil((hi - lo) / mesh_cell)) + 1
    g = np.linspace(lo, hi, n)
    vol = sdf(np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)).reshape(n, n, n)
    step = g[1] - g[0]
    verts, faces, _, _ = marching_cubes(vol, 0.0, spacing=(step, step, step))
    mesh = trimesh.Trimesh(verts + lo, faces, process=False)
    if not mesh.is_watertight:
        raise ObjectError(f"object {name!r}: the mesh is not watertight")
    if mesh.volume < 0:
        mesh.invert()
    bmin, bmax = mesh.bounds
    if np.any(bmin < BOX_LO) or np.any(bmax > BOX_HI):
        raise ObjectError(f"object {name!r}: bounds {bmin}..{bmax} leave [{BOX_LO}, {BOX_HI}]^3")

    rng = np.random.default_rng(seed)
    g = np.arange(bmin.min() - spacing, bmax.max() + spacing, spacing)
    lattice = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
    lattice = lattice + rng.uniform(-0.25, 0.25, lattice.shape) * spacing
    particles = lattice[sdf(lattice) < 0]
    colours = pattern(particles, OBJECTS[name].colours, pattern_frequency)
    return SynthObject(name, mesh, particles, float(spacing**3), colours, sdf)
