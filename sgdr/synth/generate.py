"""One benchmark sequence: object -> MPM drop -> per-frame surface -> path-traced views.

`generate_sequence(cfg, out_dir, seed)` writes a complete sgdr sequence (`sgdr.data`) with
ground truth under `gt/`:
- `particles_<fff>.npy` ([P, 3] world positions per frame), `particle_colours.npy` (rest
  colours), `mesh_rest.ply` (the watertight reference mesh);
- `params.json`: material (E, ν, density, law; `E_regions`: the E of each stiffness region and
  how the regions are split), v0, gravity, ground, collider, MPM grid and time step, hit frame
  and time, seed, timings; `effects.json`: the injected effects.

The material and v0 are the object's own (`sgdr.synth.objects`, `Material`) unless
`synth.E / nu / v0 / effects.stiff_ratio / effects.stiff_axis` are set (`with_object_material`).

Injected effects change the truth, never what the sequence records: `sequence.json` always holds
the nominal scene (gravity 9.8 along -z, the planned ground), `gt/effects.json` the effects and
the true gravity and ground (`effects.gravity`, `effects.ground_offset`, `effects.ground_tilt_deg`).

Scene layout (recorded in `sequence.json`): the object starts inside [0.3, 0.7]^3 moving
with v0; the ground plane (normal +z) is placed so that the object's lowest particle reaches the height at
which the MPM collider acts (1.5 Δx above the plane) CONTACT_LEAD frames before `synth.hit_frame`;
the recorded `hit_frame` is the first frame whose centre of mass leaves the discrete free
flight by more than HIT_TOLERANCE.
The MPM grid is a cube of side 1 whose floor lies (wall_cells + 1) cells under the ground,
centred horizontally on the object's free-flight path.
"""

from __future__ import annotations

import json
import logging
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from omegaconf import OmegaConf

from sgdr.data import SequenceError, load_sequence, write_sequence
from sgdr.synth import mpm
from sgdr.synth.config import SynthConfig
from sgdr.synth.objects import OBJECTS, build_object
from sgdr.synth.render_gt import hemisphere_cameras, render_views, sensor_dict, surface_mesh

log = logging.getLogger(__name__)

GROUND_NORMAL = np.array([0.0, 0.0, 1.0])
NOMINAL_GRAVITY = np.array([0.0, 0.0, -9.8])  # what every sequence records, whatever effects.gravity is
CONTACT_CELLS = 1.5  # particle height above the plane (in Δx) at which contact starts
CONTACT_LEAD = 0.8  # planned contact time = (hit_frame - CONTACT_LEAD) / fps
HIT_TOLERANCE = 1e-3  # centre-of-mass deviation from free fall that marks the hit, scene units


def with_object_material(cfg: SynthConfig) -> SynthConfig:
    """`cfg` with every material setting left null (E, ν, v0, effects.stiff_ratio,
    effects.stiff_axis) replaced by the object's own (`sgdr.synth.objects.Material`); values set
    in the config win."""

    m = OBJECTS.get_named(cfg.object).material
    e = cfg.effects
    effects = replace(
        e,
        stiff_ratio=float(m.stiff_ratio if e.stiff_ratio is None else e.stiff_ratio),
        stiff_axis=int(m.stiff_axis if e.stiff_axis is None else e.stiff_axis),
    )
    return replace(
        cfg,
        E=float(m.E if cfg.E is None else cfg.E),
        nu=float(m.nu if cfg.nu is None else cfg.nu),
        v0=[float(c) for c in (m.v0 if cfg.v0 is None else cfg.v0)],
        effects=effects,
    )


def material_record(cfg: SynthConfig) -> dict:
    """The material of the generated object (cfg resolved by `with_object_material`): E, ν,
    density, law, and the E of every stiffness region with the rule that splits them."""

    e = cfg.effects
    own = OBJECTS.get_named(cfg.object).material
    regions = [float(cfg.E)] if e.stiff_ratio == 1.0 else [float(cfg.E), float(cfg.E * e.stiff_ratio)]
    return {
        "material": cfg.material,
        "E": float(cfg.E),
        "nu": float(cfg.nu),
        "density": float(cfg.density),
        "E_regions": regions,
        "region_rule": "one region"
        if len(regions) == 1
        else f"region 2: particles above the median of world axis {e.stiff_axis} (gt/particle_E_scale.npy)",
        "material_source": {
            "E": "object" if cfg.E == own.E else "config",
            "nu": "object" if cfg.nu == own.nu else "config",
            "v0": "object" if tuple(cfg.v0) == tuple(own.v0) else "config",
        },
    }


def effects_record(cfg: SynthConfig) -> dict:
    """The injected effects with their magnitudes, and which differ from the plain benchmark
    (the object's own heterogeneity, torus_hetero's, is not an injected effect)."""

    cfg = with_object_material(cfg)
    e = cfg.effects
    base = SynthConfig()
    own = OBJECTS.get_named(cfg.object).material
    record = {
        "plastic_yield": float(e.plastic_yield),
        "air_drag": float(e.air_drag),
        "stiff_ratio": float(e.stiff_ratio),
        "stiff_axis": int(e.stiff_axis),
        "gravity": float(e.gravity),
        "ground_offset": float(e.ground_offset),
        "ground_tilt_deg": float(e.ground_tilt_deg),
        "ground": str(cfg.ground),
        "ground_friction": float(cfg.ground_friction),
    }
    active = [
        k
        for k in ("plastic_yield", "air_drag", "gravity", "ground_offset", "ground_tilt_deg")
        if record[k] != getattr(base.effects, k)
    ]
    if (e.stiff_ratio, e.stiff_axis) != (own.stiff_ratio, own.stiff_axis) and e.stiff_ratio != 1.0:
        active.insert(2, "stiff_ratio")
    if cfg.ground != base.ground:
        active.append("ground")
    record["active"] = active
    return record


def free_fall(x0, v0, g, t):
    """Position of a point in free fall: x0 + v0 t + ½ g t² (arrays broadcast)."""
    return x0 + v0 * t + 0.5 * g * t**2


def free_flight(x0, v0, g, drag, dt, substeps, n_frames) -> np.ndarray:
    """[n_frames, 3] positions of a point under the MPM's own discrete free flight.

    The grid update applies v <- (v + dt g) / (1 + dt c) and G2P then x <- x + dt v, so this is
    the exact no-contact trajectory of the centre of mass (including its O(dt) offset from
    the continuous parabola).
    """
    x, v = np.array(x0, dtype=np.float64), np.array(v0, dtype=np.float64)
    out = [x.copy()]
    for _ in range(n_frames - 1):
        for _ in range(substeps):
            v = (v + dt * np.asarray(g)) / (1.0 + dt * drag)
            x = x + dt * v
        out.append(x.copy())
    return np.array(out)


def tilt_rotation(tilt_deg: float) -> np.ndarray:
    """The rotation about the world x axis that takes the level normal (+z) to a ground tilted by
    `tilt_deg` (`true_ground`'s normal)."""
    t = np.radians(float(tilt_deg))
    c, s = np.cos(t), np.sin(t)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def true_ground(ground_point: np.ndarray, cfg: SynthConfig) -> tuple[np.ndarray, np.ndarray]:
    """(point, unit normal) of the ground the MPM collides with: the recorded (planned) plane
    raised by `effects.ground_offset` and tilted by `effects.ground_tilt_deg` about the world x
    axis through that point. Without those effects, the recorded plane."""
    e = cfg.effects
    normal = tilt_rotation(e.ground_tilt_deg) @ GROUND_NORMAL
    return np.asarray(ground_point, float) + float(e.ground_offset) * GROUND_NORMAL, normal


def grid_origin(particles: np.ndarray, v0, floor_z: float, cfg: SynthConfig, dx: float) -> np.ndarray:
    """The MPM grid's origin: the unit cube centred horizontally on the free-flight path of
    `particles` moving with v0 (half-way through the sequence), its floor (wall_cells + 1) cells
    under `floor_z`, the lowest ground height inside it."""
    duration = (cfg.n_frames - 1) / cfg.fps
    centre = particles.mean(0) + 0.5 * np.asarray(v0, float) * duration
    return np.array([centre[0] - 0.5, centre[1] - 0.5, floor_z - (cfg.wall_cells + 1) * dx])


def plan_scene(particles: np.ndarray, cfg: SynthConfig, dx: float):
    """Ground point, gravity vector and MPM grid origin for the drop (module docstring).

    Contact starts when a particle's B-spline stencil reaches the collider band, i.e. when the
    lowest particle is 1.5 Δx above the plane; the plane lies on a grid node layer. The grid's
    floor lies (wall_cells + 1) cells under the lower of the recorded and the true ground, so a
    lowered ground stays inside the domain (a tilted ground runs in the plane's own frame, with
    its own origin: `simulate_drop`).
    """
    g = np.array([0.0, 0.0, -float(cfg.effects.gravity)])
    v0 = np.asarray(cfg.v0, dtype=np.float64)
    t_contact = (cfg.hit_frame - CONTACT_LEAD) / cfg.fps
    bottom = particles[:, 2].min()
    ground_z = free_fall(bottom, v0[2], g[2], t_contact) - CONTACT_CELLS * dx
    ground_point = np.array([0.5, 0.5, ground_z])
    point, _ = true_ground(ground_point, cfg)
    origin = grid_origin(particles, v0, min(ground_z, float(point[2])), cfg, dx)
    return ground_point, g, origin, t_contact


def measured_hit_frame(frames: np.ndarray, flight: np.ndarray) -> int:
    """First frame whose centre of mass leaves the free flight `flight` by > HIT_TOLERANCE."""
    dev = np.linalg.norm(frames.mean(1) - flight, axis=1)
    off = np.nonzero(dev > HIT_TOLERANCE)[0]
    return int(off[0]) if len(off) else len(frames) - 1


def simulate_drop(obj, cfg: SynthConfig, progress=None):
    """Run the MPM drop of a built object; returns (frames [F, P, 3], info dict).

    A tilted ground (`effects.ground_tilt_deg`) is simulated in the plane's own frame: the
    particles, v0 and gravity rotated about the true ground point so that the plane is level and
    lies on a grid node layer, the frames rotated back. On the grid itself a plane a few degrees
    off its axes is a staircase of level bands (at 48 cells per unit a 3° plane rises half a cell
    under the paste), which bounced the object as if the plane were level: the paste's bounce on
    a 3° plane drifted 0.005 units downhill by frame 10, where a spring-mass model on the same
    plane drifts 0.03 (docs/discrepancy.md, "Seventh sitting")."""

    cfg = with_object_material(cfg)
    dx = 1.0 / cfg.mpm_grid
    ground_point, g, origin, t_contact = plan_scene(obj.particles, cfg, dx)
    e = cfg.effects
    point, normal = true_ground(ground_point, cfg)
    rot = tilt_rotation(e.ground_tilt_deg)  # plane frame -> world (identity when level)
    particles, v0, g_sim = obj.particles, np.asarray(cfg.v0, float), g
    if e.ground_tilt_deg != 0.0:
        particles = point + (obj.particles - point) @ rot  # rot.T applied to each row
        v0, g_sim, normal = v0 @ rot, g @ rot, GROUND_NORMAL
        origin = grid_origin(particles, v0, float(point[2]), cfg, dx)
    E_scale = np.ones(len(obj.particles))
    if e.stiff_ratio != 1.0:
        coord = obj.particles[:, e.stiff_axis]
        E_scale[coord > np.median(coord)] = e.stiff_ratio
    E_max = cfg.E * max(1.0, e.stiff_ratio)
    dt_frame = 1.0 / cfg.fps
    v_bound = float(np.linalg.norm(cfg.v0)) + float(np.linalg.norm(g)) * t_contact + 1.0
    substeps = cfg.substeps or mpm.cfl_substeps(dt_frame, dx, E_max, cfg.nu, cfg.density, cfg.cfl, v_bound)
    dt = dt_frame / substeps
    mpm.check_cfl(dt, dx, E_max, cfg.nu, cfg.density, cfg.cfl, v_bound)
    model = mpm.create_model(
        particles,
        obj.particle_volume,
        cfg.density,
        n_grid=cfg.mpm_grid,
        dx=dx,
        origin=origin,
        dt=dt,
        material=cfg.material,
        collider=cfg.ground,
        friction=cfg.ground_friction,
        ground_point=point,
        ground_normal=normal,
        wall_cells=cfg.wall_cells,
        E_scale=E_scale,
        plastic=e.plastic_yield > 0,
    )
    params = mpm.MPMParams.create(cfg.E, cfg.nu, g_sim, drag=e.air_drag, yield_stress=e.plastic_yield)
    state = mpm.MPMState.at_rest(particles, v0)
    frames, _ = mpm.simulate(model, params, state, cfg.n_frames, substeps, cfg.cfl, progress)
    if e.ground_tilt_deg != 0.0:
        frames = np.asarray(frames)
        frames = (point + (frames.astype(float) - point) @ rot.T).astype(frames.dtype)
    info = {
        "ground_point": ground_point,
        "gravity": g,
        "grid_origin": origin.tolist(),
        "dx": dx,
        "substeps_per_frame": substeps,
        "dt": dt,
        "hit_time_planned": t_contact,
        "hit_frame": measured_hit_frame(
            frames, free_flight(frames[0].mean(0), cfg.v0, g, e.air_drag, dt, substeps, cfg.n_frames)
        ),
        "E_scale": E_scale,
        # the frame the MPM ran in: "plane" (rotated so that a tilted ground is level) or "world"
        "frame": "plane" if e.ground_tilt_deg != 0.0 else "world",
    }
    return frames, info


def cameras_for(cfg: SynthConfig):
    return hemisphere_cameras(
        cfg.n_views, cfg.resolution, cfg.camera_target, cfg.camera_radius, cfg.camera_fov,
        cfg.camera_elevation, GROUND_NORMAL,
    )  # fmt: skip


def light_rig(cfg: SynthConfig) -> dict:
    return {
        "target": cfg.camera_target,
        "up": GROUND_NORMAL,
        "env_radiance": cfg.env_radiance,
        "light_radiance": cfg.light_radiance,
        "light_size": cfg.light_size,
        "light_height": cfg.light_height,
        "max_depth": cfg.max_depth,
    }


def is_complete(out_dir, cfg: SynthConfig) -> bool:
    """True when out_dir holds a valid sequence with ground truth matching cfg's sizes and
    injected effects (a tilted ground's simulated in the plane's frame: `simulate_drop`)."""

    cfg = as_synth_config(cfg)
    try:
        seq = load_sequence(out_dir)
    except SequenceError:
        return False
    params = seq.gt_params() or {}
    want = effects_record(cfg)
    have = params.get("effects") or {}
    same_effects = all(have.get(k) == v for k, v in want.items() if k != "active")
    tilt_frame = cfg.effects.ground_tilt_deg == 0.0 or (params.get("mpm") or {}).get("frame") == "plane"
    return (
        seq.gt_dir is not None
        and seq.n_frames == cfg.n_frames
        and seq.n_views == cfg.n_views
        and all(c.width == cfg.resolution for c in seq.cameras)
        and params.get("object") == cfg.object
        and same_effects
        and tilt_frame
    )


def as_synth_config(cfg) -> SynthConfig:
    """`cfg` as a SynthConfig dataclass (accepts the Hydra DictConfig node `cfg.synth`)."""
    if isinstance(cfg, SynthConfig):
        return cfg

    merged = OmegaConf.merge(OmegaConf.structured(SynthConfig), cfg)
    return OmegaConf.to_object(merged)


def generate_sequence(cfg: SynthConfig, out_dir, seed: int, progress: bool = False) -> Path:
    """Simulate and render one object (cfg.object) into the sgdr sequence folder out_dir.

    cfg: SynthConfig (or the `synth` node of the composed Hydra config); seed: seeds the
    particle jitter and the path tracer. Returns out_dir. Takes 1-3 minutes at the small
    preset on a 2-core CPU (docs/benchmarks.md).
    """
    import mitsuba as mi

    cfg = with_object_material(as_synth_config(cfg))
    out_dir = Path(out_dir)
    timings = {}
    t0 = time.perf_counter()
    spacing = (1.0 / cfg.mpm_grid) / cfg.particles_per_cell ** (1.0 / 3.0)
    obj = build_object(cfg.object, spacing, 0.5 / cfg.surface_grid, cfg.pattern_scale, seed)
    timings["object_s"] = time.perf_counter() - t0

    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=2 * (cfg.n_frames - 1) + 1, desc=f"{cfg.object}", unit="step", leave=False)
    t0 = time.perf_counter()
    frames, info = simulate_drop(obj, cfg, progress=(lambda f: bar.update()) if bar else None)
    timings["mpm_s"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    cameras = cameras_for(cfg)
    sensors = [mi.load_dict(sensor_dict(c, cfg.spp)) for c in cameras]
    images = np.zeros((cfg.n_views, cfg.n_frames, cfg.resolution, cfg.resolution, 4), np.float32)
    for f in range(cfg.n_frames):
        surface = surface_mesh(
            frames[f], obj.colours, obj.particle_volume, 1.0 / cfg.surface_grid,
            cfg.surface_sigma, cfg.surface_level,
        )  # fmt: skip
        images[:, f] = render_views(surface, sensors, cfg.spp, seed * 100003 + f, light_rig(cfg))
        if bar:
            bar.update()
    timings["render_s"] = time.perf_counter() - t0
    if bar:
        bar.close()

    t0 = time.perf_counter()
    params = {
        "object": cfg.object,
        "seed": int(seed),
        **material_record(cfg),
        "v0": [float(c) for c in cfg.v0],
        # the truth (what the MPM used); the sequence records the nominal scene (`recorded`)
        "gravity": info["gravity"].tolist(),
        "ground": {k: v.tolist() for k, v in zip(("point", "normal"), true_ground(info["ground_point"], cfg))},
        "recorded": {
            "gravity": NOMINAL_GRAVITY.tolist(),
            "ground": {"point": info["ground_point"].tolist(), "normal": GROUND_NORMAL.tolist()},
        },
        "collider": cfg.ground,
        "ground_friction": float(cfg.ground_friction),
        "n_particles": int(len(obj.particles)),
        "particle_volume": obj.particle_volume,
        "particle_mass": obj.particle_volume * cfg.density,
        "mpm": {k: info[k] for k in ("grid_origin", "dx", "substeps_per_frame", "dt", "frame")}
        | {"n_grid": cfg.mpm_grid, "cfl": cfg.cfl, "wall_cells": cfg.wall_cells},
        "hit_frame": info["hit_frame"],
        "hit_frame_planned": int(cfg.hit_frame),
        "hit_time_planned": info["hit_time_planned"],
        "effects": effects_record(cfg),
        "timings": timings,
    }
    write_sequence(
        out_dir,
        cameras=cameras,
        images=images,
        fps=cfg.fps,
        n_fit=cfg.n_fit,
        hit_frame=info["hit_frame"],
        ground_point=info["ground_point"],
        ground_normal=GROUND_NORMAL,
        gravity=NOMINAL_GRAVITY,  # an injected effect changes the truth, never what the sequence records
        gt_particles=list(frames),
        gt_params=params,
        gt_effects=effects_record(cfg) | {"truth": {"gravity": params["gravity"], "ground": params["ground"]}},
    )
    gt = out_dir / "gt"
    np.save(gt / "particle_colours.npy", obj.colours.astype(np.float32))
    np.save(gt / "particle_E_scale.npy", info["E_scale"].astype(np.float32))
    obj.mesh.export(gt / "mesh_rest.ply")
    timings["write_s"] = time.perf_counter() - t0
    params["timings"] = timings
    (gt / "params.json").write_text(json.dumps(params, indent=2))
    log.info("%s: %s", cfg.object, {k: round(v, 2) for k, v in timings.items()})
    return out_dir
