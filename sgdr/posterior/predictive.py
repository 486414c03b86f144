"""The posterior predictive and the posterior's plots and report section.

`predictive` rolls out `posterior.n_predictive` posterior draws and the posterior median over
every frame (fit and future) and reduces each to two curves over time: the height of the centre
of mass of the bound Gaussian centres above the ground plane, and the height of the lowest
centre. The report shows their 5-95% bands with the median prediction, the truth overlaid when
the observed sequence has ground-truth particles (gt/), and the per-frame Chamfer distance of
the posterior-median prediction against them. The future frames were not in the likelihood, so
a truth outside the bands there is a failure of prediction, not of the fit.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from sgdr.evaluate.geometry import chamfer_distance
from sgdr.posterior import forecast
from sgdr.report.html import Section, esc, image, paragraph, table, video
from sgdr.report.media import playback, tile, write_video


def heights(centres: np.ndarray, ground_point, ground_normal) -> tuple[np.ndarray, np.ndarray]:
    """(centre of mass height [..., T], lowest point height [..., T]) of centres [..., T, P, 3]."""
    n = np.asarray(ground_normal, float) / np.linalg.norm(ground_normal)
    h = (np.asarray(centres, float) - np.asarray(ground_point, float)) @ n
    return h.mean(axis=-1), h.min(axis=-1)


def predictive(
    rollout_all,
    centre_map,
    problem,
    samples: np.ndarray,
    median: np.ndarray,
    n_draws: int,
    seq,
    seed=0,
    map_theta=None,
    growth: float = 0.0,
    size: float = 1.0,
    level: float = 0.9,
    offsets: np.ndarray | None = None,
):
    """Bands and truth over every frame. rollout_all(samples) -> (positions [S, T, N_A, 3], stable);
    samples [N, D] the kept posterior samples; median [D]; map_theta [D] the identified values (the
    point estimate), rolled out beside the median when given. Returns (a JSON-ready dict, centres
    [S, T, P, 3] of the median (index 0) and the draws, stable [S]).

    With ground truth (`gt/` particles) the dict also holds the per-frame Chamfer distance (x1e3,
    as the run's scores) of the posterior median, of the point estimate and of the physics-free
    "still" prediction (the last fit frame's centres of the point estimate held where they are, as
    the run's baseline `sgdr.evaluate.baselines`), their means over the future frames, and the share of
    frames whose true centre-of-mass height lies in the 5-95% band, both as heights and as
    displacements from frame 0 (`*_disp_*`: the truth's particles are not the Gaussian centres,
    so their heights differ by a representation offset at rest, where every draw agrees).

    `com_ball`: the centre of mass's `level` predictive ball over every frame with the model
    discrepancy (`sgdr.posterior.forecast`: σ_fit from the images, growing by `growth` x `size`
    per second after the fit window), the draws' displacements beside it, and with ground truth the
    share of fit and future frames whose true displacement lies inside it. offsets [n_fit, 3]
    (`forecast.silhouette_offsets` of the point prediction, posterior.discrepancy_offset) give the
    discrepancy a mean: the ball moves by them over the fit frames and by the last one after."""

    rng = np.random.default_rng(seed)
    pick = rng.choice(samples.shape[0], size=min(int(n_draws), samples.shape[0]), replace=False)
    extra = [] if map_theta is None else [np.asarray(map_theta, float)]
    thetas = np.concatenate([median[None], *(e[None] for e in extra), samples[pick]])
    positions, stable = rollout_all(problem.samples(thetas))
    centres = centre_map(positions)  # [S, T, P, 3]
    map_centres, map_ok = (centres[1], bool(stable[1])) if extra else (None, False)
    if extra:  # the point estimate is not a draw
        keep = np.r_[0, 2 : centres.shape[0]]
        centres, stable = centres[keep], np.asarray(stable)[keep]
    com, low = heights(centres, seq.ground_point, seq.ground_normal)
    ok = np.asarray(stable, bool)
    draws = ok.copy()
    draws[0] = False  # the median is drawn as its own line
    out = {
        "frames": int(centres.shape[1]),
        "n_fit": int(seq.n_fit),
        "n_draws": int(draws.sum()),
        "n_unstable": int((~ok[1:]).sum()),
        "median_stable": bool(ok[0]),
    }
    for name, curve in (("com_height", com), ("lowest_height", low)):
        if draws.any():
            q05, q50, q95 = np.percentile(curve[draws], [5, 50, 95], axis=0)
            out[name] = {"q05": q05.tolist(), "q50": q50.tolist(), "q95": q95.tolist()}
        out[name + "_median_prediction"] = curve[0].tolist() if ok[0] else None
    truth_com, truth_low, cd, map_cd, still_cd, truth_com3 = [], [], [], [], [], []
    if seq.gt_dir is not None and ok[0]:
        for f in range(centres.shape[1]):
            gt = seq.gt_particles(f) if f < seq.n_frames else None
            if gt is None:
                break
            c, lo = heights(gt[None], seq.ground_point, seq.ground_normal)
            truth_com.append(float(c[0]))
            truth_com3.append(np.asarray(gt, float).mean(axis=0))
            truth_low.append(float(lo[0]))
            cd.append(chamfer_distance(centres[0, f], gt))
            if f >= seq.n_fit:  # the run's physics-free "still": the last fit frame's centres held
                still_cd.append(chamfer_distance((map_centres if map_ok else centres[0])[seq.n_fit - 1], gt))
            if map_ok:
                map_cd.append(chamfer_distance(map_centres[f], gt))
    point = map_centres if map_ok else centres[0]
    out["com_ball"] = _com_ball(centres, draws, point, seq, growth, size, level, seed, offsets)
    if truth_com3:
        truth_disp = np.asarray(truth_com3) - truth_com3[0]
        ball = out["com_ball"]
        t = truth_disp.shape[0]
        hit = forecast.inside(truth_disp, np.asarray(ball["centre"])[:t], np.asarray(ball["radius"])[:t])
        ball["truth"] = truth_disp.tolist()
        ball["truth_inside_fit"] = float(hit[1 : seq.n_fit].mean()) if seq.n_fit > 1 else None
        ball["truth_inside_future"] = float(hit[seq.n_fit :].mean()) if t > seq.n_fit else None
    out["truth_com_height"] = truth_com or None
    out["truth_lowest_height"] = truth_low or None
    out["median_cd_per_frame"] = cd or None  # x1e3 scene units², as the run's scores
    out["map_cd_per_frame"] = map_cd or None
    out["still_cd_per_future_frame"] = still_cd or None  # frames n_fit, n_fit + 1, ...
    future = slice(int(seq.n_fit), None)
    for name, curve in (("median", cd), ("map", map_cd)):
        out[f"{name}_future_cd"] = float(np.mean(curve[future])) if len(curve) > seq.n_fit else None
    out["still_future_cd"] = float(np.mean(still_cd)) if still_cd else None
    curve_at_rest = {"com_height": float(com[0, 0]), "lowest_height": float(low[0, 0])}  # frame 0: every draw's
    for name in ("com_height", "lowest_height"):
        truth = out[f"truth_{name}"]
        if truth is not None and name in out:
            t = np.asarray(truth)
            inside = (t >= np.asarray(out[name]["q05"][: t.size]) - 1e-9) & (
                t <= np.asarray(out[name]["q95"][: t.size]) + 1e-9
            )
            out[f"{name}_truth_inside_fit"] = float(inside[: seq.n_fit].mean())
            out[f"{name}_truth_inside_future"] = float(inside[seq.n_fit :].mean()) if t.size > seq.n_fit else None
            # displacements from frame 0: the band and the truth each relative to their own rest state
            d = t - t[0]
            base = curve_at_rest[name]
            lo_d = np.asarray(out[name]["q05"][: t.size]) - base
            hi_d = np.asarray(out[name]["q95"][: t.size]) - base
            inside_d = (d >= lo_d - 1e-9) & (d <= hi_d + 1e-9)
            out[f"{name}_disp_truth_inside_fit"] = float(inside_d[1 : seq.n_fit].mean()) if seq.n_fit > 1 else None
            out[f"{name}_disp_truth_inside_future"] = (
                float(inside_d[seq.n_fit :].mean()) if t.size > seq.n_fit else None
            )
    return out, centres, ok


def _com_ball(centres, draws, point, seq, growth, size, level, seed, offsets=None) -> dict:
    """The centre of mass's predictive ball (`sgdr.posterior.forecast`) from centres [S, T, P, 3]
    (draws marked by `draws`). Without offsets σ_fit is measured on the point prediction's centres
    `point` [T, P, 3]; with offsets [n_fit, 3] the discrepancy has their mean (the last one held
    over the future) and their scatter about it as σ."""
    n_fit = min(int(seq.n_fit), centres.shape[1])
    com = centres.mean(axis=2)  # [S, T, 3]
    disp = com - com[:, :1]
    use = disp[draws] if draws.any() else disp[:1]
    extra = {}
    if offsets is None:
        sigma_fit = forecast.fit_misfit(seq, point, n_fit)
    else:
        offsets = np.asarray(offsets, float)[:n_fit]
        use, sigma_fit, end = forecast.with_offsets(use, offsets)
        extra = {"offsets": offsets.tolist(), "offset": end.tolist()}
    centre = np.median(use, axis=0)  # [T, 3]
    sigma = forecast.sigma_over_time(sigma_fit, centres.shape[1], seq.fps, size, growth)
    radius = forecast.ball_radius(use, centre, sigma, level, seed=seed)
    return {
        "level": float(level),
        "growth": float(growth),
        "size": float(size),
        "fps": float(seq.fps),
        "sigma_fit": sigma_fit.tolist(),
        "sigma": sigma.tolist(),
        "radius": radius.tolist(),
        "centre": centre.tolist(),
        "draws": use.tolist(),
        **extra,
    }


def ensemble_video(seq, centres: np.ndarray, stable: np.ndarray, path, max_views: int = 4, size: int = 192):
    """A video of the ensemble: for up to `max_views` views, the observed image (over dark grey)
    with the projected bound centres of every posterior draw (blue, one dot each) and of the
    posterior median (orange) on top, frame by frame over fit and future; a green bar over fit
    frames, an orange one over future frames. centres [S, T, P, 3] with the median at index 0."""

    n_v = min(max_views, len(seq.cameras))
    views = sorted({int(round(i * len(seq.cameras) / n_v)) % len(seq.cameras) for i in range(n_v)})
    n_t = min(centres.shape[1], seq.n_frames)
    frames = []
    for f in range(n_t):
        cells = []
        for v in views:
            cam = seq.cameras[v]
            scale = max(1, size // max(cam.width, cam.height))
            rgba = seq.image(v, f)
            img = rgba[..., :3] * rgba[..., 3:] + 0.15 * (1 - rgba[..., 3:])
            img = np.repeat(np.repeat(img, scale, axis=0), scale, axis=1)
            for s in range(centres.shape[0]):
                if not stable[s]:
                    continue
                uv, z = cam.project(centres[s, f])
                px = np.floor(uv[z > 0] * scale).astype(int)
                inside = (px[:, 0] >= 0) & (px[:, 0] < img.shape[1]) & (px[:, 1] >= 0) & (px[:, 1] < img.shape[0])
                px = px[inside]
                colour, alpha = (np.array([0.95, 0.55, 0.1]), 0.9) if s == 0 else (np.array([0.25, 0.5, 0.95]), 0.35)
                img[px[:, 1], px[:, 0]] = (1 - alpha) * img[px[:, 1], px[:, 0]] + alpha * colour
            bar = np.zeros((max(3, scale), img.shape[1], 3))
            bar[:] = (0.24, 0.71, 0.29) if f < seq.n_fit else (0.96, 0.65, 0.14)
            cells.append(np.concatenate([bar, img], axis=0))
        frames.append(tile(cells, cols=len(cells)))
    fps, repeat = playback(n_t)
    return write_video(path, [fr for fr in frames for _ in range(repeat)], fps)


def plot_corner(samples: np.ndarray, names: list, path, truth: dict | None = None, map_theta=None):
    import corner
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    truths = None
    if truth is not None:
        truths = [truth.get(n) for n in names]
    fig = corner.corner(
        samples, labels=names, quantiles=[0.05, 0.5, 0.95], show_titles=True, truths=truths, truth_color="#d0312d"
    )
    if map_theta is not None:
        corner.overplot_lines(fig, list(map_theta), color="#3c78d8", linestyle="--")
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return path


def plot_traces(chains: np.ndarray, names: list, burn_in: int, path):
    """One panel per parameter: every walker of every ensemble (one colour per ensemble)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n_ens, _, _, dim = chains.shape
    fig, axes = plt.subplots(dim, 1, figsize=(8, 1.8 * dim), sharex=True, squeeze=False)
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for j, name in enumerate(names):
        ax = axes[j, 0]
        for e in range(n_ens):
            ax.plot(chains[e, :, :, j], color=colours[e % len(colours)], alpha=0.35, lw=0.7)
        ax.axvline(burn_in, color="k", ls=":", lw=1)
        ax.set_ylabel(name)
    axes[-1, 0].set_xlabel("step (dotted: end of burn-in)")
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return path


def plot_bands(pred: dict, fps: float, path):
    """Centre-of-mass and lowest-point heights: 5-95% band, median prediction, truth, fit | future."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = np.arange(pred["frames"])
    panels = ["com_height", "lowest_height"] + (["cd"] if pred.get("median_cd_per_frame") else [])
    panels += ["ball"] if pred.get("com_ball") else []
    fig, axes = plt.subplots(1, len(panels), figsize=(5 * len(panels), 3.4), squeeze=False)
    titles = {
        "com_height": "centre of mass height",
        "lowest_height": "lowest point height",
        "cd": "CD x1e3 against the true particles",
        "ball": "centre of mass: 90% ball with the model discrepancy",
    }
    for ax, name in zip(axes[0], panels):
        if name == "ball":
            ball = pred["com_ball"]
            ax.fill_between(t, 0, ball["radius"], color="#3c78d8", alpha=0.3, label=f"{ball['level']:.0%} radius")
            ax.plot(t, ball["sigma"], color="#3c78d8", ls=":", label="discrepancy σ per axis")
            if ball.get("truth"):
                err = np.linalg.norm(
                    np.asarray(ball["truth"]) - np.asarray(ball["centre"])[: len(ball["truth"])], axis=-1
                )
                ax.plot(t[: err.size], err, "k--", label="truth's distance from the centre")
            ax.set_ylabel("scene units")
            ax.legend(fontsize=7)
        elif name == "cd":
            for key, label, style in (
                ("median_cd_per_frame", "posterior median", dict(color="#3c78d8", marker="o")),
                ("map_cd_per_frame", "point estimate", dict(color="#e69138", marker=".")),
                ("still_cd_per_future_frame", "held still", dict(color="0.5", ls="--")),
            ):
                if pred.get(key):
                    start = pred["n_fit"] if key.startswith("still") else 0
                    ax.plot(t[start : start + len(pred[key])], pred[key], label=label, **style)
            ax.set_yscale("log")
            ax.legend(fontsize=7)
        else:
            if name in pred:
                ax.fill_between(t, pred[name]["q05"], pred[name]["q95"], color="#3c78d8", alpha=0.3, label="5-95%")
            if pred.get(name + "_median_prediction") is not None:
                ax.plot(t, pred[name + "_median_prediction"], color="#3c78d8", label="posterior median")
            if pred.get("truth_" + name) is not None:
                ax.plot(t[: len(pred["truth_" + name])], pred["truth_" + name], "k--", label="truth")
            ax.legend(fontsize=7)
        ax.axvline(pred["n_fit"] - 0.5, color="#f5a623", ls=":", lw=1.5)
        ax.set_title(titles[name], fontsize=9)
        ax.set_xlabel(f"frame ({fps:g} fps; dotted: fit | future)")
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return path


def _g(x, digits=4):
    return "n/a" if x is None else f"{x:.{digits}g}"


def section(record: dict, out_dir):
    """The report's 'Posterior' section (`sgdr.report.html.Section`); its first line is
    the convergence headline ('Not converged: ...' when a criterion failed)."""

    out_dir = Path(out_dir)
    d = record["diagnostics"]
    names = d["names"]
    truth = record.get("truth") or {}
    status = "good" if d["converged"] else "poor"
    body = [f'<p id="posterior-verdict" class="{status}"><b>{esc(record["headline"])}</b></p>']
    body.append(paragraph(f"Observed: {record['sequence']}{' (a twin with a known truth)' if truth else ''}. "
                          + _likelihood_words(record["likelihood"]) + " " + _sampling_words(record)))  # fmt: skip
    rows = []
    for n in names:
        lo, hi = d["q05"][n], d["q95"][n]
        t = truth.get(n)
        rows.append(
            [
                n,
                _g(record["map"][n]),
                _g(d["median"][n]),
                _g(lo),
                _g(hi),
                "" if t is None else f"{t:.4g} ({'inside' if lo <= t <= hi else 'OUTSIDE'})",
                "prior [" + ", ".join(f"{v:g}" for v in record["priors"][n]) + "] uniform",
            ]
        )
    body.append(table(["parameter", "identified (MAP)", "median", "5%", "95%", "truth", "prior"], rows))
    for note in record.get("notes") or []:
        body.append(paragraph("Note: " + note))
    diag_rows = [
        [
            n,
            ", ".join(_g(row[j], 3) for row in d["tau"]),
            _g(d["rhat"][n]),
            _g(d["ess_bulk"][n], 3),
            _g(d["ess_tail"][n], 3),
        ]
        for j, n in enumerate(names)
    ]
    body.append(table(["parameter", "τ per ensemble (steps)", "R-hat", "ESS bulk", "ESS tail"], diag_rows))
    body.append(
        paragraph(
            "Acceptance fraction per ensemble: "
            + ", ".join(f"{a:.2f}" for a in d["acceptance"])
            + f". Criteria: chains >= {record['criteria']['tau_factor']:g} τ, R-hat <= {record['criteria']['rhat_max']:g}"
            f" and ESS >= {record['criteria']['ess_min']:g} across the ensembles, acceptance in "
            f"[{record['criteria']['acceptance_min']:g}, {record['criteria']['acceptance_max']:g}]."
        )
    )
    body.append(
        image(
            out_dir / "corner.png",
            "corner plot of the posterior samples",
            "5/50/95% marked; red: truth, blue dashed: identified",
        )
    )
    body.append(
        image(
            out_dir / "traces.png", "trace of every walker", "every walker of every ensemble, one colour per ensemble"
        )
    )
    pred = record["predictive"]
    cap = (
        f"{pred['n_draws']} posterior draws over all {pred['frames']} frames ({pred['n_unstable']} unstable left out). "
        "The future frames were not in the likelihood."
    )
    if pred.get("com_height_truth_inside_future") is not None:
        cap += (
            f" Truth inside the 5-95% band: centre of mass {100 * pred['com_height_truth_inside_fit']:.0f}% of fit "
            f"frames, {100 * pred['com_height_truth_inside_future']:.0f}% of future frames; lowest point "
            f"{100 * pred['lowest_height_truth_inside_fit']:.0f}% / {100 * pred['lowest_height_truth_inside_future']:.0f}%."
        )
    if pred.get("com_height_disp_truth_inside_future") is not None:
        cap += (
            " As displacements from frame 0 (the particles' rest offset from the Gaussian centres removed): centre of "
            f"mass {100 * pred['com_height_disp_truth_inside_fit']:.0f}% of fit frames after frame 0, "
            f"{100 * pred['com_height_disp_truth_inside_future']:.0f}% of future frames."
        )
    ball = pred.get("com_ball") or {}
    if ball:
        if ball.get("offset") is not None:
            cap += (
                f" The {ball['level']:.0%} ball of the centre of mass adds the model discrepancy measured on the fit "
                f"frames' silhouettes, observed against the rendered point prediction: its mean, the offset "
                f"{np.linalg.norm(ball['offset']):.3g} scene units at the last fit frame, held over the future (the ball "
                f"moves by it), and its scatter (σ {ball['sigma_fit'][-1]:.3g} per axis), growing by {ball['growth']:g} "
                "object sizes per second after them."
            )
        else:
            cap += (
                f" The {ball['level']:.0%} ball of the centre of mass adds the model discrepancy: the misfit measured on "
                f"the fit frames' silhouettes (σ {ball['sigma_fit'][-1]:.3g} scene units per axis at the last fit "
                f"frame), growing by {ball['growth']:g} object sizes per second after them."
            )
        if ball.get("truth_inside_future") is not None:
            cap += (
                f" Truth inside the ball: {100 * ball['truth_inside_fit']:.0f}% of fit frames after frame 0, "
                f"{100 * ball['truth_inside_future']:.0f}% of future frames."
            )
    if pred.get("median_future_cd") is not None:
        cap += f" Future CD (x1e3, Gaussian centres against the true particles): posterior median {pred['median_future_cd']:.3g}"
        if pred.get("map_future_cd") is not None:
            cap += f", point estimate {pred['map_future_cd']:.3g}"
        cap += f", the last fit frame held still {pred['still_future_cd']:.3g}."
    body.append(image(out_dir / "predictive.png", "posterior predictive bands", cap))
    if (out_dir / "ensemble.mp4").exists():
        body.append(
            video(
                out_dir / "ensemble.mp4",
                "the ensemble over the observed images: projected centres of every posterior draw (blue) and of the "
                "posterior median (orange); green bar: fit frames, orange bar: future frames",
            )
        )
    body.append(
        paragraph(
            f"Files: {out_dir}/posterior.json (every number here), samples.npz (the chains and the kept samples), "
            "corner.png, traces.png, predictive.png, ensemble.mp4."
        )
    )
    return Section("Posterior", "".join(body))


def _likelihood_words(lk: dict) -> str:
    """The report's sentence on what the likelihood compares."""
    if lk.get("kind") == "rendered":
        disc = lk["discrepancy_per_frame"]
        prof = lk.get("profile_log10_k_shift") or {}
        words = (
            f"Likelihood: the rendered images of the open-loop rollout on {lk['n_views']} views x {lk['n_frames']} fit "
            f"frames (frame 0 and the future left out) at 1/{lk['image_scale']} scale, the identification's own image "
            f"loss, one observation per view and frame (the tempering), each frame's scale the identified asset's "
            f"misfit: noise {lk['noise']:.3g} plus a discrepancy growing over the fit frames from {disc[0]:.3g} to "
            f"{disc[-1]:.3g}; extra temperature {lk['temperature']:g}."
        )
        if prof:
            words += (
                " log L along a global stiffness shift (decades: nats, others at the MAP): "
                + ", ".join(f"{k}: {v:.1f}" for k, v in prof.items())
                + "."
            )
        return words
    return (
        f"Likelihood: the silhouettes of {lk['n_views']} views x {lk['n_frames']} fit frames (frame 0 and the future "
        f"left out), noise scale σ = {lk['sigma_px']:.3g} px from the identified parameters' residual, one "
        f"observation per view and frame (the tempering), extra temperature {lk['temperature']:g}."
    )


def _sampling_words(record: dict) -> str:
    """The report's sentence on how the posterior was sampled and what it cost."""
    d = record["diagnostics"]
    sampler = record.get("sampler") or {}
    words = (
        f"{d['n_ensembles']} independent ensembles of {d['n_walkers']} walkers x {d['n_steps']} steps started around "
        f"the run's identified parameters{_sampler_words(sampler)}"
    )
    sur = sampler.get("surrogate")
    if sur:
        last = sur["rounds"][-1]
        words += (
            f", on a Gaussian-process surrogate of log L fitted to {sur['n_true_evaluations']} rendered evaluations "
            f"(the global stage's candidates, Sobol points and each round's draws), {len(sur['rounds'])} round(s); "
            f"at the last round's draws {last['inside_95']:.0%} of the true values lay in its 95% interval "
            f"({'it stands for' if sur['validated'] else 'it does NOT stand for'} the smoothed likelihood; error "
            f"{last['rmse_nats']:.2f} nats RMS, mean {last['mean_error_nats']:+.2f}, fitted roughness "
            f"{last['roughness_nats']:.2f} nats, PSIS k-hat of the rough one {last['khat']:.2f})"
        )
        if "edges" in last:
            gap = min(last["edge_log_like_below_best"], default=float("inf"))
            words += (
                f"; just beyond the 90% intervals ({last['edges']} edges) the likelihood's profile stayed at least "
                f"{gap:.1f} nats below the best evaluation"
            )
    return (
        words + f"; burn-in {d['burn_in']} steps, thinning {d['thin']}, {d['n_kept']} samples kept; "
        f"{record['cost']['rollouts']} rendered or simulated rollouts in {record['cost']['seconds']:.0f} s."
    )


def _sampler_words(sampler: dict | None) -> str:
    """' (differential-evolution moves in ...)' for the report's sampling sentence; '' for a record
    without the sampler."""
    if not sampler:
        return ""
    moves = {"de": "differential-evolution", "stretch": "stretch"}.get(sampler["moves"], sampler["moves"])
    space = {"logit": "each parameter's logit over its prior box", "box": "the prior box"}.get(
        sampler["space"], sampler["space"]
    )
    return f" ({moves} moves in {space})"
