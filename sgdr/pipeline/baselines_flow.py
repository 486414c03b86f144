"""The baselines' own pipeline rows (`sgdr.pipeline.run.MODELS`): what replaces the spring-mass
model's dynamics, predict, report and asset stages. The shared stages (static fit, anchors,
appearance refinement, v0) and the evaluate stage are the spring-mass pipeline's, so every
method is scored by the same code on the same Gaussians. The maths is in `sgdr.baselines`.

PAC-NeRF (`recon.model=pacnerf`, `method=pacnerf`):
  dynamics/  pacnerf.json (E, ν, the search: every candidate's loss), particles.npy (the fill)
  predict/   trajectory.npz (particles [T, P, 3] as `anchors`, Gaussian centres), images.npy
  report/    report.html: verdict, scores, videos, the search's loss landscape, the parameters
  asset/     pacnerf.json, particles.npy, gaussians.ply: the identified MPM object
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from sgdr.gaussians.ply import load_ply, save_ply
from sgdr.pipeline.flow import RunContext, report_frames


def _pacnerf_scene(ctx: RunContext, particles: np.ndarray, n_frames: int):
    from sgdr.baselines.pacnerf import plan_scene

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
    from sgdr.baselines.pacnerf import ParticleSkin, fill_particles, observe, search

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

    from sgdr.arrays import array3_to_points
    from sgdr.baselines.pacnerf import ParticleSkin, rollout
    from sgdr.identify.common import render_rgba_numpy

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


def pacnerf_predict_load(ctx: RunContext, out: Path):
    from sgdr.pipeline.predict import Prediction

    with np.load(out / "trajectory.npz", allow_pickle=False) as z:
        a, c = z["anchors"], z["centres"]
    imgs = np.load(out / "images.npy", allow_pickle=False)
    n = ctx.seq.n_frames
    if a.shape[0] != n or c.shape[0] != n or imgs.shape[:2] != (n, len(ctx.cameras)) or imgs.shape[-1] != 4:
        raise ValueError("predict outputs do not cover every frame and view of the sequence")
    return Prediction(a, c, imgs)


# ---------------------------------------------------------------------- report
def _videos(ctx: RunContext, out: Path) -> list:
    from sgdr.pipeline import report

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
            videos.append((out / name, f"{what}, ground truth (left) | prediction (right) in every view"))
    return videos


def _scores_section(out: Path, scores: dict, n_fit: int):
    from sgdr.pipeline import report
    from sgdr.pipeline.report_html import Section, image, paragraph, scores_table

    body = scores_table(scores)
    try:
        png = report.plot_metric_curves(out / "metric_curves.png", scores.get("per_frame", {}), n_fit)
        body += image(png, "per-frame scores", "Per frame: the model (black) against the physics-free baselines.")
    except ValueError as exc:
        body += paragraph(f"No per-frame curves: {exc}.")
    return Section("Scores", body)


def plot_search(path: Path, evaluated: list, best: tuple, E_box, nu_box) -> Path:
    """The search's candidates in (log10 E, ν), coloured by their loss, the best marked."""
    from sgdr.pipeline.report import _pyplot, _save_figure

    plt = _pyplot()
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
    return _save_figure(fig, path)


def pacnerf_report_produce(ctx: RunContext, out: Path, ckpt) -> None:
    from sgdr.pipeline.report_html import Section, image, paragraph, table, write_report
    from sgdr.pipeline.verdict import Verdict, _baseline_warnings, fit_verdict, future_verdict

    cfg, seq, dyn, scores = ctx.cfg, ctx.seq, ctx.values["dynamics"], ctx.values["evaluate"]
    pc = cfg.baseline.pacnerf
    sections = [_scores_section(out, scores, seq.n_fit)]
    videos = _videos(ctx, out)
    if videos:
        from sgdr.pipeline.report_html import video

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
    warnings = _baseline_warnings(scores)
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
