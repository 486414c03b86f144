"""The same Gaussians as a Mitsuba 3 scene: `ellipsoids` shape + `volprim_rf_basic` integrator.

Used by the cross-check test and the benchmark as an independent reference (ray-traced 3D
Gaussians, Condor et al. / "3D Gaussian Ray Tracing"). Mitsuba's parameterisation, read from
`mitsuba/python/ad/integrators/volprim_rf_basic.py`:
- per primitive: centre, scale (standard deviations), quaternion stored (x, y, z, w) as Dr.Jit's
  `Quaternion4f`, opacity in [0, 1], SH coefficients; emission = max(SH_0 · coeff + 0.5, 0), so a
  degree-0 coefficient (rgb - 0.5) / C0 gives colour rgb (the 3DGS f_dc convention);
- transmission 1 - min(σ · exp(-½ |S⁻¹ Rᵀ (p_peak - μ)|²), 0.9999) at the kernel's peak along
  the ray; primitives composited in ray-hit order, stopping when the throughput falls below
  0.01; `srgb_primitives=False` keeps the result linear like ours; no background (black).
Differences from the splatter: exact 3D peak instead of the EWA affine projection, hit order
instead of centre-depth order, a bounding-ellipsoid cut-off instead of the α >= 1/255 test.
"""

from __future__ import annotations

import numpy as np

from sgdr.cameras import Camera
from sgdr.gaussians.model import Gaussians, sigmoid
from sgdr.gaussians.ply import SH_C0


def mitsuba_scene(gaussians: Gaussians, camera: Camera, spp: int = 1, max_depth: int = -1):
    """A loaded Mitsuba scene rendering `gaussians` from `camera` (box filter, `spp` samples)."""
    import mitsuba as mi

    d = gaussians.to_numpy()
    m = len(d["opacity_logits"])
    q = d["rotations"] / np.linalg.norm(d["rotations"], axis=1, keepdims=True)

    def tensor(a):
        return mi.TensorXf(np.ascontiguousarray(a, dtype=np.float32))

    shape = {
        "type": "ellipsoids",
        "centers": tensor(d["means"]),
        "scales": tensor(np.exp(d["log_scales"])),
        "quaternions": tensor(q[:, [1, 2, 3, 0]]),  # (w, x, y, z) -> (x, y, z, w)
        "opacities": tensor(sigmoid(d["opacity_logits"]).reshape(m, 1)),
        "sh_coeffs": tensor((sigmoid(d["color_logits"]) - 0.5) / SH_C0),
    }
    # Mitsuba's camera looks down +z with y up: build it with look_at from the OpenCV pose
    sensor = {
        "type": "perspective",
        "fov": camera.fov_x_deg,
        "fov_axis": "x",
        "to_world": mi.ScalarTransform4f().look_at(
            origin=camera.centre.tolist(), target=(camera.centre + camera.R[2]).tolist(), up=(-camera.R[1]).tolist()
        ),
        "film": {
            "type": "hdrfilm",
            "width": camera.width,
            "height": camera.height,
            "rfilter": {"type": "box"},
            "pixel_format": "rgb",
        },
        "sampler": {"type": "independent", "sample_count": int(spp)},
    }
    return mi.load_dict(
        {
            "type": "scene",
            "integrator": {"type": "volprim_rf_basic", "srgb_primitives": False, "max_depth": int(max_depth)},
            "sensor": sensor,
            "gaussians": shape,
        }
    )
