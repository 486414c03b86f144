"""Simulation-based calibration of the posterior on twin sequences (issue 14, §5).

    python -m evaluation.studies.calibrate_posterior posterior.run=outputs/torus_tiny_s0 preset=tiny \
        +cases=20 +out=results/calibration_tiny

For each case a truth is drawn from the prior (`posterior.priors`, the sampled
`posterior.parameters`; seeded by the case number), a twin sequence is rendered from the run's
asset with that truth (`sgdr.synth.twin`: the truth is in the model class), and the posterior
is computed on the twin's images with the same asset (`sgdr.posterior.run.run_posterior`).
Calibrated posteriors put the truth inside their 90% interval (5-95%) in 90% of the cases and
give SBC ranks (the number of kept posterior draws below the truth, Talts et al. 2018) that are
uniform. Writes `<out>/calibration.json` (or `+record=<file>`, e.g. a committed file under
results/ while the case folders stay in `<out>`; per case: truth, median, 5%, 95%, rank,
converged, τ, R-hat, the asset's digest; per parameter: coverage and the rank histogram, over all
cases and over the converged ones) and `<out>/ranks.png`; the last line printed is one JSON
object with the coverages. Cases already in the record are kept (resumable over sittings; a
record written with another sampler setup is refused). Truths come from the whole prior box (the
SBC's design); `+truth_margin=m` keeps them the fraction m of each box away from its edges (0.1 in
the records before 2026-12-06, whose ranks pile up in the middle wherever the data leave a
parameter to its prior); `+first_case=c` numbers the cases from c (another draw of truths and
noise, into a new record). `+twin_scale=s` renders the twins s times finer than the asset's cameras; `+twin_noise=σ` adds Gaussian noise of that standard
deviation to the twins' colours (seeded by the case: data of the kind the likelihood models).
`+shard=i/n` runs only the cases with case % n == i, so that n processes (one per core) share one
record: each case is merged into it under a file lock.
"""

from __future__ import annotations

import fcntl
import hashlib
import json
import sys
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path

import numpy as np
from omegaconf import OmegaConf

import sgdr.backend
from evaluation.studies.config import split_extra
from sgdr.cli import user_errors
from sgdr.config import compose, validate
from sgdr.posterior.run import design_search_config, run_posterior
from sgdr.synth.twin import twin_sequence

N_BINS = 5  # rank histogram bins (few cases: coarse bins)


TRUTH_MARGIN_BEFORE = 0.1  # records without "truth_margin" in their setup drew from the middle 80%


def draw_truth(priors, names, case: int, margin: float = 0.0) -> dict:
    """One truth per case, uniform in each sampled parameter's prior box (seeded by the case).
    `margin` > 0 keeps it that fraction of the box away from each edge (the records before
    2026-12-06 used 0.1): the ranks of a calibrated posterior are then uniform only where the data
    pin the parameter down; where the posterior is close to the prior they pile up in the middle
    (a truth in the middle 80% of a box-shaped posterior has a rank in [0.1, 0.9]). 0, the
    default, is the SBC's own design (Talts et al. 2018: the truth drawn from the prior)."""
    if not 0.0 <= margin < 0.5:
        raise SystemExit(f"error: +truth_margin={margin}: need 0 <= margin < 0.5 (a fraction of each prior box)")
    rng = np.random.default_rng([2026, case])
    out = {}
    for n in names:
        lo, hi = map(float, getattr(priors, n))
        out[n] = float(lo + (hi - lo) * rng.uniform(margin, 1.0 - margin))
    return out


def sbc_rank(kept: np.ndarray, truth: float) -> float:
    """The truth's rank among the kept draws as a fraction in [0, 1] (0: below every draw)."""
    kept = np.asarray(kept, float)
    return float(np.mean(kept < truth)) if kept.size else float("nan")


def rank_uniform_p(hist) -> float | None:
    """The p-value of Pearson's chi-square test of a rank histogram against the uniform one (the
    SBC's "uniform within its sampling error": a small p says the ranks pile up somewhere, e.g. at
    both ends when the posteriors are too narrow); None with fewer than one case per bin."""
    from scipy.stats import chisquare

    hist = np.asarray(hist, float)
    if hist.sum() < hist.size:
        return None
    return float(chisquare(hist).pvalue)


def summarise(cases: list[dict], names: list[str]) -> dict:
    """Coverage of the 5-95% interval and the rank histogram per parameter (with its chi-square
    p-value against the uniform one), and the coverage of the central 50% interval from the ranks
    (a rank in [0.25, 0.75]): 0.5 when calibrated, above it when the posteriors are too wide
    (conservative), below when too narrow; with the 90% coverage alone a too-wide posterior looks
    perfect."""
    out = {}
    for n in names:
        inside = [c["inside"][n] for c in cases if n in c["inside"]]
        ranks = np.array([c["rank"][n] for c in cases if np.isfinite(c["rank"].get(n, np.nan))], float)
        hist, _ = np.histogram(ranks, bins=N_BINS, range=(0.0, 1.0))
        out[n] = {
            "cases": len(inside),
            "coverage_90": float(np.mean(inside)) if inside else None,
            "coverage_50": float(np.mean((ranks >= 0.25) & (ranks <= 0.75))) if ranks.size else None,
            "rank_histogram": hist.tolist(),
            "rank_uniform_p": rank_uniform_p(hist),
        }
    return out


def plot_ranks(summary: dict, path: Path) -> Path:
    import matplotlib  # here, not at the top: the Agg backend is chosen only when a figure is drawn

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(summary)
    fig, axes = plt.subplots(1, len(names), figsize=(3.2 * len(names), 2.8), squeeze=False)
    for ax, n in zip(axes[0], names):
        h = summary[n]["rank_histogram"]
        ax.bar(np.arange(len(h)) + 0.5, h, width=0.9)
        ax.axhline(summary[n]["cases"] / len(h), color="k", ls="--", lw=1)
        ax.set_xlabel(f"rank of the true {n} (bins)")
        ax.set_ylabel("cases")
        cov, half = summary[n]["coverage_90"], summary[n].get("coverage_50")
        title = n if cov is None else f"{n}\n90% interval covers {cov:.0%}"
        if half is not None:
            title += f", 50%: {half:.0%}"
        if summary[n].get("rank_uniform_p") is not None:
            title += f"\nuniform ranks: p = {summary[n]['rank_uniform_p']:.2f}"
        ax.set_title(title, fontsize=9)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


@contextmanager
def locked_record(record_file: Path, setup: dict):
    """The record, read under an exclusive lock (so that shards running at once merge their cases
    instead of overwriting each other's); a record written with another setup is refused."""
    with open(record_file.with_name(record_file.name + ".lock"), "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            record = json.loads(record_file.read_text()) if record_file.exists() else {"cases": [], "setup": setup}
            if record.setdefault("setup", setup) != setup:
                hint = ""
                if "truth_margin" not in record["setup"] and setup.get("truth_margin") is not None:
                    hint = (
                        f" (its truths came from the prior's middle: +truth_margin={TRUTH_MARGIN_BEFORE} continues it)"
                    )
                raise SystemExit(
                    f"error: {record_file} was written with {record['setup']}, not {setup}{hint}: "
                    "use another +out= or +record=, or remove it"
                )
            yield record
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)


def parse_shard(text: str | None) -> tuple[int, int]:
    """`"i/n"` -> (i, n) with 0 <= i < n; None -> (0, 1)."""
    if text is None:
        return 0, 1
    try:
        i, n = (int(x) for x in str(text).split("/"))
    except ValueError:
        raise SystemExit(f"error: +shard={text}: expected i/n, e.g. +shard=0/2") from None
    if not (n >= 1 and 0 <= i < n):
        raise SystemExit(f"error: +shard={text}: need 0 <= i < n")
    return i, n


def sampler_setup(cfg, twin_scale: int, twin_noise: float = 0.0, truth_margin: float = 0.0) -> dict:
    """What a record's cases must share: the twins' scale and noise, how truths are drawn
    (`truth_margin`; absent in the records that drew from the middle 80%), the sampler's settings and, where the
    design comes from a global search on each twin's images (`posterior.surrogate.search_other_sequence`),
    that search's settings (`design_search_config`: its budget and schedule decide which basin is found)."""
    pc = cfg.posterior
    from dataclasses import asdict

    searched = pc.sampler == "surrogate" and pc.surrogate.search_other_sequence
    # the surrogate's own settings; its design search's are in "design_search", in effect
    surrogate = {k: v for k, v in asdict(pc.surrogate).items() if k != "design_search"}
    return {
        "twin_scale": int(twin_scale),
        **({"twin_noise": float(twin_noise)} if twin_noise else {}),  # absent without: older records stand
        **({"truth_margin": float(truth_margin)} if truth_margin != TRUTH_MARGIN_BEFORE else {}),
        "likelihood": pc.likelihood,
        "sampler": pc.sampler,
        "surrogate": surrogate if pc.sampler == "surrogate" else None,
        "moves": pc.moves,
        "space": pc.space,
        "n_steps": int(pc.n_steps),
        "n_walkers": int(pc.n_walkers),
        "n_ensembles": int(pc.n_ensembles),
        "parameters": list(pc.parameters),
        "design_search": asdict(design_search_config(cfg)) if searched else None,
    }


def same_twin(twin: Path, asset_dir: Path, truth: dict, twin_scale: int, twin_noise: float) -> bool:
    """Whether `twin` is a finished twin sequence (its sequence.json, written last) of `asset_dir`
    with this truth, scale and noise (gt/params.json): a resumed case reuses it, so that its posterior
    finds the design search it kept (`design_search.json`, keyed by the twin's files)."""
    try:
        gt = json.loads((twin / "gt" / "params.json").read_text())
    except (FileNotFoundError, json.JSONDecodeError):
        return False
    return (
        (twin / "sequence.json").exists()
        and gt.get("asset") == str(Path(asset_dir).resolve())
        and gt.get("truth") == json.loads(json.dumps(truth))
        and int(gt.get("image_scale", 1)) == int(twin_scale)
        and float(gt.get("image_noise", 0.0)) == float(twin_noise)
    )


def run_case(
    cfg,
    case: int,
    asset_dir: Path,
    digest: str,
    out: Path,
    twin_scale: int,
    twin_noise: float = 0.0,
    truth_margin: float = 0.0,
) -> dict:
    """One case: a truth drawn from the prior, its twin rendered from the asset (`digest`: its
    asset.json's), the posterior on the twin's images; the record's entry (truth, median, 5%, 95%,
    inside, rank, diagnostics)."""
    pc = cfg.posterior
    names = list(pc.parameters)
    truth = draw_truth(pc.priors, names, case, truth_margin)
    case_dir = out / f"case_{case:03d}"
    twin = case_dir / "twin"
    # a resumed case keeps its twin, and with it the design search its posterior kept
    if not same_twin(twin, asset_dir, truth, twin_scale, twin_noise):
        twin_sequence(asset_dir, twin, truth, cfg.render, image_scale=int(twin_scale),
                      image_noise=float(twin_noise), noise_seed=case)  # fmt: skip
    case_cfg = replace(
        cfg,
        tracking=replace(cfg.tracking, enabled=False),
        posterior=replace(pc, sequence=str(twin), out_dir=str(case_dir / "posterior")),
    )
    res = run_posterior(case_cfg, progress=False)
    with np.load(case_dir / "posterior" / "samples.npz", allow_pickle=False) as z:
        kept = z["kept"]
    diag = res["diagnostics"]
    return {
        "case": case,
        "truth": truth,
        "median": {n: diag["median"][n] for n in names},
        "q05": {n: diag["q05"][n] for n in names},
        "q95": {n: diag["q95"][n] for n in names},
        "inside": {n: bool(diag["q05"][n] <= truth[n] <= diag["q95"][n]) for n in names},
        "rank": {n: sbc_rank(kept[:, i], truth[n]) for i, n in enumerate(names)},
        "converged": bool(res["converged"]),
        "asset": digest,
        "failed": res["failed"],
        "tau_max": diag.get("tau_max"),
        "rhat_max": max((v for v in diag["rhat"].values() if v is not None), default=None),
        "seconds": res["cost"]["seconds"],
    }


def calibrate(
    cfg,
    n_cases: int,
    out: Path,
    progress: bool = True,
    twin_scale: int = 1,
    record_file: Path | None = None,
    shard: tuple[int, int] = (0, 1),
    twin_noise: float = 0.0,
    truth_margin: float = 0.0,
    first_case: int = 0,
) -> dict:
    """`n_cases` twins of `posterior.run`'s asset (cases `first_case`, ..., each case's truth and
    noise seeded by its number), each rendered `twin_scale` times finer than its cameras, and their
    posteriors; resumable (cases in `record_file`, default `<out>/calibration.json`, are kept, and
    a record written with another setup is refused). `shard=(i, n)` runs the cases with
    case % n == i; shards merge into one record."""
    out.mkdir(parents=True, exist_ok=True)
    record_file = Path(record_file) if record_file else out / "calibration.json"
    record_file.parent.mkdir(parents=True, exist_ok=True)
    draw_truth(cfg.posterior.priors, [], 0, truth_margin)  # a bad margin is refused before any work
    setup = sampler_setup(cfg, twin_scale, twin_noise, truth_margin)
    with locked_record(record_file, setup):
        pass  # refuses a record of another setup before any work
    names = list(cfg.posterior.parameters)
    asset_dir = Path(cfg.posterior.run) / "asset"
    digest = hashlib.sha256((asset_dir / "asset.json").read_bytes()).hexdigest()[:12]
    for case in range(first_case, first_case + n_cases):
        if case % shard[1] != shard[0]:
            continue
        with locked_record(record_file, setup) as record:
            if case in {c["case"] for c in record["cases"]}:
                continue
        entry = run_case(cfg, case, asset_dir, digest, out, twin_scale, twin_noise, truth_margin)
        with locked_record(record_file, setup) as record:
            record["cases"] = sorted(
                [c for c in record["cases"] if c["case"] != case] + [entry], key=lambda c: c["case"]
            )
            record_file.write_text(json.dumps(record, indent=1))
        if progress:
            inside = sum(entry["inside"].values())
            print(
                f"case {case}: {inside}/{len(names)} truths inside their 90% interval, {entry['seconds']:.0f} s",
                flush=True,
            )
    with locked_record(record_file, setup) as record:
        record["summary"] = summarise(record["cases"], names)
        converged = [c for c in record["cases"] if c["converged"]]
        record["converged_cases"] = len(converged)
        record["summary_converged"] = summarise(converged, names)
        record["parameters"] = names
        record_file.write_text(json.dumps(record, indent=1))
    plot_ranks(record["summary"], out / "ranks.png")
    return record


def main(argv: list[str]) -> None:
    extra, overrides = split_extra(argv)
    with user_errors():
        cfg = OmegaConf.to_object(compose(overrides))
        validate(cfg)
        sgdr.backend.init(cfg.backend, cfg.threads or None)
        out = Path(extra.get("out", "results/calibration"))
        record_file = Path(extra["record"]) if "record" in extra else out / "calibration.json"
        record = calibrate(
            cfg,
            int(extra.get("cases", 20)),
            out,
            twin_scale=int(extra.get("twin_scale", 1)),
            record_file=record_file,
            shard=parse_shard(extra.get("shard")),
            twin_noise=float(extra.get("twin_noise", 0.0)),
            truth_margin=float(extra.get("truth_margin", 0.0)),
            first_case=int(extra.get("first_case", 0)),
        )
    summary = {n: s["coverage_90"] for n, s in record["summary"].items()}
    conv = {n: s["coverage_90"] for n, s in record["summary_converged"].items()}
    line = {"calibration": str(record_file), "cases": len(record["cases"]), "coverage_90": summary}
    print(json.dumps({**line, "converged_cases": record["converged_cases"], "coverage_90_converged": conv}))


if __name__ == "__main__":
    main(sys.argv[1:])
