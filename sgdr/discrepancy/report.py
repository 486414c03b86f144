"""The plots of the residual diagnostics (`sgdr.discrepancy.residuals`) and the report's
'Model discrepancy' section (the diagnosis's decision, its candidates and the residuals).

Plots, written into the diagnosis folder:
  residual_d.png        D per view and frame (heat map; the fit / future boundary drawn) and its
                        mean per frame
  residual_com.png      centre-of-mass height above the recorded ground and horizontal
                        displacement over the frames, observed against simulated
  residual_spatial.png  for the views that disagree most, where: red = observed, not simulated;
                        blue = simulated, not observed (fraction of frames)
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from sgdr.report.html import Section, esc, image, paragraph, table


def pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _marks(ax, record: dict):
    """The hit frames (dotted; observed black, simulated blue) and the first future frame (dashed)."""
    ax.axvline(record["hit_frame"], color="k", ls=":", lw=1, label="hit frame")
    if record["hit_frame_simulated"] != record["hit_frame"]:
        ax.axvline(record["hit_frame_simulated"], color="tab:blue", ls=":", lw=1, label="hit frame, simulated")
    if record["n_fit"] < record["frames"]:
        ax.axvline(record["n_fit"] - 0.5, color="tab:orange", ls="--", lw=1, label="fit | future")


def plot_d(record: dict, path) -> Path:
    plt = pyplot()
    d = np.asarray(record["d"]["matrix"], float)  # [V, T]
    unit = record["d"].get("unit") or "the diagnosis's measure"
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(8, 2.2 + 0.25 * d.shape[0]), sharex=True,
                                      gridspec_kw={"height_ratios": [max(d.shape[0], 2), 3]})  # fmt: skip
    im = top.imshow(np.ma.masked_invalid(d), aspect="auto", cmap="magma", interpolation="nearest",
                    extent=(-0.5, d.shape[1] - 0.5, d.shape[0] - 0.5, -0.5))  # fmt: skip
    top.set_yticks(range(d.shape[0]))
    per_view = np.asarray(record["d"]["per_view_fit"], float)  # the fit frames' mean per view, in the label
    top.set_yticklabels([f"{n} ({m:.3g})" for n, m in zip(record["views"], per_view)], fontsize=7)
    top.set_ylabel("view")
    fig.colorbar(im, ax=top, location="top", label=f"D ({unit})", aspect=40)  # on top: the frame axes stay aligned
    if record["n_fit"] < record["frames"]:
        top.axvline(record["n_fit"] - 0.5, color="w", ls="--", lw=1)
    bottom.plot(np.arange(d.shape[1]), np.asarray(record["d"]["per_frame"], float), "k.-")
    _marks(bottom, record)
    bottom.set_xlabel("frame")
    bottom.set_ylabel("mean D")
    bottom.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return Path(path)


def plot_com(record: dict, path) -> Path:
    plt = pyplot()
    com = record["com"]
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.2))
    styles = {"observed": ("k", "o-", "observed (triangulated)"),
              "simulated": ("tab:blue", "s--", "simulated (triangulated)"),
              "anchors": ("tab:green", "-", "simulated anchors' mean")}  # fmt: skip
    frames = np.arange(record["frames"])
    for ax, key, label in (
        (axes[0], "height", "height above the ground"),
        (axes[1], "slide", "horizontal displacement"),
    ):
        for name, (colour, style, legend) in styles.items():
            ax.plot(frames, np.asarray(com[f"{key}_{name}"], float), style, color=colour, ms=3, label=legend)
        _marks(ax, record)
        ax.set_xlabel("frame")
        ax.set_ylabel(f"{label} (scene units)")
    axes[0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return Path(path)


def plot_spatial(record: dict, maps: list, path, n_views: int) -> Path:
    plt = pyplot()
    shown = record["spatial"]["order"][: max(1, int(n_views))]
    fig, axes = plt.subplots(1, len(shown), figsize=(2.6 * len(shown), 2.8), squeeze=False)
    for ax, v in zip(axes[0], shown):
        m = np.asarray(maps[v], float)  # [h, w, 2]
        rgb = np.ones(m.shape[:2] + (3,))
        rgb[..., 1] -= np.clip(m[..., 0] + m[..., 1], 0, 1)  # white where they agree
        rgb[..., 2] -= np.clip(m[..., 0], 0, 1)  # observed only -> red
        rgb[..., 0] -= np.clip(m[..., 1], 0, 1)  # simulated only -> blue
        ax.imshow(np.clip(rgb, 0, 1), interpolation="nearest")
        dis = record["spatial"]["disagreement"][v]
        ax.set_title(
            f"{record['views'][v]}: {'-' if dis is None or not np.isfinite(dis) else f'{dis:.2f}'}", fontsize=8
        )
        ax.set_xticks([])
        ax.set_yticks([])
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return Path(path)


def plot_extension(per_frame: dict, diagnosis: dict, name: str, path) -> Path:
    """The residual the named cause removes: D per frame (mean over the views) of the refit base and
    of the extended model, with the held-out time and the future frames shaded."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7, 3))
    for key, style, label in (("base", "k.-", "base (refit)"), ("extended", "C3.-", f"with {name}")):
        d = np.array([np.nan if v is None else v for v in per_frame[key]], float)
        ax.plot(np.arange(d.size), d, style, label=label, ms=4)
    time, future = diagnosis.get("time_frames") or [], diagnosis.get("future_frames") or []
    if time:
        ax.axvspan(time[0] - 0.5, time[-1] + 0.5, color="tab:green", alpha=0.12, label="held-out time")
    if future:
        ax.axvspan(future[0] - 0.5, future[-1] + 0.5, color="tab:orange", alpha=0.12, label="future")
    unit = (diagnosis.get("discrepancy") or {}).get("unit") or "the diagnosis's measure"
    ax.set_xlabel("frame")
    ax.set_ylabel(f"mean D ({unit})")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)


def write_plots(record: dict, maps: list, out_dir, n_views: int) -> dict:
    """{name: path} of the three plots written into out_dir."""
    out_dir = Path(out_dir)
    return {
        "d": plot_d(record, out_dir / "residual_d.png"),
        "com": plot_com(record, out_dir / "residual_com.png"),
        "spatial": plot_spatial(record, maps, out_dir / "residual_spatial.png", n_views),
    }


def _g(x, digits: int = 3) -> str:
    return "-" if x is None or (isinstance(x, float) and not np.isfinite(x)) else f"{x:.{digits}g}"


def _ci(fit: dict, key: str) -> str:
    """'c [low, high]' of a free-flight drag fit ('-' when not fitted)."""
    c, interval = fit[f"{key}_per_s"], fit[f"{key}_interval"]
    return _g(c) + (f" [{_g(interval[0])}, {_g(interval[1])}]" if interval else "")


def section(diagnosis: dict, record: dict | None, plots: dict | None):
    """The report's 'Model discrepancy' section: the decision and candidates, then the residuals
    (when computed). diagnosis and record are strict-JSON dicts (None for missing numbers)."""

    body = [f'<p id="discrepancy-cause"><b>Cause named: {esc(diagnosis["cause"])}</b> '
            "(a candidate is named when its held-out gain reaches its threshold, calibrated on null data; the largest "
            "such gain wins).</p>"]  # fmt: skip
    if diagnosis.get("ambiguous_with"):
        others = ", ".join(esc(c) for c in diagnosis["ambiguous_with"])
        body.append(
            f'<p id="discrepancy-ambiguous"><b>Ambiguous:</b> {others} fits the data as well (held-out gain within '
            f"{_g(diagnosis.get('mimic_margin'))} of the named cause's): these data do not tell them apart. "
            "Frames that separate them (e.g. a rebound, or sideways motion for air drag) would.</p>"
        )
        sep = diagnosis.get("separate")
        if sep:
            frames = sep["free_flight_frames"]
            longer = (
                f"a free fall of {frames} frames ({_g(sep['seconds'])} s) before the hit, against the "
                f"{sep['observed_frames']} observed, parts the fitted models by {_g(sep['pixel'])} pixel in some view"
                if frames is not None
                else "no fall within 10 s parts the fitted models by a pixel"
            )
            side = (
                f"; or a sideways throw of at least {_g(sep['sideways_speed'])} scene units / s (drag slows it, a "
                "weaker gravity does not)"
                if sep.get("sideways_speed") is not None
                else ""
            )
            body.append(
                f'<p id="discrepancy-separate"><b>What would separate them:</b> {longer} (they differ by at most '
                f"{_g(sep['pixels_within_observed'])} pixels over the observed frames){side}.</p>"
            )
    tie = diagnosis.get("settled_among") or []
    named = next((n for n, c in diagnosis["candidates"].items() if c["decision"] == "cause"), None)
    if tie and named in tie:
        others = [n for n in tie if n != named]
        window = lambda n: _g(diagnosis["candidates"][n].get("fit_window_gain"))  # noqa: E731
        body.append(
            f'<p id="discrepancy-settled"><b>Mimics told apart:</b> {esc(", ".join(others))} fit the free fall '
            f"about as well as {esc(named)}, but with their free-flight values {esc(named)} explains the whole "
            f"fit window better (held-out gain {window(named)} against "
            f"{', '.join(window(n) for n in others)}; margin {_g(diagnosis.get('mimic_window_margin'))}): "
            "a bounce's rise and fall part them.</p>"
        )
    rows = [
        [n, c["changes"], ", ".join(f"{k} = {_g(v)}" for k, v in (c["values"] or {}).items()),
         _g(c["gain"]), _g(c.get("min_gain", diagnosis["min_gain"])), _g(c.get("time_gain")),
         _g(c.get("min_time_gain")), _g(c["future_gain"]), c.get("decided_on", "views"), c["decision"]]
        for n, c in diagnosis["candidates"].items()
    ]  # fmt: skip
    header = ["candidate", "changes", "fitted values", "held-out-view gain", "threshold", "held-out-time gain",
              "threshold", "future gain", "decided on", "decision"]  # fmt: skip
    body.append(table(header, rows))
    if diagnosis.get("time_frames"):
        body.append(paragraph(
            f"Every fit uses frames {diagnosis['frames'][0]}-{diagnosis['frames'][-1]}; the held-out time is frames "
            f"{diagnosis['time_frames'][0]}-{diagnosis['time_frames'][-1]} of the fit window (all views), scored on "
            "each fit's open-loop rollout. Gains are the share of the base's discrepancy above the floor (frame 0's) "
            f"that a candidate removes; the cause is decided on: {esc(diagnosis.get('judge', 'views'))} (gravity "
            "and drag always on their free-flight window's held-out views)."
        ))  # fmt: skip
    ext = diagnosis.get("extension")
    if ext:
        fitted = ", ".join(
            f"{esc(k)} = {_g(v)} [{_g(ext['intervals'][k][0])}, {_g(ext['intervals'][k][1])}]"
            for k, v in ext["values"].items()
        )
        body.append(paragraph(
            f"The named cause's extension ({esc(ext['candidate'])}): {fitted} (the values whose fitting D is within 5% "
            f"of the best); held-out-view gain {_g(ext['held_out_gain'])}, held-out-time gain {_g(ext['time_gain'])}, "
            f"future gain {_g(ext['future_gain'])}. The asset with it: {esc(ext['asset'])} "
            "(experiments/simulate.py loads it)."
        ))  # fmt: skip
        body.append(image(ext["plot"], "the residual the named cause removes",
                          "D per frame (mean over the views) of the refit base and of the model with the named "
                          "extension; green: the held-out time (no fit saw it), orange: the future frames."))  # fmt: skip
    at_truth = {n: c["truth"] for n, c in diagnosis["candidates"].items() if c.get("truth")}
    if at_truth:
        parts = [
            f"{esc(n)} at " + ", ".join(f"{k} = {_g(v)}" for k, v in t["values"].items())
            + f": held-out gain {_g(t['gain'])} (threshold {_g(diagnosis['candidates'][n].get('min_gain'))})"
            for n, t in at_truth.items()
        ]  # fmt: skip
        body.append(
            '<p id="discrepancy-truth"><b>At the injected truth</b> (gt/effects.json; judged as the fits are): '
            + "; ".join(parts)
            + ". A gain below the threshold even at the truth means these data and this base model do not show "
            "the effect: no search would name it.</p>"
        )
    base, unit = diagnosis["base"], diagnosis["discrepancy"]["unit"]
    rebase = diagnosis.get("rebase")
    if rebase:
        fitted = "; ".join(
            f"{n} " + ", ".join(f"{_g(v)}" for v in st["values"].values()) + ("" if st["kept"] else " (not kept)")
            for n, st in rebase["steps"].items()
        )
        body.append(paragraph(
            f"The base is the asset's fit with its own parameters refitted on the fitting views ({fitted}): "
            f"held-out gain {_g(rebase['held_out_gain'])} and future gain {_g(rebase['future_gain'])} over the asset's "
            "fit. Each candidate is fitted from the asset's fit, these parameters are refitted with it in place, and "
            "its gains are over this base: what a candidate adds beyond a better fit of the base model."
        ))  # fmt: skip
    body.append(paragraph(
        f"Observed: {diagnosis['sequence']}. Measure: {diagnosis['discrepancy']['measure']} ({unit}). Base D, summed "
        f"over the view-frames: fitting views {_g(base['d_fit'])}, held-out views {_g(base['d_held_out'])}, held-out "
        f"time {_g(base.get('d_time'))}, future frames {_g(base['d_future'])}."
    ))  # fmt: skip
    if record is None:
        return Section("Model discrepancy", "".join(body))
    ff, ct, rs, com = record["free_flight"], record["contact"], record["rest_shape"], record["com"]
    body.append(image(plots["d"], "residual D per view and frame",
                      f"The base fit's discrepancy D ({unit}) per view (rows; in brackets its mean over the fit "
                      "frames) and frame (columns); frame 0 is the rest state and not scored. Below: the mean over "
                      "the views."))  # fmt: skip
    body.append(image(plots["com"], "centre of mass observed against simulated",
                      "Centre of mass from the silhouette centroids of all views, triangulated the same way for the "
                      "images and for the base rollout's projected Gaussians; green: the simulated anchors' mean."))  # fmt: skip
    rows = []
    for label, get in (
        ("free fall: acceleration / recorded gravity", lambda n: ff[n]["ratio"]),
        ("free fall: linear drag at recorded gravity (1/s) [95%]", lambda n: _ci(ff[n], "drag")),
        ("free fall: rms residual of the parabola (scene units)", lambda n: ff[n]["rms_parabola"]),
        ("free flight: horizontal speed (scene units / s)", lambda n: ff[n]["horizontal_speed"]),
        ("free flight: linear drag of the horizontal motion (1/s) [95%]", lambda n: _ci(ff[n], "horizontal_drag")),
        ("bounce apex above the contact (scene units)", lambda n: ct[n]["bounce"]),
        ("sliding after the hit frame (scene units)", lambda n: ct[n]["sliding"]),
        ("rest shape: area last / first frame (median over views)", lambda n: rs[f"area_{n}"]),
        ("rest shape: height last / first frame", lambda n: rs[f"height_{n}"]),
        ("rest shape: width last / first frame", lambda n: rs[f"width_{n}"]),
        ("speed at the last frame (scene units / s)", lambda n: com[f"speed_last_{n}"]),
    ):
        rows.append([label, *(v if isinstance(v, str) else _g(v) for v in (get("observed"), get("simulated")))])
    body.append(table(["quantity", "observed", "simulated"], rows))
    notes = [r for r in (ff["observed"]["reason"], ct["observed"]["reason"]) if r]
    body.append(paragraph(
        f"Centre-of-mass error (observed - simulated, triangulated): rms {_g(com['rms_error_fit'])} over the fit "
        f"frames, {_g(com['rms_error_future'])} over the future frames; object size {_g(com['size'])}. "
        "Both columns use the same estimator, so compare them with each other, not with the truth: a free fall "
        "slower than gravity in the images but not in the simulation points at drag or a weaker gravity (drag also "
        "slows the horizontal motion; a weaker gravity does not); a rest "
        "shape that changes in the images only points at plasticity (the ratios compare rest shapes only when the "
        "speed at the last frame is near zero; else they compare poses). " + " ".join(f"Not computed: {n}." for n in notes)
    ))  # fmt: skip
    body.append(image(plots["spatial"], "where the silhouettes disagree",
                      "Views that disagree most (title: mean |observed XOR simulated| / observed area over the frames "
                      "after 0). Red: observed, not simulated; blue: simulated, not observed; darker = more frames."))  # fmt: skip
    body.append(paragraph("Files: diagnosis.json (the decision), residuals.json (every number here)."))
    return Section("Model discrepancy", "".join(body))
