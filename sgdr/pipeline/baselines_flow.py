"""The baselines' own pipeline rows (`sgdr.pipeline.run.MODELS`): what replaces the spring-mass
model's dynamics, predict, report and asset stages. The shared stages (static fit, anchors,
appearance refinement, v0) and the evaluate stage are the spring-mass pipeline's, so every
method is scored by the same code on the same Gaussians. The maths is in `sgdr.baselines`.

PAC-NeRF (`recon.model=pacnerf`, `method=pacnerf`):
  dynamics/  pacnerf.json (E, ν, the search: every candidate's loss), particles.npy (the fill)
  predict/   trajectory.npz (particles [T, P, 3] as `anchors`, Gaussian centres), images.npy
  report/    report.html: verdict, scores, videos, the search's loss landscape, the parameters
  asset/     pacnerf.json, particles.npy, gaussians.ply: the identified MPM object

Table 2's other rows, SIMPLIFIED (`recon.model=dyngaus` | `deform4d`, `method=dyngaus` |
`deform4d`; docs/baselines.md): dynamic reconstruction of the fit frames only, no physics, no future.
  dynamics/  dynamics.json (losses, the all-view loss held still and fitted), centres.npz
             (centres [n_fit, M, 3], every Adam step's loss and image loss, the frame it fitted)
  predict/   trajectory.npz (centres [n_fit, M, 3]; anchors [n_fit, 0, 3]: no anchors), images.npy
             (every view of every fit frame)
  evaluate/  scores.json: the fit frames' scores; every future score null, "the method
             reconstructs the fit frames only"
  report/    report.html: verdict of the fit, scores, the fit frames' video, the losses
  asset/     <model>.json, gaussians.ply (frame 0), centres.npy: the reconstruction (not simulatable)
"""

from __future__ import annotations

import dataclasses
import importlib
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from omegaconf import OmegaConf

from sgdr.arrays import array3_to_points, points_to_array3
from sgdr.asset.predict import Prediction
from sgdr.baselines.common import all_view_loss
from sgdr.baselines.pacnerf import ParticleSkin, fill_particles, observe, plan_scene, rollout, search
from sgdr.evaluate.score import evaluate_prediction, strict_json
from sgdr.gaussians.ply import load_ply, save_ply
from sgdr.observe.targets import frame_targets
from sgdr.pipeline.flow import RunContext, report_frames, report_videos
from sgdr.render.images import posed, render_rgba_numpy
from sgdr.report import media as report
from sgdr.report.html import Section, image, paragraph, scores_table, table, video, write_report
from sgdr.report.media import pyplot, save_figure
from sgdr.report.verdict import FIT_PSNR_FAIR, FIT_PSNR_GOOD, Verdict, baseline_warnings, fit_verdict, future_verdict


def _pacnerf_scene(ctx: RunContext, particles: np.ndarray, n_frames: int):
    cfg, seq = ctx.cfg.baseline.pacnerf, ctx.seq
    spacing = _spacing(particles, cfg)
    return plan_scene(
        particles, spacing, ctx.v0, seq.gravity, seq.ground_point, seq.ground_normal, 1.0 / seq.fps, n_frames
    )


def _spacing(gaussian_means: np.ndarray, cfg) -> float:
    """Particle lattice spacing: half an MPM cell (`dx`, or `cells_per_size` cells across the object)."""
    if cfg.dx > 0:
        return 0.5 * float(cfg.dx)
    extent = float((gaussian_means.max(0) - gaussian_means.min(0)).max())
    return extent / float(cfg.cells_per_size) / 2.0


# ---------------------------------------------------------------------- dynamics: fill + search
def pacnerf_produce(ctx: RunContext, out: Path, ckpt) -> None:
    cfg, seq = ctx.cfg.baseline.pacnerf, ctx.seq
    g = ctx.gaussians.to_numpy()
    particles = fill_particles(g, _spacing(g["means"], cfg), cfg.fill_threshold)
    scene = _pacnerf_scene(ctx, particles, seq.n_fit)
    skin = ParticleSkin(ctx.gaussians, particles, cfg.bind_k)
    res = search(scene, skin, observe(seq, cfg), cfg, ctx.cfg.render, ctx.progress)
    np.save(out / "particles.npy", particles.astype(np.float32))
    record = {
        "E": res.E,
        "log10_E": math.log10(res.E),
        "nu": res.nu,
        "loss": res.loss,
        "substeps": res.substeps,
        "n_particles": int(len(particles)),
        "particle_spacing": scene.spacing,
        "mpm_dx": scene.dx,
        "mpm_grid": scene.n_grid,
        "mpm_origin": scene.origin.tolist(),
        "collider": cfg.collider,
        "at_bound": res.at_bound,
        "evaluated": res.evaluated,
        "pass_losses": res.round_best,
        "eval_loss_initial": res.round_best[0],
        "eval_loss_final": res.loss,
        "note": "pass_losses: the best loss after each search round; eval_loss_initial: the first round's best",
    }
    (out / "pacnerf.json").write_text(json.dumps(record, indent=1))


def pacnerf_load(ctx: RunContext, out: Path) -> dict:
    d = json.loads((out / "pacnerf.json").read_text())
    d["particles"] = np.load(out / "particles.npy", allow_pickle=False)
    if d["particles"].ndim != 2 or d["particles"].shape[1] != 3 or not math.isfinite(d["E"]):
        raise ValueError("dynamics/particles.npy or pacnerf.json is damaged")
    return d


def pacnerf_identified(stages: dict) -> dict:
    dyn = stages["dynamics"].value
    return {
        "E": dyn["E"],
        "log10_E": dyn["log10_E"],
        "nu": dyn["nu"],
        "v0": list(stages["velocity"].value["v0"]),
        "n_particles": dyn["n_particles"],
    }


# ---------------------------------------------------------------------- predict: the best (E, ν) rolled out
def pacnerf_predict_produce(ctx: RunContext, out: Path, ckpt) -> None:
    import drjit as dr

    cfg, seq, dyn = ctx.cfg.baseline.pacnerf, ctx.seq, ctx.values["dynamics"]
    particles = dyn["particles"].astype(np.float64)
    scene = _pacnerf_scene(ctx, particles, seq.n_frames)
    frames = range(seq.n_frames)
    bar = None
    if ctx.progress:
        from tqdm import tqdm

        bar = tqdm(total=seq.n_frames - 1, desc="PAC-NeRF rollout", leave=False)
    x = rollout(scene, cfg, [dyn["E"]], [dyn["nu"]], seq.n_frames, (lambda f: bar.update(1)) if bar else None)[0]
    if bar:
        bar.close()
    skin = ParticleSkin(ctx.gaussians, particles, cfg.bind_k)
    centres, images = [], []
    with dr.suspend_grad():
        for f in frames:
            g = skin.posed(x[f])
            centres.append(array3_to_points(g.means))
            images.append(
                (np.stack([render_rgba_numpy(g, cam, ctx.cfg.render) for cam in ctx.cameras]) * 255.0 + 0.5).astype(
                    np.uint8
                )
            )
    np.savez(out / "trajectory.npz", anchors=x.astype(np.float32), centres=np.stack(centres))
    np.save(out / "images.npy", np.stack(images))


def load_prediction(out: Path, n_frames: int, n_views: int, what: str = "every frame"):
    """The predict stage's trajectory.npz and images.npy as a `Prediction`, checked to cover
    `n_frames` frames and `n_views` views (`what` names them in the error)."""

    with np.load(out / "trajectory.npz", allow_pickle=False) as z:
        a, c = z["anchors"], z["centres"]
    imgs = np.load(out / "images.npy", allow_pickle=False)
    if a.shape[0] != n_frames or c.shape[0] != n_frames or imgs.shape[:2] != (n_frames, n_views) or imgs.shape[-1] != 4:
        raise ValueError(f"predict outputs do not cover {what} and view of the sequence")
    return Prediction(a, c, imgs)


def pacnerf_predict_load(ctx: RunContext, out: Path):
    return load_prediction(out, ctx.seq.n_frames, len(ctx.cameras))


# ---------------------------------------------------------------------- report
def _scores_section(out: Path, scores: dict, n_fit: int):
    body = scores_table(scores)
    try:
        png = report.plot_metric_curves(out / "metric_curves.png", scores.get("per_frame", {}), n_fit)
        body += image(png, "per-frame scores", "Per frame: the model (black) against the physics-free baselines.")
    except ValueError as exc:
        body += paragraph(f"No per-frame curves: {exc}.")
    return Section("Scores", body)


def plot_search(path: Path, evaluated: list, best: tuple, E_box, nu_box) -> Path:
    """The search's candidates in (log10 E, ν), coloured by their loss, the best marked."""

    plt = pyplot()
    fig, ax = plt.subplots(figsize=(5.5, 4.0))
    e = np.array([c["log10_E"] for c in evaluated])
    n = np.array([c["nu"] for c in evaluated])
    loss = np.array([c["loss"] for c in evaluated])
    sc = ax.scatter(e, n, c=np.log10(loss), cmap="viridis", s=28)
    ax.plot(*best, marker="*", color="red", markersize=14, linestyle="none", label="identified")
    ax.set_xlim(E_box[0] - 0.05, E_box[1] + 0.05)
    ax.set_ylim(nu_box[0] - 0.01, nu_box[1] + 0.01)
    ax.set_xlabel("log10 E (Pa)")
    ax.set_ylabel("ν")
    fig.colorbar(sc, ax=ax, label="log10 image loss")
    ax.legend(loc="best")
    return save_figure(fig, path)


def pacnerf_report_produce(ctx: RunContext, out: Path, ckpt) -> None:
    cfg, seq, dyn, scores = ctx.cfg, ctx.seq, ctx.values["dynamics"], ctx.values["evaluate"]
    pc = cfg.baseline.pacnerf
    sections = [_scores_section(out, scores, seq.n_fit)]
    videos = report_videos(ctx, out)
    if videos:
        from sgdr.report.html import video

        sections.append(Section("Videos", "".join(video(p, c) for p, c in videos)))
    png = plot_search(out / "search.png", dyn["evaluated"], (dyn["log10_E"], dyn["nu"]), pc.log10_E_range, pc.nu_range)
    sections.append(
        Section(
            "E, ν search",
            image(
                png,
                "search",
                f"Every candidate of the {pc.rounds} rounds ({pc.grid_E} x {pc.grid_nu} batched rollouts each); "
                "each round's grid is centred on the best so far.",
            )
            + paragraph("Best loss after each round: " + ", ".join(f"{v:.4g}" for v in dyn["pass_losses"]) + "."),
        )
    )
    rows = [
        ("E, Young's modulus (global)", f"{dyn['E']:.4g} Pa (log10 {dyn['log10_E']:.3f})", str(pc.log10_E_range)),
        ("ν, Poisson ratio (global)", f"{dyn['nu']:.3f}", str(pc.nu_range)),
        ("v0 (shared velocity stage)", ", ".join(f"{v:.3f}" for v in ctx.v0), ""),
        ("ground collider", pc.collider, "baseline.pacnerf.collider"),
        (
            "particles (filled into the static Gaussians)",
            f"{dyn['n_particles']}, spacing {dyn['particle_spacing']:.4g}",
            "",
        ),
        ("MPM grid", f"{dyn['mpm_grid']}³ nodes, Δx {dyn['mpm_dx']:.4g}, {dyn['substeps']} substeps per frame", ""),
    ]
    sections.append(Section("Identified parameters", table(("parameter", "identified", "search range"), rows)))
    fit, fit_text = fit_verdict(scores)
    future, future_head, future_text = future_verdict(scores)
    warnings = baseline_warnings(scores)
    if dyn["at_bound"]:
        warnings.append(
            "The identified value lies on the edge of the search box ("
            + ", ".join(dyn["at_bound"])
            + "): the best value may lie outside; widen baseline.pacnerf.log10_E_range / nu_range."
        )
    verdict = Verdict(fit, future, f"Fit {fit}, {future_head}.", [fit_text, *future_text], warnings)
    subtitle = (
        f"PAC-NeRF baseline (MLS-MPM, one global E and ν; docs/baselines.md) on {seq.root}: {len(seq.cameras)} "
        f"views, {seq.n_frames} frames at {seq.fps:g} fps, frames 0..{seq.n_fit - 1} fitted. Preset {cfg.preset}, "
        f"method {cfg.method}, seed {cfg.seed}."
    )
    write_report(out / "report.html", f"sgdr run {out.parent.name}", verdict, sections, subtitle)


def report_load(ctx: RunContext, out: Path) -> list[str]:
    return sorted(str(p.relative_to(out)) for p in out.rglob("*") if p.is_file())


# ---------------------------------------------------------------------- asset
def pacnerf_asset_produce(ctx: RunContext, out: Path, ckpt) -> None:
    dyn = ctx.values["dynamics"]
    pc = ctx.cfg.baseline.pacnerf
    save_ply(out / "gaussians.ply", ctx.gaussians)
    np.save(out / "particles.npy", dyn["particles"])
    (out / "pacnerf.json").write_text(
        json.dumps(
            {
                "model": "pacnerf",
                "E": dyn["E"],
                "nu": dyn["nu"],
                "v0": list(ctx.v0),
                "density": pc.density,
                "material": pc.material,
                "collider": pc.collider,
                "ground_friction": pc.ground_friction,
                "bind_k": pc.bind_k,
                "particle_spacing": dyn["particle_spacing"],
                "gravity": list(map(float, ctx.seq.gravity)),
                "ground_point": list(map(float, ctx.seq.ground_point)),
                "ground_normal": list(map(float, ctx.seq.ground_normal)),
                "fps": ctx.seq.fps,
                "note": "the PAC-NeRF baseline's MPM object; experiments/simulate.py loads spring-mass assets only",
            },
            indent=1,
        )
    )


def pacnerf_asset_load(ctx: RunContext, out: Path) -> dict:
    d = json.loads((out / "pacnerf.json").read_text())
    d["gaussians"] = load_ply(out / "gaussians.ply")
    return d


# ---------------------------------------------------------------------- Table 2's other rows: dyngaus, deform4d
FIT_ONLY = "the method reconstructs the fit frames only"


@dataclass(frozen=True)
class FitFrameModel:
    title: str  # what it is, in a few words (the report's subtitle, the asset)
    how: str  # what it does, in a sentence (the report)
    fit: str  # "module:function" reconstructing the fit frames (`ReconstructionResult`)


FIT_FRAME_MODELS = {
    "dyngaus": FitFrameModel(
        "simplified Dy-Gaus (per-frame tracking)",
        "the centres (and a rotation per Gaussian) tracked frame by frame, each frame from the last plus its "
        "velocity, under Dynamic 3D Gaussians' local-rigidity, rotation and isometry priors",
        "sgdr.baselines.dyngaus:track_gaussians",
    ),
    "deform4d": FitFrameModel(
        "simplified 4D-Gaus (deformation grids)",
        "the centres moved by one displacement grid per fit frame over the object's box (trilinear), all grids "
        "fitted jointly with smoothness penalties in space and time after a frame-by-frame start",
        "sgdr.baselines.deform4d:fit_deformation",
    ),
}


def _fit_targets(ctx: RunContext) -> list:
    return [frame_targets(ctx.seq, f) for f in range(ctx.seq.n_fit)]


def fit_frames_produce(model: str, ctx: RunContext, out: Path, ckpt) -> None:
    """dynamics of `model` (dyngaus | deform4d): its reconstruction of the fit frames."""

    module, name = FIT_FRAME_MODELS[model].fit.split(":")
    fit = getattr(importlib.import_module(module), name)
    cfg = getattr(ctx.cfg.baseline, model)
    targets = _fit_targets(ctx)
    res = fit(ctx.gaussians, targets, ctx.cameras, ctx.cfg.render, cfg, ctx.cfg.seed, ctx.progress)
    held = np.repeat(res.centres[:1], len(res.centres), axis=0)  # every fit frame at frame 0: nothing moved
    lam = float(cfg.lambda_dssim)
    np.savez(
        out / "centres.npz",
        centres=res.centres,
        losses=res.losses,
        image_losses=res.image_losses,
        step_frames=np.asarray(res.step_frames, np.int64),
    )
    record = {
        "model": model,
        "n_gaussians": int(res.centres.shape[1]),
        "n_fit": int(res.centres.shape[0]),
        "pass_losses": _pass_losses(res),
        "eval_loss_initial": all_view_loss(ctx.gaussians, held, targets, ctx.cameras, ctx.cfg.render, lam),
        "eval_loss_final": all_view_loss(ctx.gaussians, res.centres, targets, ctx.cameras, ctx.cfg.render, lam),
        "note": (
            "pass_losses: the joint steps' losses (deform4d) or each tracked frame's last loss (dyngaus), image + "
            "priors / regularisers (every step's: centres.npz); eval_loss_initial / final: the "
            "all-view image loss of fit frames 1..n_fit-1 with every Gaussian held at frame 0 / as reconstructed"
        ),
    }
    (out / "dynamics.json").write_text(json.dumps(record, indent=1, allow_nan=False))


def _pass_losses(res) -> list[float]:
    """A run's per-pass losses: every joint step's (step frame -1), or else each frame's last step's."""
    frames = np.asarray(res.step_frames)
    if (frames == -1).any():
        return [float(x) for x in res.losses[frames == -1]]
    return [float(res.losses[frames == f][-1]) for f in sorted(set(frames.tolist()))]


def fit_frames_load(ctx: RunContext, out: Path) -> dict:
    d = json.loads((out / "dynamics.json").read_text())
    with np.load(out / "centres.npz", allow_pickle=False) as z:
        d.update({k: z[k] for k in ("centres", "losses", "image_losses", "step_frames")})
    m = ctx.gaussians.count
    if d["centres"].shape != (ctx.seq.n_fit, m, 3) or not np.all(np.isfinite(d["centres"])):
        raise ValueError(f"dynamics/centres.npz: centres {d['centres'].shape} are not finite [n_fit, {m}, 3]")
    return d


def fit_frames_identified(stages: dict) -> dict:
    dyn = stages["dynamics"].value
    return {"n_gaussians": dyn["n_gaussians"], "fit_frames": dyn["n_fit"], "physical_parameters": None}


def fit_frames_predict_produce(ctx: RunContext, out: Path, ckpt) -> None:
    """Every view's render of the reconstructed fit frames (there is no future to predict)."""
    import drjit as dr

    centres = ctx.values["dynamics"]["centres"]
    images = []
    with dr.suspend_grad():
        for c in centres:
            g = posed(ctx.gaussians, points_to_array3(c))
            rgba = np.stack([render_rgba_numpy(g, cam, ctx.cfg.render) for cam in ctx.cameras])
            images.append((rgba * 255.0 + 0.5).astype(np.uint8))
    np.savez(out / "trajectory.npz", anchors=np.zeros((len(centres), 0, 3), np.float32), centres=centres)
    np.save(out / "images.npy", np.stack(images))


def fit_frames_predict_load(ctx: RunContext, out: Path):
    return load_prediction(out, ctx.seq.n_fit, len(ctx.cameras), "every fit frame")


def fit_frames_evaluate_produce(ctx: RunContext, out: Path, ckpt) -> None:
    """The fit frames' scores; the future's are null with the reason `FIT_ONLY`."""

    r = ctx.cfg.recon
    scores = evaluate_prediction(
        ctx.values["predict"],
        ctx.seq,
        with_emd=r.eval_emd,
        seed=ctx.cfg.seed,
        workers=r.eval_workers,
        fit_only=FIT_ONLY,
    )
    missing = scores.pop("missing")
    scores = strict_json(scores, missing)
    scores["missing"] = missing
    (out / "scores.json").write_text(json.dumps(scores, indent=1, allow_nan=False))


def fit_frames_report_produce(model: str, ctx: RunContext, out: Path, ckpt) -> None:
    cfg, seq, dyn, scores = ctx.cfg, ctx.seq, ctx.values["dynamics"], ctx.values["evaluate"]
    what = FIT_FRAME_MODELS[model]
    sections = [_scores_section(out, scores, seq.n_fit)]
    if cfg.recon.render_videos:
        clip = report_frames(seq, ctx.values["predict"], seq.n_fit)
        fps, repeat = report.playback(len(clip))
        report.write_video(out / "fit.mp4", [f for f in clip for _ in range(repeat)], fps)
        caption = f"the {seq.n_fit} fit frames, ground truth (left) | reconstruction (right) in every view"
        sections.append(Section("Video", video(out / "fit.mp4", caption)))
    frames = np.asarray(dyn["step_frames"])
    curves = {"loss (image + priors)": dyn["losses"], "image loss": dyn["image_losses"]}
    png = report.plot_losses(out / "losses.png", curves, {k: "Adam step" for k in curves})
    steps = (
        f"{int((frames == -1).sum())} joint steps over every fit frame, after {int((frames >= 0).sum())} steps of "
        "the frame-by-frame start"
        if (frames == -1).any()
        else f"{len(frames)} steps, frame by frame (frames 1..{seq.n_fit - 1})"
    )
    sections.append(Section("Losses", image(png, "losses", f"Every Adam step's loss: {steps}.")))
    section = plain_section(getattr(cfg.baseline, model))
    rows = [(k, str(v)) for k, v in section.items()]
    rows.append(
        (
            "all-view image loss, held at frame 0 / reconstructed",
            f"{dyn['eval_loss_initial']:.4g} / {dyn['eval_loss_final']:.4g}",
        )
    )
    sections.append(Section("Settings", table((f"baseline.{model}", "value"), rows)))
    psnr = scores.get("fit_psnr")
    if psnr is None:
        quality = "unknown"
        text = f"The fit cannot be judged: no image PSNR of the fit frames ({scores['missing'].get('fit_psnr')})."
    else:
        quality = "good" if psnr >= FIT_PSNR_GOOD else "fair" if psnr >= FIT_PSNR_FAIR else "poor"
        text = (
            f"The reconstruction of the fit frames is {quality}: its renders match the input images at {psnr:.1f} "
            f"dB PSNR (good from {FIT_PSNR_GOOD:g} dB, fair from {FIT_PSNR_FAIR:g} dB)"
        )
        if scores.get("fit_cd") is not None:
            text += (
                f"; its centres are at Chamfer distance {scores['fit_cd']:.3g} (x1e3) from the ground-truth particles"
            )
        text += "."
    future = f"The future is not scored: {FIT_ONLY} (no physics, nothing to simulate)."
    verdict = Verdict(quality, "not scored", f"Fit {quality}; the future is not predicted.", [text, future], [])
    sections.append(
        Section(
            "What this is",
            paragraph(
                f"The {what.title} baseline (docs/baselines.md, Table 2's other rows): the refined frame-0 Gaussians "
                f"of the shared stages, appearance frozen; {what.how}. No physical parameter, no future."
            ),
        )
    )
    subtitle = (
        f"The {what.title} baseline on {seq.root}: {len(seq.cameras)} views, frames 0..{seq.n_fit - 1} reconstructed. Preset "
        f"{cfg.preset}, method {cfg.method}, seed {cfg.seed}."
    )
    write_report(out / "report.html", f"sgdr run {out.parent.name}", verdict, sections, subtitle)


def plain_section(section) -> dict:
    """A config section (dataclass or DictConfig) as a plain dict."""

    if dataclasses.is_dataclass(section):
        return dataclasses.asdict(section)
    return OmegaConf.to_container(section, resolve=True)


def fit_frames_asset_produce(model: str, ctx: RunContext, out: Path, ckpt) -> None:
    dyn = ctx.values["dynamics"]
    save_ply(out / "gaussians.ply", ctx.gaussians)
    np.save(out / "centres.npy", dyn["centres"].astype(np.float32))
    record = {
        "model": model,
        "what": FIT_FRAME_MODELS[model].title,
        "settings": plain_section(getattr(ctx.cfg.baseline, model)),
        "n_fit": int(ctx.seq.n_fit),
        "fps": ctx.seq.fps,
        "note": f"{FIT_ONLY}: gaussians.ply is frame 0, centres.npy [n_fit, M, 3] every fit frame; not simulatable",
    }
    (out / f"{model}.json").write_text(json.dumps(record, indent=1))


def fit_frames_asset_load(model: str, ctx: RunContext, out: Path) -> dict:
    d = json.loads((out / f"{model}.json").read_text())
    d["gaussians"] = load_ply(out / "gaussians.ply")
    d["centres"] = np.load(out / "centres.npy", allow_pickle=False)
    return d
