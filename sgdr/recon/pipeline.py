"""The reconstruction pipeline, stage by stage, from a multi-view sequence to a scored asset.

    static fit -> anchors/springs/IDW -> refine (frame 0) -> v0 -> dynamics -> predict
               -> evaluate -> report, asset

Each stage runs through `StageRunner` in `<run_dir>/<stage>/`: a rerun skips stages whose
outputs verify, `recon.force=true` redoes them, a damaged output is redone (see
`sgdr.recon.stages`). Every stage key holds the whole config sections the stage reads
(`stage_sections`), the digests of its inputs and the sequence's digest, so changing a
setting redoes that stage and everything after it; a field is left out of a key only by the
explicit lists below (`RECON_NEVER_IN_KEYS`, `RECON_STAGE_FIELDS`), so a forgotten field
errs on the side of recomputing.
The run folder also gets `config.yaml`, `metrics.json` and an MLflow run (`sgdr.tracking`).

Stage outputs (all under the run folder):
  static/gaussians.ply          3DGS PLY of the static fit (frame 0)
  anchors/anchors.npy           [N_A, 3] rest anchors (springs and IDW are rebuilt from them)
  refine/gaussians.ply          appearance refined at the IDW positions; losses.json
  velocity/velocity.json        v0 [3], loss per step, frames used
  dynamics/params.npz, dynamics.json   identified log10 k_i, κ, friction, restitution, n_t, losses
  predict/trajectory.npz        anchors [T, N_A, 3], centres [T, M, 3]; images.npy [T, V, H, W, 3] uint8
  evaluate/scores.json          fit/future CD, EMD, PSNR, SSIM, baseline (also metrics.json)
  report/                       side_by_side.mp4, losses.png, stiffness.png, ply/
  asset/                        what `experiments/simulate.py` loads (sgdr.recon.asset)
"""

from __future__ import annotations

import json
import logging
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from sgdr.arrays import points_to_array3
from sgdr.recon.common import frame_targets, raised_ground
from sgdr.recon.stages import StageResult, StageRunner, file_hash, key_hash

log = logging.getLogger(__name__)

STAGES = ("static", "anchors", "refine", "velocity", "dynamics", "predict", "evaluate", "report", "asset")


@dataclass
class RunOutputs:
    run_dir: Path
    metrics: dict  # what metrics.json holds
    stages: dict[str, StageResult] = field(default_factory=dict)


# ------------------------------------------------------------------------------ stage keys
# recon fields that change no stage's outputs: where the run goes, whether to redo, how many
# processes score the EMD (the scores do not depend on it), how often to checkpoint (a resume
# is exact), and the settings of the other tools (experiments/simulate.py, oracle.py).
RECON_NEVER_IN_KEYS = ("output_dir", "run_name", "force", "eval_workers", "checkpoint_every", "simulate", "oracle")
# recon fields that only one stage reads: the other stages leave them out of their keys (a
# stage after it sees them through its input digests). A recon field in none of these lists
# is in the key of every stage that reads `recon`.
RECON_STAGE_FIELDS = {
    "refine": ("refine_iterations", "lr_scale", "lr_color", "lr_opacity", "refine_lambda_dssim"),
    "velocity": ("v0_iterations", "lr_v0", "v0_lambda_dssim", "v0_views_per_step"),
    "dynamics": ("iterations", "lambda_dssim", "substep_growth", "cameras_per_frame", "lr_log10_k", "lr_kappa",
                 "lr_friction", "lr_restitution", "mode", "log10_k_grid", "log10_k_min", "log10_k_max",
                 "friction_max", "contact_margin"),
    "evaluate": ("eval_emd",),
    "report": ("render_videos", "write_plys"),
}


def recon_section(cfg, stage: str) -> dict:
    """The `recon` section as stage `stage` sees it for its key: every field except
    `RECON_NEVER_IN_KEYS` and the fields other stages own (`RECON_STAGE_FIELDS`)."""
    from sgdr.recon.stages import plain

    others = {f for name, fields in RECON_STAGE_FIELDS.items() if name != stage for f in fields}
    return {k: v for k, v in plain(cfg.recon).items() if k not in others and k not in RECON_NEVER_IN_KEYS}


# The config sections each stage reads, whole, in its key (besides seeds and input digests).
STAGE_SECTIONS = {
    "static": ("static_fit", "render"),
    "anchors": ("anchors",),
    "refine": ("recon", "anchors", "render"),
    "velocity": ("recon", "render"),
    "dynamics": ("recon", "physics", "anchors", "render"),
    "predict": ("physics", "anchors", "render"),
    "evaluate": ("recon",),
    "report": ("recon",),
    "asset": ("physics", "anchors"),
}


def stage_sections(cfg, stage: str) -> dict:
    """{section: its whole config} for the sections `stage` reads (`recon` via `recon_section`)."""
    return {name: recon_section(cfg, stage) if name == "recon" else getattr(cfg, name) for name in STAGE_SECTIONS[stage]}


# ------------------------------------------------------------------------------ locating
DEFAULT_METHOD = "spring_gaus"  # conf/config.yaml's default method group


def default_run_name(cfg) -> str:
    """recon.run_name, or `<object>_<preset>_s<seed>` (`<object>_<preset>_<method>_s<seed>` for
    a method other than the default, so that two methods never share a run folder)."""
    method = "" if cfg.method == DEFAULT_METHOD else f"_{cfg.method}"
    return cfg.recon.run_name or f"{cfg.synth.object}_{cfg.preset}{method}_s{cfg.seed}"


def sequence_path(cfg) -> Path:
    """`cfg.sequence`, or `<data_dir>/<synth.object>` when empty."""
    return Path(cfg.sequence) if cfg.sequence else Path(cfg.data_dir) / cfg.synth.object


def ensure_sequence(cfg, generate_if_missing: bool = True) -> Path:
    """The sequence to reconstruct; generated with `cfg.synth` if missing and allowed.

    An existing default-located sequence whose resolution or view count differs from the
    preset's `synth` settings is refused (it was generated at another preset): pass
    `sequence=<path>` to use it anyway, or delete it to regenerate.
    """
    from sgdr.data import load_sequence

    path = sequence_path(cfg)
    if not (path / "sequence.json").exists():
        if cfg.sequence or not generate_if_missing:
            raise FileNotFoundError(f"no sequence at {path} (sequence.json missing); run `make data` or set sequence=")
        from sgdr.synth.generate import generate_sequence

        log.info("generating %s at preset %s into %s", cfg.synth.object, cfg.preset, path)
        return Path(generate_sequence(cfg.synth, path, seed=cfg.seed, progress=True))
    if not cfg.sequence:
        from sgdr.synth.generate import is_complete

        if not is_complete(path, cfg.synth):
            seq = load_sequence(path)
            cam = seq.cameras[0]
            raise ValueError(
                f"{path} ({len(seq.cameras)} views at {cam.width}px, {seq.n_frames} frames) does not match preset "
                f"{cfg.preset!r} (synth.n_views={cfg.synth.n_views}, synth.resolution={cfg.synth.resolution}, "
                f"synth.n_frames={cfg.synth.n_frames}, synth.object={cfg.synth.object}): it was generated with other "
                f"settings. Delete it to regenerate, or pass sequence={path} to use it as it is."
            )
    return path


def sequence_digest(root: Path) -> str:
    """Hash of every file of a sequence folder (names and contents)."""
    root = Path(root)
    return key_hash({str(p.relative_to(root)): file_hash(p) for p in sorted(root.rglob("*")) if p.is_file()})


def contact_margin(recon_cfg, static_gaussians) -> float:
    """Height (scene units) of the anchors' contact plane above the sequence's ground.

    The anchors are averages of Gaussian centres, i.e. interior points; the rendered surface
    extends about one Gaussian scale beyond the outermost centres. Letting the anchors touch
    the true ground sinks the visible object into it (measured on the small torus: by ~0.015,
    the lowest anchor 0.015 above the lowest ground-truth particle at frame 0). recon.contact_margin
    >= 0 is used as given; < 0 takes the median scale of the static fit's Gaussians.
    """
    if float(recon_cfg.contact_margin) >= 0.0:
        return float(recon_cfg.contact_margin)
    scales = np.exp(np.asarray(static_gaussians.to_numpy()["log_scales"], float))
    return float(np.median(scales))


# ------------------------------------------------------------------------------ the run
def run_pipeline(cfg, progress: bool = True, run_dir: Path | None = None) -> RunOutputs:
    """Reconstruct, predict, evaluate and report one sequence; returns the run's outputs.

    cfg: the composed `sgdr.config.Config` (a dataclass instance: `OmegaConf.to_object`).
    The backend must be initialised by the caller (`sgdr.backend.init`).
    """
    from sgdr.data import load_sequence
    from sgdr.tracking import RunTracker

    t_start = time.time()
    seq_root = ensure_sequence(cfg)
    t_sequence = time.time() - t_start  # generation when the sequence was missing
    seq = load_sequence(seq_root)
    name = default_run_name(cfg)
    run_dir = Path(run_dir) if run_dir is not None else Path(cfg.recon.output_dir) / name
    with RunTracker(run_dir, cfg, cfg.tracking, run_name=name) as tracker:
        out = _run_stages(cfg, seq, seq_root, run_dir, tracker, progress)
        metrics = dict(out.stages["evaluate"].value)
        dyn = out.stages["dynamics"].value
        metrics.update(
            {
                "object": cfg.synth.object,
                "preset": cfg.preset,
                "seed": cfg.seed,
                "sequence": str(seq_root),
                "dynamic_loss_first_pass": dyn["pass_losses"][0] if dyn["pass_losses"] else None,
                "dynamic_loss_last_pass": dyn["pass_losses"][-1] if dyn["pass_losses"] else None,
                "dynamic_eval_loss_initial": dyn["eval_loss_initial"],
                "dynamic_eval_loss_final": dyn["eval_loss_final"],
                "identified": {
                    "log10_k_mean": float(np.mean(dyn["log10_k"])),
                    "log10_k_std": float(np.std(dyn["log10_k"])),
                    "kappa": dyn["kappa"],
                    "friction": dyn["friction"],
                    "restitution": dyn["restitution"],
                    "v0": list(out.stages["velocity"].value["v0"]),
                },
                "stages_skipped": [n for n, r in out.stages.items() if r.skipped],
                "stage_seconds": {"sequence": t_sequence, **{n: r.seconds for n, r in out.stages.items()}},
                "minutes": (time.time() - t_start) / 60.0,
            }
        )
        for i, loss in enumerate(dyn["pass_losses"]):
            tracker.log_metrics({"dynamic_pass_loss": loss}, step=i)
        tracker.finish(metrics)
        tracker.log_artifact(run_dir / "report", "report")
        out.metrics = metrics
    return out


def _run_stages(cfg, seq, seq_root: Path, run_dir: Path, tracker, progress: bool) -> RunOutputs:
    from sgdr.anchors import IDWBinding, sample_anchors
    from sgdr.gaussians.ply import load_ply, save_ply
    from sgdr.gaussians.static_fit import fit_static
    from sgdr.physics import build_spring_model

    runner = StageRunner(run_dir, force=cfg.recon.force)
    seq_hash = sequence_digest(seq_root)
    stages: dict[str, StageResult] = {}
    cameras = list(seq.cameras)

    # ---- 1. static fit on frame 0 of every view
    def static_produce(out: Path, ckpt) -> None:
        images = [seq.image(v, 0) for v in range(len(cameras))]
        g = fit_static(images, cameras, cfg.static_fit, cfg.render, None, cfg.seed, progress=progress)
        save_ply(out / "gaussians.ply", g)

    stages["static"] = runner.run(
        "static",
        {**stage_sections(cfg, "static"), "seed": cfg.seed, "sequence": seq_hash},
        static_produce,
        lambda out: load_ply(out / "gaussians.ply"),
    )
    static_g = stages["static"].value

    # ---- 2. anchors (springs and IDW are deterministic functions of them)
    def anchors_produce(out: Path, ckpt) -> None:
        centres = static_g.to_numpy()["means"]
        a = sample_anchors(centres, cfg.anchors.n_anchors, cfg.anchors.sampler, cfg.anchors.voxel_size, cfg.seed)
        np.save(out / "anchors.npy", np.asarray(a, dtype=np.float64))

    def anchors_load(out: Path) -> np.ndarray:
        a = np.load(out / "anchors.npy", allow_pickle=False)
        if a.ndim != 2 or a.shape[1] != 3 or not np.all(np.isfinite(a)):
            raise ValueError(f"anchors.npy has shape {a.shape} or non-finite values")
        return a

    stages["anchors"] = runner.run(
        "anchors",
        {**stage_sections(cfg, "anchors"), "seed": cfg.seed, "input": stages["static"].digest},
        anchors_produce,
        anchors_load,
    )
    anchors = stages["anchors"].value
    model = build_spring_model(anchors, cfg.anchors.n_k, cfg.physics)
    binding = IDWBinding.build(static_g.to_numpy()["means"], anchors, cfg.anchors.n_b, cfg.anchors.p_b, cfg.anchors.binding)
    bound_means = binding.apply(points_to_array3(anchors))

    # ---- 3. refine scale, colour, opacity at the IDW positions (frame 0)
    def refine_produce(out: Path, ckpt) -> None:
        from sgdr.recon.refine import refine_appearance

        res = refine_appearance(static_g, bound_means, frame_targets(seq, 0), cameras, cfg.recon, cfg.render, cfg.seed, progress)
        save_ply(out / "gaussians.ply", res.gaussians)
        (out / "losses.json").write_text(json.dumps(res.losses))

    stages["refine"] = runner.run(
        "refine",
        {**stage_sections(cfg, "refine"), "seed": cfg.seed,
         "input": [stages["static"].digest, stages["anchors"].digest]},
        refine_produce,
        lambda out: (load_ply(out / "gaussians.ply"), json.loads((out / "losses.json").read_text())),
    )
    gaussians, refine_losses = stages["refine"].value

    # ---- 4. v0 from the free-fall frames before the hit frame
    def velocity_produce(out: Path, ckpt) -> None:
        from sgdr.recon.velocity import fit_initial_velocity

        frames = range(1, min(int(seq.hit_frame), int(seq.n_fit)))
        targets = {f: frame_targets(seq, f) for f in frames}
        res = fit_initial_velocity(gaussians, targets, cameras, seq.fps, seq.gravity, cfg.recon, cfg.render, cfg.seed, progress)
        (out / "velocity.json").write_text(
            json.dumps({"v0": res.v0.tolist(), "losses": res.losses, "frames": res.frames, "note": res.note})
        )

    def velocity_load(out: Path) -> dict:
        d = json.loads((out / "velocity.json").read_text())
        if len(d["v0"]) != 3:
            raise ValueError("velocity.json: v0 must have 3 entries")
        return d

    stages["velocity"] = runner.run(
        "velocity",
        {**stage_sections(cfg, "velocity"), "seed": cfg.seed,
         "sequence": seq_hash, "input": stages["refine"].digest},
        velocity_produce,
        velocity_load,
    )
    v0 = np.asarray(stages["velocity"].value["v0"], dtype=np.float64)
    margin = contact_margin(cfg.recon, static_g)
    ground = raised_ground(seq, margin)

    # ---- 5. dynamic reconstruction
    def dynamics_produce(out: Path, ckpt) -> None:
        from sgdr.recon.dynamics import fit_dynamics

        targets = [frame_targets(seq, f) for f in range(int(seq.n_fit))]
        res = fit_dynamics(
            model, binding, gaussians, v0, np.asarray(seq.gravity, float), ground, targets, cameras, seq.fps,
            cfg.physics, cfg.recon, cfg.render, cfg.seed, ckpt=ckpt,
            on_pass=lambda it, loss, n_t: tracker.log_metrics({"dynamic_pass_loss_live": loss, "n_substeps": n_t}, step=it),
            progress=progress,
        )
        np.savez(out / "params.npz", log10_k=res.log10_k)
        (out / "dynamics.json").write_text(
            json.dumps(
                {"kappa": res.kappa, "friction": res.friction, "restitution": res.restitution,
                 "n_substeps": res.n_substeps, "pass_losses": res.pass_losses,
                 "eval_loss_initial": res.eval_loss_initial, "eval_loss_final": res.eval_loss_final,
                 "log10_k_grid_losses": res.k_grid}
            )
        )

    def dynamics_load(out: Path) -> dict:
        d = json.loads((out / "dynamics.json").read_text())
        with np.load(out / "params.npz", allow_pickle=False) as z:
            d["log10_k"] = z["log10_k"]
        if d["log10_k"].shape != (anchors.shape[0],):
            raise ValueError(f"params.npz: log10_k has shape {d['log10_k'].shape}, expected ({anchors.shape[0]},)")
        return d

    stages["dynamics"] = runner.run(
        "dynamics",
        {**stage_sections(cfg, "dynamics"), "seed": cfg.seed,
         "sequence": seq_hash, "input": [stages["refine"].digest, stages["velocity"].digest]},
        dynamics_produce,
        dynamics_load,
    )
    dyn = stages["dynamics"].value
    values = {**{k: dyn[k] for k in ("log10_k", "kappa", "friction", "restitution")}, "v0": v0, "gravity": seq.gravity}

    # ---- 6. future prediction: fit frames re-simulated from frame 0, then the future
    def predict_produce(out: Path, ckpt) -> None:
        from sgdr.recon.predict import physical_params, predict

        params = physical_params(model, cfg.physics, values)
        pred = predict(model, params, binding, gaussians, ground, seq.n_frames, seq.fps, dyn["n_substeps"],
                       cfg.physics, cameras, cfg.render, True, progress)
        np.savez(out / "trajectory.npz", anchors=pred.anchors, centres=pred.centres)
        np.save(out / "images.npy", pred.images)

    def predict_load(out: Path):
        from sgdr.recon.predict import Prediction

        with np.load(out / "trajectory.npz", allow_pickle=False) as z:
            a, c = z["anchors"], z["centres"]
        imgs = np.load(out / "images.npy", allow_pickle=False)
        if a.shape[0] != seq.n_frames or c.shape[0] != seq.n_frames or imgs.shape[:2] != (seq.n_frames, len(cameras)):
            raise ValueError("predict outputs do not cover every frame and view of the sequence")
        return Prediction(a, c, imgs)

    stages["predict"] = runner.run(
        "predict",
        {**stage_sections(cfg, "predict"),
         "input": [stages["dynamics"].digest, stages["velocity"].digest]},
        predict_produce,
        predict_load,
    )
    pred = stages["predict"].value

    # ---- 7. evaluation
    def evaluate_produce(out: Path, ckpt) -> None:
        from sgdr.recon.evaluate import evaluate_prediction

        scores = evaluate_prediction(pred, seq, with_emd=cfg.recon.eval_emd, seed=cfg.seed, workers=cfg.recon.eval_workers)
        (out / "scores.json").write_text(json.dumps(scores, indent=1, default=float))

    stages["evaluate"] = runner.run(
        "evaluate",
        {**stage_sections(cfg, "evaluate"), "seed": cfg.seed, "sequence": seq_hash,
         "input": stages["predict"].digest},
        evaluate_produce,
        lambda out: json.loads((out / "scores.json").read_text()),
    )

    # ---- 8. report: videos, plots, per-frame PLYs
    def report_produce(out: Path, ckpt) -> None:
        from sgdr.recon import report

        if cfg.recon.render_videos:
            frames = [
                report.side_by_side([seq.image(v, f) for v in range(len(cameras))], list(pred.images[f]))
                for f in range(seq.n_frames)
            ]
            report.write_video(out / "side_by_side.mp4", frames, seq.fps)
            report.write_video(out / "future.mp4", frames[seq.n_fit :], seq.fps)
        curves = {"refine": refine_losses, "v0": stages["velocity"].value["losses"], "dynamics (per pass)": dyn["pass_losses"]}
        report.plot_losses(out / "losses.png", {k: v for k, v in curves.items() if v})
        report.plot_stiffness(out / "stiffness.png", anchors, dyn["log10_k"])
        if cfg.recon.write_plys:
            colours = 1.0 / (1.0 + np.exp(-gaussians.to_numpy()["color_logits"]))
            report.write_frame_plys(out / "ply", list(pred.centres), "centres", colours)
            report.write_frame_plys(out / "ply", list(pred.anchors), "anchors")

    stages["report"] = runner.run(
        "report",
        {**stage_sections(cfg, "report"),
         "input": [stages["predict"].digest, stages["evaluate"].digest, stages["refine"].digest]},
        report_produce,
        lambda out: sorted(str(p.relative_to(out)) for p in out.rglob("*") if p.is_file()),
    )

    # ---- 9. the simulatable asset
    def asset_produce(out: Path, ckpt) -> None:
        from sgdr.recon.asset import save_asset

        save_asset(out, gaussians, anchors, values, cfg.physics, cfg.anchors, seq, dyn["n_substeps"], static_g.to_numpy()["means"],
                   ground_point=ground.point)

    def asset_load(out: Path):
        from sgdr.recon.asset import load_asset

        return load_asset(out)

    stages["asset"] = runner.run(
        "asset",
        {**stage_sections(cfg, "asset"),
         "input": [stages["dynamics"].digest, stages["refine"].digest, stages["velocity"].digest], "sequence": seq_hash,
         "ground_point": ground.point.tolist()},
        asset_produce,
        asset_load,
    )
    return RunOutputs(run_dir, {}, stages)
