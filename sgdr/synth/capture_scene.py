"""The simulated capture's Mitsuba scenes and its camera pipeline.

Scenes (simulation frame, sgdr's unit cube, z up), built on `sgdr.synth.render_gt`:
- `table_dict`: a square `rectangle` on the plane z = height facing up, two-sided diffuse,
  whose albedo is a colour times (1 + amplitude x smooth noise) (a bitmap texture, seeded), so
  that the background is neither black nor uniform;
- `build_scene(surface, table, light)`: the lighting rig of `render_gt.scene_dict` (path
  tracer, constant environment, square area light above the object) with the object's
  marching-cubes mesh and/or the table: the object on the table (photos, video frames), the
  table alone (background plates), the object alone (`mask_scene`: alpha = coverage, the
  masks' source; a one-bounce integrator, since only whether a ray hits matters);
- `render_linear(scene, sensors, spp, seed)`: [V, H, W, 4] float32, linear RGB and alpha.

Camera pipeline (`expose`): linear radiance x exposure x per-channel white-balance gains, plus
Gaussian sensor noise (σ in linear units), clipped, encoded with the sRGB curve and quantised
to 8 bits; `write_jpeg` / `write_mask` store the results (RGB JPEG; 8-bit single-channel PNG,
255 = object).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from sgdr.synth.render_gt import SurfaceMesh, scene_dict, srgb, to_mitsuba_mesh


def table_texture(colour, amplitude: float, cells: int, rng: np.random.Generator, size: int = 512) -> np.ndarray:
    """[size, size, 3] float32 linear albedo: colour x (1 + amplitude n), n smooth noise in [-1, 1]
    with `cells` noise cells across (bicubic upsampling of a random grid)."""

    coarse = rng.uniform(-1.0, 1.0, (cells, cells)).astype(np.float32)
    n = cv2.resize(coarse, (size, size), interpolation=cv2.INTER_CUBIC)
    fine = cv2.resize(rng.uniform(-1.0, 1.0, (4 * cells, 4 * cells)).astype(np.float32), (size, size))
    n = np.clip(0.7 * n + 0.3 * fine, -1.0, 1.0)
    tex = np.asarray(colour, dtype=np.float32)[None, None, :] * (1.0 + amplitude * n[..., None])
    return np.clip(tex, 0.0, 1.0).astype(np.float32)


def table_dict(centre, height: float, size: float, texture: np.ndarray) -> dict:
    """Mitsuba dict of the table: a size x size square at z = height centred at centre[:2]
    (reusable in any number of scenes)."""
    import mitsuba as mi

    to_world = mi.ScalarTransform4f().translate([float(centre[0]), float(centre[1]), float(height)])
    to_world = to_world @ mi.ScalarTransform4f().scale([0.5 * size, 0.5 * size, 1.0])
    return {
        "type": "rectangle",
        "to_world": to_world,
        # loaded once: a scene takes the texture's tensor over, so a dict could serve only one scene
        "bsdf": mi.load_dict(
            {
                "type": "twosided",
                "bsdf": {
                    "type": "diffuse",
                    "reflectance": {"type": "bitmap", "data": mi.TensorXf(texture), "raw": True},
                },
            }
        ),
    }


def build_scene(surface: SurfaceMesh | None, table: dict | None, light: dict):
    """The object (if any) and the table (if any) under the lighting rig (module docstring).

    light: keyword arguments of `sgdr.synth.render_gt.scene_dict` (everything but the mesh).
    """
    import mitsuba as mi

    d = scene_dict(to_mitsuba_mesh(surface) if surface is not None else None, **light)
    if surface is None:
        del d["object"]
    if table is not None:
        d["table"] = table
    return mi.load_dict(d)


def mask_scene(surface: SurfaceMesh):
    """The object alone with a one-bounce integrator: its renders' alpha is the coverage."""
    import mitsuba as mi

    return mi.load_dict(
        {"type": "scene", "integrator": {"type": "path", "max_depth": 1}, "object": to_mitsuba_mesh(surface)}
    )


def render_linear(scene, sensors: list, spp: int, seed: int) -> np.ndarray:
    """[V, H, W, 4] float32: linear RGB and alpha (coverage) of each sensor."""
    import mitsuba as mi

    out = [np.array(mi.render(scene, sensor=s, spp=int(spp), seed=int(seed) * 1009 + i)) for i, s in enumerate(sensors)]
    return np.stack(out).astype(np.float32)


def expose(linear_rgb, exposure: float, wb, noise_sigma: float, rng: np.random.Generator) -> np.ndarray:
    """[..., 3] linear radiance -> [..., 3] uint8 sRGB (module docstring)."""
    x = np.asarray(linear_rgb, dtype=np.float64) * exposure * np.asarray(wb, dtype=np.float64)
    if noise_sigma > 0:
        x = x + rng.normal(0.0, noise_sigma, x.shape)
    return np.round(srgb(np.clip(x, 0.0, 1.0)) * 255.0).astype(np.uint8)


def write_jpeg(path, rgb_u8: np.ndarray, quality: int) -> Path:
    """Write an [H, W, 3] uint8 RGB image as a JPEG (`quality` 1-100)."""

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    rgb = np.asarray(rgb_u8)
    if rgb.ndim == 2:
        rgb = np.repeat(rgb[..., None], 3, -1)
    if not cv2.imwrite(str(path), rgb[..., ::-1].copy(), [cv2.IMWRITE_JPEG_QUALITY, int(quality)]):
        raise OSError(f"{path}: the JPEG could not be written")
    return path


def write_mask(path, mask: np.ndarray) -> Path:
    """Write an [H, W] bool mask as an 8-bit single-channel PNG (255 = object)."""

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), np.where(np.asarray(mask, dtype=bool), 255, 0).astype(np.uint8)):
        raise OSError(f"{path}: the PNG could not be written")
    return path
