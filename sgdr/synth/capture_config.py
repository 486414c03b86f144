"""Typed config schema of the simulated real capture (group key `realcap`).

The defaults are the CI size (`conf/preset/tiny.yaml` sets the same values explicitly;
`small.yaml` a larger capture). Lengths of the rendering rig (camera distances, the table) are
in sgdr's simulation units (the unit cube the object is built and dropped in, `sgdr.synth`);
`metres_per_unit` turns them into the dynamic frame's metres.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from sgdr.checks import any_text, at_least, between, choice, list_of, non_negative, positive, vector


@dataclass
class RealCaptureSimConfig:
    object: str = "torus"  # the sgdr.synth object dropped (torus | cross | cream | apple | paste | chess | banana)
    obj_name: str = ""  # OBJ_NAME, the object's folder name in the layout; "" = object
    seq: int = 0  # SEQ, the sequence number (dynamic/sequences/<obj>/<seq>.json)
    # --- the drop (MPM of sgdr.synth.generate.simulate_drop, in the simulation frame)
    n_frames: int = 14  # video frames of the sequence
    fps: float = 120.0  # video frame rate (FREQ; the official capture's 120)
    hit_frame: int = 5  # the object is planned to touch the ground during this frame
    v0: list = field(default_factory=lambda: [0.15, 0.05, -0.5])  # initial velocity, simulation frame (z up), units/s
    mpm_grid: int = 32  # MPM grid cells per simulation unit
    particles_per_cell: int = 4  # MPM particle sampling density
    E: float = 2.0e4  # Young's modulus, Pa
    nu: float = 0.3  # Poisson ratio
    density: float = 1.0e3  # kg / simulation unit³
    ground_friction: float = 0.5  # Coulomb μ of the MPM ground
    surface_grid: int = 48  # marching-cubes density grid, cells per simulation unit
    metres_per_unit: float = 0.25  # dynamic-frame metres per simulation unit (a 0.4-unit object is 10 cm)
    gravity: float = 9.8  # m/s² in the dynamic frame (+z); the MPM gets gravity / metres_per_unit units/s²
    # --- the dynamic (video) cameras
    video_width: int = 160  # video frame width, pixels (W)
    video_height: int = 120  # video frame height, pixels (H); W / H must equal static_width / static_height
    camera_fov: float = 40.0  # horizontal field of view of the videos AND the photos, degrees (the official K rule)
    video_radius: float = 1.8  # distance of the video cameras from their look-at point, simulation units
    video_target: float = (
        0.3  # the videos look at this fraction of the way from the board's centre to frame 0's centroid
    )
    video_azimuth: list = field(default_factory=lambda: [-140.0, -90.0, -40.0])  # per camera, degrees from board x
    video_elevation: list = field(default_factory=lambda: [42.0, 50.0, 45.0])  # per camera, degrees above the table
    video_spp: int = 8  # path-tracing samples per pixel of the video frames
    plate_spp: int = 16  # samples per pixel of the background plates
    mask_spp: int = 16  # samples per pixel of the object-only coverage (masks = coverage > 0.5)
    video_exposure: float = 1.3  # gain on linear radiance of the video cameras
    video_wb: list = field(default_factory=lambda: [1.1, 1.0, 0.85])  # video white-balance gains (R, G, B)
    # --- the static scan (photos in their own frame, written as a COLMAP model)
    static_width: int = 64  # photo width, pixels (W_S)
    static_height: int = 48  # photo height, pixels (H_S)
    static_views: int = 56  # photos, spread over the rings
    static_elevation: list = field(default_factory=lambda: [22.0, 38.0, 55.0])  # ring elevations, degrees
    static_radius: float = 0.9  # distance of the photo cameras from the object's centre, simulation units
    static_spp: int = 8  # samples per pixel of the photos
    static_exposure: float = 1.0  # gain on linear radiance of the photo camera
    static_wb: list = field(default_factory=lambda: [1.0, 1.0, 1.0])  # photo white-balance gains (R, G, B)
    static_scale: float = 0.05  # registration scale s_r: dynamic metres per static-frame unit
    static_offset: float = 1.5  # the object's centroid lies within +-this of the static origin per axis, static units
    # --- the rough initial registration written as config.yaml's REGIST
    init_rot_deg: float = 12.0  # rotation error of INIT_R, degrees (random axis)
    init_scale_err: float = 0.1  # relative error of INIT_S (random sign)
    init_trans_err: float = 0.1  # error of INIT_T, fraction of the object's size (random direction)
    # --- checkerboards (drawn analytically, sgdr.data.board)
    board_pattern: list = field(default_factory=lambda: [6, 5])  # inner corners (cols, rows); cols + rows odd
    board_square: float = 0.02  # square side, metres
    board_views: int = 20  # images per camera, the first of the world board on the table
    board_tilt_deg: float = 40.0  # the other boards are tilted up to this from facing the camera, degrees
    board_fill: list = field(default_factory=lambda: [0.6, 0.85])  # board width / image width, min and max
    board_supersample: int = 4  # samples per pixel side of the board images
    board_yaw_deg: float = 20.0  # the world board's x axis, degrees from the simulation's x axis
    # --- lights, table and sensor (the rig of sgdr.synth.render_gt.scene_dict plus a table)
    env_radiance: float = 0.35  # constant environment emitter radiance
    light_radiance: float = 12.0  # area light radiance
    light_size: float = 0.6  # area light side, simulation units
    light_height: float = 2.0  # area light height above the object, simulation units
    max_depth: int = 4  # path tracer maximum path depth
    table_size: float = 12.0  # side of the square table plane, simulation units
    table_colour: list = field(default_factory=lambda: [0.33, 0.36, 0.4])  # video table albedo (linear RGB)
    static_table_colour: list = field(default_factory=lambda: [0.45, 0.38, 0.3])  # photo table albedo (linear RGB)
    table_texture: float = 0.25  # relative amplitude of the table's noise texture
    table_texture_cells: int = 96  # noise cells across the table texture
    noise_sigma: float = 0.01  # Gaussian sensor noise, standard deviation in linear units
    jpeg_quality: int = 95  # JPEG quality of photos, frames, plates and boards
    overwrite: bool = False  # replace an existing capture made with other settings


CHECKS = {
    "object": choice("sgdr.synth.objects:OBJECTS"),
    "obj_name": any_text("the object's folder name; empty: the object's name"),
    "seq": non_negative(),
    "n_frames": at_least(2),
    "fps": positive(),
    "hit_frame": at_least(1),
    "v0": vector(3),
    "mpm_grid": at_least(8),
    "particles_per_cell": at_least(1),
    "E": positive(),
    "nu": between(0.0, 0.5, hi_open=True),
    "density": positive(),
    "ground_friction": non_negative(),
    "surface_grid": at_least(8),
    "metres_per_unit": positive(),
    "gravity": positive(),
    "video_width": at_least(16),
    "video_height": at_least(16),
    "camera_fov": between(0.0, 180.0, lo_open=True, hi_open=True),
    "video_radius": positive(),
    "video_target": between(0.0, 1.0),
    "video_azimuth": vector(3),
    "video_elevation": vector(3, each=between(5.0, 89.0)),
    "video_spp": at_least(1),
    "plate_spp": at_least(1),
    "mask_spp": at_least(1),
    "video_exposure": positive(),
    "video_wb": vector(3, each=positive()),
    "static_width": at_least(16),
    "static_height": at_least(16),
    "static_views": at_least(3),
    "static_elevation": list_of(between(5.0, 89.0), min_len=1),
    "static_radius": positive(),
    "static_spp": at_least(1),
    "static_exposure": positive(),
    "static_wb": vector(3, each=positive()),
    "static_scale": positive(),
    "static_offset": non_negative(),
    "init_rot_deg": non_negative(),
    "init_scale_err": between(0.0, 1.0, hi_open=True),
    "init_trans_err": non_negative(),
    "board_pattern": vector(2, each=at_least(2)),
    "board_square": positive(),
    "board_views": at_least(3),
    "board_tilt_deg": between(0.0, 80.0),
    "board_fill": vector(2, each=between(0.05, 1.0)),
    "board_supersample": at_least(1),
    "board_yaw_deg": between(-360.0, 360.0),
    "env_radiance": non_negative(),
    "light_radiance": non_negative(),
    "light_size": positive(),
    "light_height": positive(),
    "max_depth": at_least(1),
    "table_size": positive(),
    "table_colour": vector(3, each=between(0.0, 1.0)),
    "static_table_colour": vector(3, each=between(0.0, 1.0)),
    "table_texture": between(0.0, 1.0),
    "table_texture_cells": at_least(2),
    "noise_sigma": non_negative(),
    "jpeg_quality": between(1, 100),
}


def rule_problem(c: RealCaptureSimConfig) -> str | None:
    """The rules between the capture's fields: the error line, or None."""
    if c.video_width * c.static_height != c.video_height * c.static_width:
        return (
            f"realcap.video_width x realcap.video_height = {c.video_width} x {c.video_height} and realcap.static_width x "
            f"realcap.static_height = {c.static_width} x {c.static_height} must have the same aspect ratio (the official "
            "loader scales the photo focal lengths by W / W_S and H / H_S; square pixels need both ratios equal)"
        )
    if c.hit_frame >= c.n_frames:
        return f"realcap.hit_frame={c.hit_frame} must be < realcap.n_frames={c.n_frames}"
    if sum(c.board_pattern) % 2 == 0:
        return f"realcap.board_pattern={list(c.board_pattern)}: cols + rows must be odd (the board's first corner)"
    if not c.board_fill[0] <= c.board_fill[1]:
        return f"realcap.board_fill={list(c.board_fill)}: min must be <= max"
    return None
