"""Ground-truth images: particles -> surface mesh -> Mitsuba path tracing, RGBA on black.

Per frame:
1. `surface_mesh`: particle counts on a grid (cell = 1 / synth.surface_grid), blurred by a
   Gaussian of synth.surface_sigma cells, divided by the count a fully occupied cell holds
   at rest; scikit-image marching cubes at synth.surface_level gives a closed mesh (the grid
   is padded, so the surface never touches its border). Each vertex takes the rest-state
   colour of its nearest particle (the colours move with the material).
2. `render_views`: a Mitsuba scene (variant chosen by `sgdr.backend`, `llvm_ad_rgb` by
   default) with a `path` integrator that hides emitters, a constant environment emitter and a
   square area light above the object, and the mesh with a two-sided diffuse BSDF whose
   reflectance is the `vertex_color` mesh attribute. Each camera becomes a `perspective`
   sensor with an RGBA `hdrfilm` and a box reconstruction filter, so alpha is exactly the
   fraction of a pixel's samples that hit the object. Missing rays return zero radiance, so
   RGB is already composited on black; it is encoded with the sRGB curve for the PNGs.

Cameras: `sgdr.cameras.Camera` uses OpenCV axes (x right, y down, z forward); a Mitsuba
perspective sensor looks down its local +z with +y up and +x to the left, so its to_world is
the OpenCV camera-to-world times diag(-1, -1, 1). `hemisphere_cameras` puts the views on the
upper hemisphere around the look-at target with a golden-angle azimuth sequence.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import gaussian_filter
from scipy.spatial import cKDTree

from sgdr.cameras import Camera

_CV_TO_MI = np.diag([-1.0, -1.0, 1.0, 1.0])


class RenderError(ValueError):
    """A camera or mesh the ground-truth renderer cannot handle; the message says which."""


# ---------------------------------------------------------------------------- cameras
def hemisphere_cameras(n_views, resolution, target, radius, fov_deg, elevation_deg, up) -> list[Camera]:
    """n_views cameras at distance `radius` from `target`, elevations spread over
    [elevation_deg[0], elevation_deg[1]] above the plane normal to `up`, golden-angle azimuths."""
    up = np.asarray(up, dtype=np.float64)
    up = up / np.linalg.norm(up)
    a = np.cross(up, [1.0, 0.0, 0.0] if abs(up[0]) < 0.9 else [0.0, 1.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(up, a)
    lo, hi = np.radians(elevation_deg[0]), np.radians(elevation_deg[1])
    golden = np.pi * (3.0 - np.sqrt(5.0))
    cams = []
    for i in range(n_views):
        el = lo + (hi - lo) * ((i + 0.5) / n_views)
        az = i * golden
        d = np.cos(el) * (np.cos(az) * a + np.sin(az) * b) + np.sin(el) * up
        eye = np.asarray(target, dtype=np.float64) + radius * d
        cams.append(Camera.look_at(eye, target, up, fov_deg, resolution, resolution, f"view_{i:02d}"))
    return cams


def mitsuba_to_world(camera: Camera) -> np.ndarray:
    """[4, 4] to_world of a Mitsuba perspective sensor that sees what `camera` sees."""
    return camera.c2w @ _CV_TO_MI


def sensor_dict(camera: Camera, spp: int) -> dict:
    """Mitsuba dict of a perspective sensor with an RGBA film for an OpenCV `camera`.

    Supports square pixels and principal points at the image centre (the generator's cameras);
    anything else raises `RenderError`.
    """
    import mitsuba as mi

    K, w, h = camera.K, camera.width, camera.height
    if abs(K[0, 0] - K[1, 1]) > 1e-6 * K[0, 0]:
        raise RenderError(f"camera {camera.name!r}: fx != fy is not supported by the GT renderer")
    if abs(K[0, 2] - 0.5 * w) > 1e-6 or abs(K[1, 2] - 0.5 * h) > 1e-6:
        raise RenderError(f"camera {camera.name!r}: principal point must be the image centre")
    return {
        "type": "perspective",
        "fov": camera.fov_x_deg,
        "fov_axis": "x",
        "to_world": mi.ScalarTransform4f(mitsuba_to_world(camera).tolist()),
        "film": {
            "type": "hdrfilm",
            "width": w,
            "height": h,
            "pixel_format": "rgba",
            "rfilter": {"type": "box"},
            "sample_border": False,
        },
        "sampler": {"type": "independent", "sample_count": int(spp)},
    }


# ---------------------------------------------------------------------------- surface
@dataclass
class SurfaceMesh:
    vertices: np.ndarray  # [V, 3] world
    faces: np.ndarray  # [T, 3] vertex indices, counter-clockwise seen from outside
    normals: np.ndarray  # [V, 3] unit outward vertex normals
    colours: np.ndarray  # [V, 3] linear RGB in [0, 1]


def surface_mesh(x, rest_colours, particle_volume, cell, sigma_cells, level) -> SurfaceMesh:
    """Marching-cubes surface of particles x [P, 3] with vertex colours (module docstring).

    particle_volume: rest volume per particle (scene units³); cell: density grid cell (scene
    units); sigma_cells: Gaussian blur in cells; level: iso-level relative to a full cell.
    """
    from skimage.measure import marching_cubes

    x = np.asarray(x, dtype=np.float64)
    pad = int(np.ceil(3.0 * sigma_cells)) + 2
    lo = x.min(0) - pad * cell
    shape = np.ceil((x.max(0) + pad * cell - lo) / cell).astype(int) + 1
    edges = [lo[a] + cell * np.arange(shape[a] + 1) for a in range(3)]
    counts, _ = np.histogramdd(x, bins=edges)
    density = gaussian_filter(counts, sigma_cells, mode="constant") * (particle_volume / cell**3)
    verts, faces, normals, _ = marching_cubes(density, level, spacing=(cell, cell, cell))
    verts = verts + lo + 0.5 * cell  # histogram cell centres
    # Normals point towards decreasing density (outwards); make the winding agree with them
    # (counter-clockwise seen from outside = positive signed volume).
    v0, v1, v2 = (verts[faces[:, k]] - verts.mean(0) for k in range(3))
    if np.einsum("ij,ij->", v0, np.cross(v1, v2)) < 0:
        faces = faces[:, ::-1]
    _, nearest = cKDTree(x).query(verts)
    return SurfaceMesh(verts, faces.astype(np.int64), normals, np.asarray(rest_colours)[nearest])


def to_mitsuba_mesh(surface: SurfaceMesh, name: str = "object"):
    """A `mi.Mesh` with a two-sided diffuse BSDF reading the `vertex_color` attribute."""
    import mitsuba as mi

    props = mi.Properties()
    props["bsdf"] = mi.load_dict(
        {
            "type": "twosided",
            "bsdf": {"type": "diffuse", "reflectance": {"type": "mesh_attribute", "name": "vertex_color"}},
        }
    )
    mesh = mi.Mesh(name, len(surface.vertices), len(surface.faces), props=props, has_vertex_normals=True)
    mesh.add_attribute("vertex_color", 3, mi.Float(surface.colours.astype(np.float32).ravel()))
    params = mi.traverse(mesh)
    params["vertex_positions"] = mi.Float(surface.vertices.astype(np.float32).ravel())
    params["vertex_normals"] = mi.Float(surface.normals.astype(np.float32).ravel())
    params["faces"] = mi.UInt32(surface.faces.astype(np.uint32).ravel())
    params.update()
    return mesh


def scene_dict(mesh, target, up, env_radiance, light_radiance, light_size, light_height, max_depth) -> dict:
    """The lighting rig around `mesh` (module docstring)."""
    import mitsuba as mi

    target = np.asarray(target, dtype=np.float64)
    up = np.asarray(up, dtype=np.float64) / np.linalg.norm(up)
    side = np.cross(up, [1.0, 0.0, 0.0] if abs(up[0]) < 0.9 else [0.0, 1.0, 0.0])
    light_to_world = mi.ScalarTransform4f().look_at(
        origin=(target + light_height * up).tolist(), target=target.tolist(), up=side.tolist()
    ) @ mi.ScalarTransform4f().scale([0.5 * light_size, 0.5 * light_size, 1.0])
    return {
        "type": "scene",
        "integrator": {"type": "path", "max_depth": int(max_depth), "hide_emitters": True},
        "environment": {"type": "constant", "radiance": {"type": "rgb", "value": float(env_radiance)}},
        "light": {
            "type": "rectangle",
            "to_world": light_to_world,
            "emitter": {"type": "area", "radiance": {"type": "rgb", "value": float(light_radiance)}},
        },
        "object": mesh,
    }


def srgb(linear: np.ndarray) -> np.ndarray:
    """The sRGB transfer curve on linear values in [0, 1]."""
    c = np.clip(linear, 0.0, 1.0)
    return np.where(c <= 0.0031308, 12.92 * c, 1.055 * np.power(c, 1.0 / 2.4) - 0.055)


def render_views(surface: SurfaceMesh, sensors: list, spp: int, seed: int, light: dict) -> np.ndarray:
    """[V, H, W, 4] float32: sRGB RGB composited on black and alpha = coverage, one per sensor.

    sensors: Mitsuba sensors from `sensor_dict`; light: keyword arguments of `scene_dict`
    (everything but the mesh).
    """
    import mitsuba as mi

    scene = mi.load_dict(scene_dict(to_mitsuba_mesh(surface), **light))
    out = []
    for i, sensor in enumerate(sensors):
        img = np.array(mi.render(scene, sensor=sensor, spp=int(spp), seed=int(seed) * 1009 + i))
        rgb, alpha = img[..., :3], img[..., 3:4]
        out.append(np.concatenate([srgb(rgb), np.clip(alpha, 0.0, 1.0)], -1))
    return np.stack(out).astype(np.float32)
