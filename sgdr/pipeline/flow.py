"""What each pipeline stage computes and how its outputs are read back: one `produce` and one
`load` per stage, over a `RunContext` that holds the sequence, the config and the values of the
stages already run. The order, keys and file layout of the stages are the table in
`sgdr.pipeline.run`; the maths lives in the stage packages (`sgdr.static_fit`, `sgdr.anchors`,
`sgdr.skin`, `sgdr.identify`, `sgdr.physics`, `sgdr.evaluate`).

`produce(ctx, out, ckpt)` writes the stage's files into `out` (a `Checkpoint` for stages that
resume mid-way); `load(ctx, out)` reads them back, validating shapes, and returns the value
later stages see as `ctx.values[<stage>]`.
"""

from __future__ import annotations

import json
from functools import cached_property
from pathlib import Path

import numpy as np

from sgdr.anchors import sample_anchors
from sgdr.arrays import points_to_array3
from sgdr.asset.predict import Prediction, audit_momentum, physical_params, predict
from sgdr.asset.store import load_asset, save_asset
from sgdr.evaluate.score import evaluate_prediction, strict_json
from sgdr.gaussians.ply import load_ply, save_ply
from sgdr.identify.appearance import refine_appearance
from sgdr.identify.dynamics import fit_dynamics
from sgdr.identify.velocity import fit_initial_velocity
from sgdr.observe.targets import frame_targets, raised_ground
from sgdr.physics import build_spring_model
from sgdr.report import media as report
from sgdr.report.html import Section, run_sections, table, write_report
from sgdr.report.verdict import judge
from sgdr.skin import IDWBinding
from sgdr.static_fit.fit import fit_static
from sgdr.static_fit.scan import fit_scan, register_scan


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


class RunContext:
    """One run: the sequence, its cameras, the config, the tracker, and `values[stage]` of every
    stage run so far. Quantities derived from several stages (the spring model, the skinning,
    the contact plane, the identified parameters) are computed once, on first use."""

    def __init__(self, cfg, seq, tracker, progress: bool):
        self.cfg, self.seq, self.tracker, self.progress = cfg, seq, tracker, progress
        self.cameras = list(seq.cameras)
        self.values: dict[str, object] = {}

    @cached_property
    def static_centres(self) -> np.ndarray:  # [M, 3] world: the static fit's Gaussian centres
        return self.values["static"].to_numpy()["means"]

    @cached_property
    def model(self):  # SpringModel from the rest anchors (kNN springs, Eqs. 5-7)

        return build_spring_model(self.values["anchors"], self.cfg.anchors.n_k, self.cfg.physics)

    @cached_property
    def binding(self):  # the skinning of the static centres to the anchors (Eq. 14)

        a = self.cfg.anchors
        return IDWBinding.build(self.static_centres, self.values["anchors"], a.n_b, a.p_b, a.binding)

    @cached_property
    def ground(self):  # the anchors' contact plane: the sequence's ground raised by the margin
        return raised_ground(self.seq, contact_margin(self.cfg.recon, self.values["static"]))

    @property
    def gaussians(self):  # refined Gaussians (appearance at the bound positions)
        return self.values["refine"][0]

    @property
    def v0(self) -> np.ndarray:  # [3] identified initial velocity
        return np.asarray(self.values["velocity"]["v0"], dtype=np.float64)

    @property
    def identified(self) -> dict:  # physical values of the asset (sgdr.asset.predict.physical_params)
        dyn = self.values["dynamics"]
        return {
            **{k: dyn[k] for k in ("log10_k", "kappa", "friction", "restitution")},
            "v0": self.v0,
            "gravity": self.seq.gravity,
        }


# ---------------------------------------------------------------------- 1. static fit (frame 0)
def static_produce(ctx: RunContext, out: Path, ckpt) -> None:
    if "static" in ctx.seq.extras:  # a real capture: fit its static scan, register it into the dynamic frame
        return _static_real_capture(ctx, out)
    images = [ctx.seq.image(v, 0) for v in range(len(ctx.cameras))]
    g = fit_static(images, ctx.cameras, ctx.cfg.static_fit, ctx.cfg.render, None, ctx.cfg.seed, progress=ctx.progress)
    save_ply(out / "gaussians.ply", g)


def _static_real_capture(ctx: RunContext, out: Path) -> None:
    """Sec. 4.2: Gaussians fitted to the scan (its own frame), then registered by the dynamic
    views' frame-0 masks (`sgdr.static_fit.scan`); gaussians.ply holds them in the dynamic frame."""

    cfg = ctx.cfg
    scan = fit_scan(ctx.seq.extras["static"], cfg.static_fit, cfg.render, cfg.seed, ctx.progress)
    save_ply(out / "scan_gaussians.ply", scan)
    g, reg = register_scan(scan, ctx.seq, cfg.static_fit, cfg.render, cfg.seed, ctx.progress)
    save_ply(out / "gaussians.ply", g)
    s, R, t = reg.as_similarity()
    (out / "registration.json").write_text(
        json.dumps(
            {
                "note": "X_dynamic = s R X_static + t (static = the scan's COLMAP frame)",
                "s": s,
                "R": R.tolist(),
                "t": t.tolist(),
                "official_form": {"s": reg.s, "R": reg.R.tolist(), "t": reg.t.tolist(), "c": reg.c.tolist()},
                "losses": reg.losses,
            },
            indent=1,
        )
    )


def static_load(ctx: RunContext, out: Path):
    return load_ply(out / "gaussians.ply")


# ---------------------------------------------------------------------- 2. anchors
def anchors_produce(ctx: RunContext, out: Path, ckpt) -> None:
    a = ctx.cfg.anchors
    points = sample_anchors(ctx.static_centres, a.n_anchors, a.sampler, a.voxel_size, ctx.cfg.seed)
    np.save(out / "anchors.npy", np.asarray(points, dtype=np.float64))


def anchors_load(ctx: RunContext, out: Path) -> np.ndarray:
    a = np.load(out / "anchors.npy", allow_pickle=False)
    if a.ndim != 2 or a.shape[1] != 3 or not np.all(np.isfinite(a)):
        raise ValueError(f"anchors.npy has shape {a.shape} or non-finite values")
    return a


# ---------------------------------------------------------------------- 3. appearance at the bound positions
def refine_produce(ctx: RunContext, out: Path, ckpt) -> None:
    bound_means = ctx.binding.apply(points_to_array3(ctx.values["anchors"]))
    res = refine_appearance(
        ctx.values["static"],
        bound_means,
        frame_targets(ctx.seq, 0),
        ctx.cameras,
        ctx.cfg.recon,
        ctx.cfg.render,
        ctx.cfg.seed,
        ctx.progress,
    )
    save_ply(out / "gaussians.ply", res.gaussians)
    (out / "losses.json").write_text(json.dumps(res.losses))


def refine_load(ctx: RunContext, out: Path):
    return load_ply(out / "gaussians.ply"), json.loads((out / "losses.json").read_text())


# ---------------------------------------------------------------------- 4. v0 from the free-fall frames
def velocity_produce(ctx: RunContext, out: Path, ckpt) -> None:
    seq = ctx.seq
    targets = {f: frame_targets(seq, f) for f in range(1, min(int(seq.hit_frame), int(seq.n_fit)))}
    res = fit_initial_velocity(
        ctx.gaussians,
        targets,
        ctx.cameras,
        seq.fps,
        seq.gravity,
        ctx.cfg.recon,
        ctx.cfg.render,
        ctx.cfg.seed,
        ctx.progress,
    )
    (out / "velocity.json").write_text(
        json.dumps({"v0": res.v0.tolist(), "losses": res.losses, "frames": res.frames, "note": res.note})
    )


def velocity_load(ctx: RunContext, out: Path) -> dict:
    d = json.loads((out / "velocity.json").read_text())
    if len(d["v0"]) != 3:
        raise ValueError("velocity.json: v0 must have 3 entries")
    return d


# ---------------------------------------------------------------------- 5. dynamic reconstruction
def dynamics_produce(ctx: RunContext, out: Path, ckpt) -> None:
    seq, cfg = ctx.seq, ctx.cfg
    targets = [frame_targets(seq, f) for f in range(int(seq.n_fit))]
    res = fit_dynamics(
        ctx.model,
        ctx.binding,
        ctx.gaussians,
        ctx.v0,
        np.asarray(seq.gravity, float),
        ctx.ground,
        targets,
        ctx.cameras,
        seq.fps,
        cfg.physics,
        cfg.recon,
        cfg.render,
        cfg.seed,
        ckpt=ckpt,
        on_pass=lambda it, loss, n_t: ctx.tracker.log_metrics(
            {"dynamic_pass_loss_live": loss, "n_substeps": n_t}, step=it
        ),
        progress=ctx.progress,
        n_predict=int(seq.n_frames),
    )
    np.savez(out / "params.npz", log10_k=res.log10_k)
    (out / "dynamics.json").write_text(
        json.dumps(
            {
                "kappa": res.kappa,
                "friction": res.friction,
                "restitution": res.restitution,
                "n_substeps": res.n_substeps,
                "pass_losses": res.pass_losses,
                "eval_loss_initial": res.eval_loss_initial,
                "eval_loss_final": res.eval_loss_final,
                "log10_k_grid_losses": res.k_grid,
                "search": res.search,
                "field_prior": res.field_prior,
                "best_pass": res.best_pass,
            }
        )
    )


def dynamics_load(ctx: RunContext, out: Path) -> dict:
    d = json.loads((out / "dynamics.json").read_text())
    with np.load(out / "params.npz", allow_pickle=False) as z:
        d["log10_k"] = z["log10_k"]
    n = ctx.values["anchors"].shape[0]
    if d["log10_k"].shape != (n,):
        raise ValueError(f"params.npz: log10_k has shape {d['log10_k'].shape}, expected ({n},)")
    return d


# ---------------------------------------------------------------------- 6. prediction (fit frames from frame 0, then the future)
def predict_produce(ctx: RunContext, out: Path, ckpt) -> None:
    cfg, seq = ctx.cfg, ctx.seq
    params = physical_params(ctx.model, cfg.physics, ctx.identified)
    pred = predict(
        ctx.model,
        params,
        ctx.binding,
        ctx.gaussians,
        ctx.ground,
        seq.n_frames,
        seq.fps,
        ctx.values["dynamics"]["n_substeps"],
        cfg.physics,
        ctx.cameras,
        cfg.render,
        True,
        ctx.progress,
    )
    np.savez(out / "trajectory.npz", anchors=pred.anchors, centres=pred.centres)
    np.save(out / "images.npy", pred.images)
    momentum = audit_momentum(ctx.model, params, ctx.ground, seq.gravity, pred, seq.dt_frame, cfg.physics)
    (out / "momentum.json").write_text(json.dumps(momentum, indent=1))


def predict_load(ctx: RunContext, out: Path):
    with np.load(out / "trajectory.npz", allow_pickle=False) as z:
        a, c = z["anchors"], z["centres"]
    imgs = np.load(out / "images.npy", allow_pickle=False)
    n = ctx.seq.n_frames
    if a.shape[0] != n or c.shape[0] != n or imgs.shape[:2] != (n, len(ctx.cameras)):
        raise ValueError("predict outputs do not cover every frame and view of the sequence")
    if imgs.ndim != 5 or imgs.shape[-1] != 4:
        raise ValueError(f"predict/images.npy has shape {imgs.shape}, expected [T, V, H, W, 4] (RGBA)")
    momentum = json.loads((out / "momentum.json").read_text())
    return Prediction(a, c, imgs, momentum=momentum)


# ---------------------------------------------------------------------- 7. evaluation
def evaluate_produce(ctx: RunContext, out: Path, ckpt) -> None:
    r = ctx.cfg.recon
    scores = evaluate_prediction(
        ctx.values["predict"], ctx.seq, with_emd=r.eval_emd, seed=ctx.cfg.seed, workers=r.eval_workers
    )
    missing = scores.pop("missing")
    scores = strict_json(scores, missing)  # NaN/inf -> null, with the reason in "missing"
    scores["missing"] = missing
    (out / "scores.json").write_text(json.dumps(scores, indent=1, allow_nan=False))


def evaluate_load(ctx: RunContext, out: Path) -> dict:
    return json.loads((out / "scores.json").read_text())


# ---------------------------------------------------------------------- 8. report: report.html, videos, plots, PLYs
def report_frames(seq, pred, n_frames: int | None = None) -> list[np.ndarray]:
    """Labelled video frames of every frame (or of the first `n_frames`: a prediction of the fit
    frames only): [ground truth | prediction] per view, both over the sequence's ground plane,
    with the frame number and the FIT / FUTURE marker."""

    grounds = [report.ground_image(cam, seq.ground_point, seq.ground_normal) for cam in seq.cameras]
    frames = []
    for f in range(seq.n_frames if n_frames is None else n_frames):
        gts, preds = [], []
        for v, ground in enumerate(grounds):
            gt, p = seq.image(v, f), pred.images[f, v]
            gts.append(report.over_ground(gt[..., :3], gt[..., 3], ground))
            preds.append(report.over_ground(p[..., :3], p[..., 3], ground))
        frames.append(report.video_frame(gts, preds, f, seq.n_frames, seq.n_fit))
    return frames


def report_videos(ctx: RunContext, out: Path) -> list[tuple[Path, str]]:
    """side_by_side.mp4 (every frame) and future.mp4 written into `out` unless
    recon.render_videos is off; (file, caption) of each."""

    seq, pred = ctx.seq, ctx.values["predict"]
    videos = []
    if not ctx.cfg.recon.render_videos:
        return videos
    frames = report_frames(seq, pred)
    for name, clip, what in (
        ("side_by_side.mp4", frames, f"all {seq.n_frames} frames, fit then future"),
        ("future.mp4", frames[seq.n_fit :], f"the {seq.n_frames - seq.n_fit} future frames"),
    ):
        if clip:
            fps, repeat = report.playback(len(clip))
            report.write_video(out / name, [f for f in clip for _ in range(repeat)], fps)
            caption = (
                f"{what}, ground truth (left) | prediction (right) in every view, over the ground plane; "
                f"played at {fps / repeat:.3g} frames per second ({len(clip) * repeat / fps:.1f} s), the "
                f"sequence runs at {seq.fps:g} fps"
            )
            videos.append((out / name, caption))
    return videos


def report_produce(ctx: RunContext, out: Path, ckpt) -> None:
    cfg, seq, pred, dyn = ctx.cfg, ctx.seq, ctx.values["predict"], ctx.values["dynamics"]
    videos = report_videos(ctx, out)
    scores = ctx.values["evaluate"]
    sections = run_sections(
        out,
        scores,
        dyn,
        ctx.values["velocity"],
        ctx.values["refine"][1],
        ctx.values["anchors"],
        cfg.recon,
        cfg.physics,
        seq.n_fit,
        videos,
        ctx.values["predict"].momentum,
    )
    if cfg.recon.write_plys:
        colours = 1.0 / (1.0 + np.exp(-ctx.gaussians.to_numpy()["color_logits"]))
        report.write_frame_plys(out / "ply", list(pred.centres), "centres", colours)
        report.write_frame_plys(out / "ply", list(pred.anchors), "anchors")
    rows = [(p.name, f"{p.stat().st_size / 1024:.0f} KiB") for p in sorted(out.iterdir()) if p.is_file()]
    if cfg.recon.write_plys:
        rows.append(("ply/", "per-frame point clouds: centres_<frame>.ply, anchors_<frame>.ply"))
    rows.append(("../metrics.json", "every score and the identified parameters, strict JSON"))
    sections.append(Section("Files beside this page", table(("file", "size / content"), rows)))
    run = out.parent.name
    subtitle = (
        f"Sequence {seq.root} ({seq.layout} layout): {len(seq.cameras)} views, {seq.n_frames} frames at "
        f"{seq.fps:g} fps, frames 0..{seq.n_fit - 1} fitted, {seq.n_fit}..{seq.n_frames - 1} predicted. "
        f"Preset {cfg.preset}, method {cfg.method}, physics.contact = {cfg.physics.contact}, seed {cfg.seed}."
    )
    verdict = judge(scores, dyn, cfg.recon, cfg.physics, ctx.values["predict"].momentum)
    write_report(out / "report.html", f"sgdr run {run}", verdict, sections, subtitle)


def report_load(ctx: RunContext, out: Path) -> list[str]:
    return sorted(str(p.relative_to(out)) for p in out.rglob("*") if p.is_file())


# ---------------------------------------------------------------------- 9. the simulatable asset
def asset_produce(ctx: RunContext, out: Path, ckpt) -> None:
    save_asset(
        out,
        ctx.gaussians,
        ctx.values["anchors"],
        ctx.identified,
        ctx.cfg.physics,
        ctx.cfg.anchors,
        ctx.seq,
        ctx.values["dynamics"]["n_substeps"],
        ctx.static_centres,
        ground_point=ctx.ground.point,
    )


def asset_load(ctx: RunContext, out: Path):
    return load_asset(out)


def asset_key(ctx: RunContext) -> dict:
    return {"ground_point": ctx.ground.point.tolist()}
