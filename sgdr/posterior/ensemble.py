"""The forecast of several runs of one sequence: the identification's run-to-run spread.

    python experiments/posterior.py preset=small posterior.run=outputs/torus_small_s0 \
        'posterior.ensemble=[outputs/torus_small_s1,outputs/torus_small_s2,outputs/torus_small_s3]'

Runs of the same sequence at other seeds (`experiments/reconstruct.py ... seed=1`) fit the fit
frames equally well and can predict different futures (docs/identification.md: which of the
equally good fits predicts the future is a gamble); one run's posterior only knows its own basin.
With `posterior.ensemble` the posterior combines the finished posteriors of `posterior.run` and
the listed runs (each `<run>/posterior/posterior.json`, written by `experiments/posterior.py` on
that run) instead of sampling again: the predictive ball of the centre of mass is the
equal-weight mixture of the runs' posterior-predictive draws, each with its own image-measured
misfit, growing by `posterior.ensemble_growth` after the fit frames (`forecast.ensemble_ball`).

Writes `ensemble.json` (strict JSON: the runs, the ball per frame, each run's centre and, with
ground truth, the share of frames whose true centre of mass lies inside) and `ensemble.png` into
`posterior.out_dir` (default `<posterior.run>/posterior_ensemble`).
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np

from sgdr.evaluate.score import strict_json
from sgdr.posterior import forecast

log = logging.getLogger(__name__)


def member_case(run_dir: Path) -> tuple[dict, bool]:
    """(the predictive ball's case, `forecast.coverage`'s form; whether it converged) of one run's
    finished posterior."""
    f = Path(run_dir) / "posterior" / "posterior.json"
    if not f.exists():
        raise FileNotFoundError(
            f"{f}: missing; posterior.ensemble combines finished posteriors: run "
            f"`python experiments/posterior.py posterior.run={run_dir}` first"
        )
    record = json.loads(f.read_text())
    ball = (record.get("predictive") or {}).get("com_ball")
    if not ball or not ball.get("draws"):
        raise ValueError(f"{f}: no predictive ball (predictive.com_ball); rerun the posterior with this version")
    return ball, bool(record.get("converged"))


def _digest(run_dir: Path) -> str:
    f = Path(run_dir) / "RUN.json"
    if not f.exists():
        raise FileNotFoundError(f"{f}: missing; is {run_dir} a finished run folder? (posterior.ensemble)")
    return str(json.loads(f.read_text()).get("digest", ""))


def run_ensemble(cfg) -> dict:
    """cfg: the composed config; returns the record written to ensemble.json."""
    pc = cfg.posterior
    runs = list(dict.fromkeys([str(pc.run), *map(str, pc.ensemble)]))
    digests = {r: _digest(Path(r)) for r in runs}  # before reading any posterior
    if len(set(digests.values())) > 1:
        first = runs[0]
        other = next(r for r in runs if digests[r] != digests[first])
        raise ValueError(
            f"posterior.ensemble: {other} reconstructed another sequence than {first} (RUN.json digests "
            f"differ); an ensemble combines runs of one sequence"
        )
    cases, converged = zip(*(member_case(Path(r)) for r in runs))
    ball = forecast.ensemble_ball(list(cases), float(pc.ensemble_growth), float(pc.band_level), int(cfg.seed))
    n_fit = len(cases[0]["sigma_fit"])
    size = float(np.mean([c["size"] for c in cases]))
    radius = np.asarray(ball["radius"])
    record = {
        "runs": runs,
        "converged": list(converged),
        "growth": float(pc.ensemble_growth),
        "level": float(pc.band_level),
        "n_fit": n_fit,
        "fps": float(cases[0]["fps"]),
        "size": size,
        "centre": ball["centre"],
        "radius": radius,
        "member_centres": ball["member_centres"],
        "truth": cases[0].get("truth"),
        "truth_inside_fit": ball.get("truth_inside_fit"),
        "truth_inside_future": ball.get("truth_inside_future"),
    }
    future = radius[n_fit:] if radius.size > n_fit else radius[-1:]
    record["headline"] = (
        f"Ensemble of {len(runs)} runs ({sum(converged)} of their posteriors converged): the {pc.band_level:.0%} ball of the centre of mass reaches "
        f"{future[-1] / size:.2f} object sizes at the last frame"
        + (
            f"; the true centre of mass inside on {ball['truth_inside_future']:.0%} of the future frames."
            if ball.get("truth_inside_future") is not None
            else "."
        )
    )
    out = Path(pc.out_dir) if pc.out_dir else Path(pc.run) / "posterior_ensemble"
    out.mkdir(parents=True, exist_ok=True)
    (out / "ensemble.json").write_text(json.dumps(strict_json(record), indent=1, allow_nan=False))
    plot_ensemble(record, out / "ensemble.png")
    record["out_dir"] = str(out)
    log.info("posterior ensemble: %s (%s)", record["headline"], out)
    return record


def plot_ensemble(record: dict, path) -> None:
    """The ball's radius over the frames (object sizes), each run's own centre's distance from the
    ensemble's centre, and the truth's where known."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    size = record["size"]
    centre = np.asarray(record["centre"])
    t = np.arange(centre.shape[0]) / record["fps"]
    fig, ax = plt.subplots(figsize=(7, 3.6))
    ax.fill_between(t, 0, np.asarray(record["radius"]) / size, color="tab:blue", alpha=0.2,
                    label=f"{record['level']:.0%} ball (ensemble)")  # fmt: skip
    for k, c in enumerate(np.asarray(record["member_centres"])):
        ax.plot(t, np.linalg.norm(c - centre, axis=-1) / size, lw=1, color="0.4",
                label="each run's centre" if k == 0 else None)  # fmt: skip
    if record.get("truth"):
        truth = np.asarray(record["truth"])
        ax.plot(t[: truth.shape[0]], np.linalg.norm(truth - centre[: truth.shape[0]], axis=-1) / size, "k--",
                label="truth")  # fmt: skip
    ax.axvline((record["n_fit"] - 0.5) / record["fps"], color="tab:red", lw=0.8, label="end of the fit frames")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("from the ensemble centre (sizes)")
    ax.legend(fontsize=7, loc="upper left")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
