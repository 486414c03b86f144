"""The posterior of a finished run, start to end (`experiments/posterior.py` calls `run_posterior`).

Reads `<posterior.run>/asset`, the observed sequence (`posterior.sequence`, default the run's own
from RUN.json; e.g. a twin), builds the likelihood (`posterior.likelihood`: the rendered images,
scaled by the identified parameters' own misfit; or the silhouettes), samples it
(`posterior.sampler`: ensembles on a checked Gaussian-process surrogate started from the run's
global-stage population, or on the likelihood itself), diagnoses the chains, rolls out the
posterior predictive with the forecast's discrepancy ball, and writes into `<run>/posterior/`
(or `posterior.out_dir`):

  posterior.json   strict JSON: headline, converged, failed criteria, per-parameter median / 5% / 95%,
                   τ, R-hat, ESS, acceptance, priors, likelihood settings, predictive curves, cost
  samples.npz      chains [E, steps, W, D], log_prob [E, steps, W], acceptance [E, W], names,
                   kept [N, D] (post burn-in, thinned), burn_in, thin; with the surrogate also
                   evaluated [N, D], evaluated_log_like [N] (every rendered evaluation)
  design_search.json  a sequence other than the run's own: the global search on its images (the
                   design's candidates), kept with its key (`search_key`) for a rerun
  corner.png, traces.png, predictive.png, ensemble.mp4 (the draws' projected centres over the images)

and adds the 'Posterior' section to `<run>/report/report.html` when that page exists.
The walkers' samples are simulated by `posterior.rollout` (`sgdr.posterior.rollouts.ROLLOUTS`:
batched by default) unless a `rollout` function is passed.
"""

from __future__ import annotations

import json
import logging
import time
from pathlib import Path

import numpy as np

from sgdr.digest import file_hash, key_hash
from sgdr.evaluate.score import strict_json
from sgdr.observe.silhouette import CentreMap, discrepancy, observation
from sgdr.physics import Ground
from sgdr.posterior import predictive as pp
from sgdr.posterior.likelihood import RenderedImages, RenderedLikelihood, SilhouetteLikelihood, reference_index
from sgdr.posterior.rollouts import ROLLOUTS
from sgdr.posterior.sample import (
    LogProbability,
    Problem,
    diagnose,
    headline,
    kept_samples,
    longer_chains,
    run_ensembles,
)
from sgdr.posterior.surrogate import design, sample_with_surrogate
from sgdr.report.html import add_section
from sgdr.run_folder import run_asset_and_sequence, run_sequence, sequence_digest

log = logging.getLogger(__name__)


def run_posterior(cfg, rollout=None, progress: bool = False) -> dict:
    """cfg: the composed config (`Config`); returns the record written to posterior.json."""

    pc = cfg.posterior
    t0 = time.time()
    run_dir = Path(pc.run)
    asset_dir, asset, seq_dir, seq = run_asset_and_sequence(run_dir, pc.sequence, cfg.scene_file, "posterior")
    out = Path(pc.out_dir) if pc.out_dir else run_dir / "posterior"
    out.mkdir(parents=True, exist_ok=True)

    model, _ = asset.build()
    ground = Ground(asset.ground_point, asset.ground_normal)
    rollout = rollout or ROLLOUTS.get_named(pc.rollout)
    common = (model, asset.values)
    fit_frames = np.arange(1, asset.n_fit, int(pc.frame_stride))
    if fit_frames.size == 0:
        raise ValueError(f"{asset_dir}: {asset.n_fit} fit frame(s); the likelihood needs fit frames after frame 0")
    n_fit_rollout = int(fit_frames[-1]) + 1
    rollout_fit = lambda s: rollout(*common, s, ground, n_fit_rollout, 1.0 / asset.fps, asset.n_substeps, asset.physics)  # noqa: E731
    n_all = max(asset.n_frames, seq.n_frames)
    rollout_all = lambda s: rollout(*common, s, ground, n_all, 1.0 / asset.fps, asset.n_substeps, asset.physics)  # noqa: E731

    problem = Problem.from_config(asset, pc)
    images = rendered_images(cfg, run_dir, asset, seq, problem) if pc.likelihood == "rendered" else None
    start, design_search = None, None
    if pc.sampler == "surrogate":
        search = _dynamics(run_dir).get("search") or {}
        if search.get("candidates") and pc.surrogate.search_other_sequence and not _own_sequence(run_dir, seq_dir):
            search = design_search = cached_search(
                out / "design_search.json",
                search_key(cfg, asset_dir, seq_dir),
                lambda: search_sequence(cfg, asset, seq, images, progress),
            )
        start = design(problem, candidates_as_theta(search, asset, problem), pc.surrogate.n_initial,
                       pc.surrogate.n_sobol, cfg.seed)  # fmt: skip
    if pc.likelihood == "rendered":
        log_prob, _, like_record = _rendered(cfg, run_dir, asset, seq, problem, start, images)
    else:
        log_prob, _, like_record = _silhouette(cfg, asset, seq, problem, rollout_fit, asset_dir)
    run_chains = lambda lp, steps, start=None, **kw: run_ensembles(lp, problem, pc.n_walkers, steps, pc.n_ensembles,  # noqa: E731
                                                                   pc.init_ball, seed=cfg.seed, progress=progress,
                                                                   move=pc.moves, space=pc.space, start=start, **kw)  # fmt: skip
    # the chains on the surrogate (cheap): a pilot, then the mixture's independence proposals beside pc.moves
    on_surrogate = {"independence": pc.surrogate.independence, "pilot_steps": pc.surrogate.pilot_steps}
    surrogate = None
    if pc.sampler == "surrogate":
        chains, log_probs, acceptance, surrogate = sample_with_surrogate(
            log_prob, problem, start, pc.surrogate, lambda lp, walkers: run_chains(lp, pc.surrogate.chain_steps, walkers, **on_surrogate), cfg.seed,
            progress,
        )  # fmt: skip
    else:
        chains, log_probs, acceptance = run_chains(log_prob, pc.n_steps)
    sample_seconds = time.time() - t0
    diag = diagnose(chains, problem.names, pc, acceptance)
    cap = 10 * int(pc.surrogate.chain_steps)
    while surrogate is not None and surrogate.validated and (steps := longer_chains(diag, pc, cap)):
        # the surrogate stands; its chains are only too short (τ, ESS or R-hat): lengthen them, again
        # while they stay short (GP predictions only, no renders), at most 10 x posterior.surrogate.chain_steps
        log.info("posterior surrogate: chains of %d steps are too short (%s); again with %d", diag["n_steps"],
                 "; ".join(diag["failed"]), steps)  # fmt: skip
        chains, log_probs, acceptance = run_chains(surrogate.surrogate, steps, surrogate.start, **on_surrogate)
        diag = diagnose(chains, problem.names, pc, acceptance)
    if surrogate is not None and not surrogate.validated:
        last = surrogate.rounds[-1]
        if last.get("open_edges"):
            why = (f"{last['open_edges']} of its {last['edges']} edge probes within {pc.surrogate.edge_within:g} nats "
                   f"of the best: the likelihood reaches beyond the chains (posterior.surrogate.edge_points)")  # fmt: skip
        else:
            why = (f"{last['inside_95']:.0%} of its last draws inside its 95% interval, < "
                   f"{pc.surrogate.inside_min:g}")  # fmt: skip
        diag["failed"].append(
            f"the surrogate did not stand for the rendered likelihood after {len(surrogate.rounds)} round(s): "
            f"{why} (posterior.surrogate.max_rounds, posterior.surrogate.n_validate)"
        )
        diag["converged"] = False
    kept = kept_samples(chains, diag)
    median = np.array([diag["median"][n] for n in problem.names])
    pred, pred_centres, pred_stable = pp.predictive(
        rollout_all,
        CentreMap(asset, 0),
        problem,
        kept,
        median,
        pc.n_predictive,
        seq,
        seed=cfg.seed,
        map_theta=problem.map_theta,
        growth=pc.discrepancy_growth,
        size=float(np.ptp(asset.anchors, axis=0).max()),
        level=pc.band_level,
        offsets=point_offsets(cfg, asset, seq) if pc.discrepancy_offset else None,
    )
    truth = twin_truth(seq, asset_dir, problem)
    notes = []
    if "restitution" in problem.names and asset.physics.contact != "coulomb":
        notes.append(
            f"restitution has no effect with the asset's physics.contact={asset.physics.contact} (only coulomb "
            "contact bounces): its posterior is its prior"
        )
    record = {
        "headline": headline(diag),
        "converged": diag["converged"],
        "failed": diag["failed"],
        "run": str(run_dir),
        "sequence": str(seq_dir),
        "names": problem.names,
        "map": {n: float(t) for n, t in zip(problem.names, problem.map_theta)},
        "priors": {n: [float(lo), float(hi)] for n, lo, hi in zip(problem.names, problem.low, problem.high)},
        "sampler": {
            "kind": pc.sampler,
            "moves": pc.moves,
            "space": pc.space,
            "rollout": pc.rollout,
            "surrogate": surrogate.to_json() if surrogate is not None else None,
            # the global search on this sequence that gave the design's candidates (a sequence other
            # than the run's own; posterior.surrogate.search_other_sequence), else None: the run's own
            "design_search": None
            if design_search is None
            else {k: design_search[k] for k in ("names", "best", "best_loss", "n_evaluations", "image_scale")},
        },
        "truth": truth or None,
        "notes": notes,
        "truth_inside_5_95": {n: bool(diag["q05"][n] <= t <= diag["q95"][n]) for n, t in truth.items()} or None,
        "likelihood": like_record,
        "criteria": {
            k: float(getattr(pc, k)) for k in ("tau_factor", "rhat_max", "ess_min", "acceptance_min", "acceptance_max")
        },
        "diagnostics": diag,
        "predictive": pred,
        "cost": {
            "rollouts": int(log_prob.calls),
            "unstable_rollouts": int(log_prob.unstable),
            "sampling_seconds": float(sample_seconds),
            "seconds": float(time.time() - t0),
        },
    }
    record = write_outputs(strict_json(record), out, run_dir, seq, asset, problem, chains, log_probs, acceptance,
                           kept, diag, pred, pred_centres, pred_stable, truth, t0, surrogate)  # fmt: skip
    if cfg.tracking.enabled:
        record["mlflow_run_id"] = log_to_mlflow(run_dir, out, record)
    return record


PROFILE_SHIFTS = (-0.5, -0.25, -0.1, 0.0, 0.1, 0.25, 0.5)
"""log10 k shifts (decades, the other parameters at the MAP) at which the record profiles the
rendered log-likelihood: how sharply the images pin the stiffness level down."""


class RenderedLogProbability(LogProbability):
    """log p(θ) [S] for θ [S, D]: the uniform prior and the rendered likelihood (-inf outside);
    `LogProbability` with the image losses [S, F, V] in place of the silhouette residuals."""

    def __init__(self, problem, images: RenderedImages, likelihood: RenderedLikelihood):
        self.problem, self.images, self.likelihood = problem, images, likelihood

    @property
    def calls(self) -> int:
        return self.images.calls

    @property
    def unstable(self) -> int:
        return self.images.unstable

    def discrepancies(self, thetas: np.ndarray) -> np.ndarray:
        return self.images(thetas)


def rendered_images(cfg, run_dir: Path, asset, seq, problem) -> RenderedImages:
    """The rendered likelihood's images at posterior.image_scale (0: the run's own search scale)."""
    pc = cfg.posterior
    scale = int(pc.image_scale) or int(((_dynamics(run_dir).get("search") or {}).get("image_scale")) or 1)
    return RenderedImages(asset, seq, problem, cfg.render, cfg.recon.lambda_dssim, scale,
                          cfg.recon.search.images_per_call)  # fmt: skip


def _own_sequence(run_dir: Path, seq_dir: Path) -> bool:
    try:
        return Path(seq_dir).resolve() == run_sequence(run_dir).resolve()
    except (FileNotFoundError, KeyError):
        return False


def design_search_config(cfg):
    """The design search's settings on a sequence other than the run's own: recon.search.* with
    posterior.surrogate.design_search.* (its first look, sweeps, generations and windows) in place."""
    from dataclasses import asdict, is_dataclass, replace

    from omegaconf import OmegaConf

    ds = cfg.posterior.surrogate.design_search
    over = asdict(ds) if is_dataclass(ds) else OmegaConf.to_container(ds, resolve=True)
    over["frame_schedule"] = [float(f) for f in over["frame_schedule"]]
    search = cfg.recon.search
    return replace(search, **over) if is_dataclass(search) else OmegaConf.merge(search, over)


def asset_level(asset) -> float:
    """The asset's stiffness level: the mean of its log10 k field, what log10_k_shift shifts."""
    return float(np.mean(asset.values["log10_k"]))


SEARCHED_AS = {"log10_k_shift": "log10_k", "kappa": "kappa", "friction": "friction", "restitution": "restitution"}


def prior_search_box(sc, priors, sampled, level: float):
    """The design search's settings with its box the posterior's prior box: each sampled parameter's
    `recon.search.<name>_range` from `posterior.priors` (the shift's as the level `level` + the
    shift; the stability cap still applies). The identification's own box can be narrower (its
    restitution ends at 0.9): a truth outside it can never be a design candidate. On the SBC's fourth
    draw, case 33's e = 0.976 lay there, and its posterior missed all four truths."""
    from dataclasses import is_dataclass, replace

    from omegaconf import OmegaConf

    over = {}
    for name in sampled:
        if name in SEARCHED_AS:
            a, b = (float(v) for v in getattr(priors, name))
            shift = level if SEARCHED_AS[name] == "log10_k" else 0.0
            over[f"{SEARCHED_AS[name]}_range"] = [a + shift, b + shift]
    return replace(sc, **over) if is_dataclass(sc) else OmegaConf.merge(sc, over)


def search_key(cfg, asset_dir: Path, seq_dir: Path) -> str:
    """The digest of what decides a design search: the asset's and the sequence's files, the
    search's settings (`design_search_config`), the prior box it searches (`prior_search_box`), the
    image loss's weight, the renderer's settings, the seed."""
    asset_files = {p.name: file_hash(p) for p in sorted(Path(asset_dir).iterdir()) if p.is_file()}
    return key_hash(
        {
            "asset": asset_files,
            "sequence": sequence_digest(Path(seq_dir)),
            "search": design_search_config(cfg),
            "priors": {n: [float(v) for v in getattr(cfg.posterior.priors, n)] for n in cfg.posterior.parameters},
            "lambda_dssim": float(cfg.recon.lambda_dssim),
            "render": cfg.render,
            "seed": int(cfg.seed),
        }
    )


def cached_search(path: Path, key: str, search) -> dict:
    """`search()`'s record, kept in `path` with `key` (`search_key`): a posterior run again on the
    same sequence (a calibration case resumed after its search, a rerun with other sampler
    settings) reads it instead of searching again (~20 min at small); a record of another key is
    searched again and replaced."""
    path = Path(path)
    if path.exists():
        try:
            kept = json.loads(path.read_text())
        except json.JSONDecodeError:
            kept = {}
        if kept.get("key") == key:
            log.info("posterior: the design search from %s (same sequence, asset and search settings)", path)
            return kept["search"]
    found = search()
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps({"key": key, "search": found}))
    tmp.replace(path)
    return found


def design_search_space(cfg, asset):
    """(settings, SearchSpace) of the design search on a sequence other than the run's own: recon.search.*
    with posterior.surrogate.design_search.* in place (`design_search_config`), over the posterior's
    prior box (`prior_search_box`) with the asset's model."""
    from sgdr.identify.global_search import search_space

    sc = prior_search_box(design_search_config(cfg), cfg.posterior.priors, cfg.posterior.parameters, asset_level(asset))
    model, _ = asset.build()
    per_anchor = np.ndim(asset.values["log10_k"]) > 0 and np.size(asset.values["log10_k"]) > 1
    return sc, search_space(sc, asset.physics, model, 1.0 / asset.fps, int(asset.n_substeps), per_anchor)


def search_sequence(cfg, asset, seq, images: RenderedImages | None, progress: bool = False) -> dict:
    """The identification's global stage (CMA-ES over its parameters, every candidate's open-loop
    rollout rendered and scored; recon.search.* with posterior.surrogate.design_search.* in place,
    `design_search_config`) on `seq` with the asset's model and appearance: the design's
    candidates for a sequence the run did not see (e.g. a twin); the search record's JSON
    ({"names", "candidates", "losses", ...})."""
    from sgdr.identify.global_search import REGION_START, global_search

    sc, space = design_search_space(cfg, asset)
    if images is None or images.scorer.image_scale != int(sc.image_scale):
        images = RenderedImages(asset, seq, None, cfg.render, cfg.recon.lambda_dssim, sc.image_scale,
                                sc.images_per_call)  # fmt: skip
    # from the asset's own values (the regions from the identification's start), else the box's centre
    centre = dict(zip(space.names, 0.5 * (space.lo + space.hi)))
    init = {n: REGION_START.get(n, float(np.mean(asset.values.get(n, centre[n])))) for n in space.names}
    t0 = time.time()
    found = global_search(images.scorer, space, init, sc, cfg.seed, progress)
    log.info("posterior: global search on %s: %d candidates in %.0f s, best %s (loss %.5f)", seq.root,
             len(found.losses), time.time() - t0, found.best, found.best_loss)  # fmt: skip
    return found.to_json()


def _rendered(cfg, run_dir: Path, asset, seq, problem, design_thetas=None, images=None):
    """(log_prob, likelihood, the record's likelihood section) of the rendered likelihood: the
    identification's image loss at posterior.image_scale (0: the run's own search scale). Its
    scale is the misfit of the best-fitting of the MAP and `design_thetas` (the surrogate's first
    design, evaluated here once: the sampler's evaluation of it is not rendered again)."""
    pc = cfg.posterior
    images = images or rendered_images(cfg, run_dir, asset, seq, problem)
    scale = images.scorer.image_scale
    map_losses = images(problem.map_theta[None])
    if not np.all(np.isfinite(map_losses)):
        raise RuntimeError(f"{asset.root}: the identified parameters' rollout is unstable")
    evaluated = (
        problem.map_theta[None] if design_thetas is None else np.concatenate([problem.map_theta[None], design_thetas])
    )
    losses = images(evaluated)
    ref = reference_index(losses)
    likelihood = RenderedLikelihood.at_map(losses[ref], pc.loss_floor, pc.temperature)
    log_prob = RenderedLogProbability(problem, images, likelihood)
    profile = {}
    if "log10_k_shift" in problem.names:
        j = problem.names.index("log10_k_shift")
        thetas = np.repeat(problem.map_theta[None], len(PROFILE_SHIFTS), axis=0)
        thetas[:, j] = PROFILE_SHIFTS
        profile = {f"{d:+g}": float(v) for d, v in zip(PROFILE_SHIFTS, log_prob(thetas))}
    log.info("posterior: rendered likelihood, %d views x %d frames at 1/%d scale, noise %.4g, discrepancy %.4g -> %.4g",
             images.n_views, len(images.frames), scale, likelihood.noise, likelihood.discrepancy[0],
             likelihood.discrepancy[-1])  # fmt: skip
    record = {
        "kind": "rendered",
        "views": [c.name for c in seq.cameras],
        "n_views": images.n_views,
        "frames": images.frames.tolist(),
        "n_frames": len(images.frames),
        "image_scale": scale,
        "lambda_dssim": float(cfg.recon.lambda_dssim),
        "noise": likelihood.noise,
        "discrepancy_per_frame": likelihood.discrepancy.tolist(),
        "map_loss_per_frame": map_losses[0].mean(axis=1).tolist(),
        # the scale's reference: the best-fitting evaluated sample (the MAP unless a design point fits better)
        "reference": {n: float(t) for n, t in zip(problem.names, evaluated[ref])},
        "reference_is_map": bool(np.allclose(evaluated[ref], problem.map_theta, rtol=0.0, atol=1e-6)),
        "reference_loss_per_frame": losses[ref].mean(axis=1).tolist(),
        "temperature": float(pc.temperature),
        "profile_log10_k_shift": profile or None,
    }
    return log_prob, likelihood, record


def _silhouette(cfg, asset, seq, problem, rollout_fit, asset_dir: Path):
    """(log_prob, likelihood, the record's likelihood section) of the silhouette likelihood."""
    pc = cfg.posterior
    fit_frames = np.arange(1, asset.n_fit, int(pc.frame_stride))
    n_views = len(seq.cameras) if pc.n_views == 0 else min(int(pc.n_views), len(seq.cameras))
    views = sorted({int(round(i * len(seq.cameras) / n_views)) % len(seq.cameras) for i in range(n_views)})
    obs = observation(seq, views, fit_frames, pc.n_mask_points, seed=cfg.seed)
    centre_map = CentreMap(asset, pc.n_points, seed=cfg.seed)
    pos, stable = rollout_fit(problem.samples(problem.map_theta[None]))
    if not stable[0]:
        raise RuntimeError(f"{asset_dir}: the identified parameters' rollout is unstable")
    d_map = discrepancy(obs, centre_map(pos[:, obs.frames]))[0]
    likelihood = SilhouetteLikelihood.at_map(obs, d_map, pc.sigma_floor_px, pc.temperature)
    log.info("posterior: silhouette likelihood, %d views x %d frames, sigma %.3g px", len(views), len(fit_frames),
             np.sqrt(likelihood.sigma2))  # fmt: skip
    record = {
        "kind": "silhouette chamfer",
        "views": [seq.cameras[v].name for v in views],
        "n_views": len(views),
        "frames": fit_frames.tolist(),
        "n_frames": len(fit_frames),
        "n_points": int(centre_map.rest.shape[0]),
        "n_mask_points": int(pc.n_mask_points),
        "sigma_px": float(np.sqrt(likelihood.sigma2)),
        "map_discrepancy_px2": d_map.tolist(),
        "temperature": float(pc.temperature),
    }
    return LogProbability(problem, rollout_fit, centre_map, likelihood), likelihood, record


def _dynamics(run_dir: Path) -> dict:
    path = run_dir / "dynamics" / "dynamics.json"
    return json.loads(path.read_text()) if path.exists() else {}


def candidates_as_theta(search: dict, asset, problem) -> np.ndarray:
    """[N, D] a global search's candidates (its record: names, candidates, losses; best first) as
    θ: the level as a shift of the asset's field mean, parameters the search did not vary at the
    MAP; empty when there was no search."""
    if not search.get("candidates"):
        return np.zeros((0, len(problem.names)))
    names = list(search["names"])
    cand = np.asarray(search["candidates"], float)
    loss = np.asarray(search["losses"], float)
    cand = cand[np.argsort(loss, kind="stable")]
    level = asset_level(asset)
    out = np.repeat(problem.map_theta[None], len(cand), axis=0)
    for j, name in enumerate(problem.names):
        key = "log10_k" if name == "log10_k_shift" else name
        if key in names:
            out[:, j] = cand[:, names.index(key)] - (level if key == "log10_k" else 0.0)
    return out


def twin_truth(seq, asset_dir: Path, problem) -> dict:
    """The true values of the sampled parameters when the sequence is a twin (its gt records
    them; a twin of this very asset: the keys it left out are the asset's own values), else {}."""
    gt = seq.gt_params() or {}
    if not gt.get("twin"):
        return {}
    truth = {k: float(v) for k, v in (gt.get("truth") or {}).items() if k in problem.names}
    if Path(gt.get("asset", "")).resolve() == asset_dir.resolve():
        for n, t in zip(problem.names, problem.map_theta):
            truth.setdefault(n, float(t))
    return truth


def write_outputs(record, out, run_dir, seq, asset, problem, chains, log_probs, acceptance, kept, diag, pred,
                  pred_centres, pred_stable, truth, t0, surrogate=None) -> dict:  # fmt: skip
    """samples.npz, the corner, trace and band plots, the ensemble video, posterior.json and the
    report's 'Posterior' section (when the run has a report). With the surrogate sampler,
    samples.npz also holds every true evaluation (`evaluated` [N, D], `evaluated_log_like` [N])."""
    np.savez(
        out / "samples.npz",
        chains=chains,
        log_prob=log_probs,
        acceptance=acceptance,
        names=np.array(problem.names),
        kept=kept,
        burn_in=diag["burn_in"],
        thin=diag["thin"],
        **({"evaluated": surrogate.thetas, "evaluated_log_like": surrogate.log_like} if surrogate is not None else {}),
    )
    pp.plot_corner(kept, problem.names, out / "corner.png", truth or None, problem.map_theta)
    pp.plot_traces(chains, problem.names, diag["burn_in"], out / "traces.png")
    pp.plot_bands(pred, asset.fps, out / "predictive.png")
    pp.ensemble_video(seq, pred_centres, pred_stable, out / "ensemble.mp4")
    record["cost"]["seconds"] = float(time.time() - t0)
    (out / "posterior.json").write_text(json.dumps(record, indent=1, allow_nan=False))
    report = run_dir / "report" / "report.html"
    if report.exists():
        add_section(report, pp.section(record, out))
        record["report"] = str(report)
    return record


def log_to_mlflow(run_dir: Path, out: Path, record: dict) -> str | None:
    """Log the posterior's files (artifact folder `posterior/`) and its diagnostics (metrics
    `posterior_*`) into the run folder's MLflow run (`mlflow_run.json`); None when the run has
    none. A tracking failure is logged, never raised: the posterior's files are already written."""
    state = run_dir / "mlflow_run.json"
    if not state.exists():
        log.warning("posterior: %s missing, nothing logged to MLflow", state)
        return None
    doc = json.loads(state.read_text())
    try:
        from mlflow.tracking import MlflowClient

        client = MlflowClient(tracking_uri=doc["tracking_uri"])
        run_id = doc["run_id"]
        client.log_artifacts(run_id, str(out), "posterior")
        d = record["diagnostics"]
        metrics = {"posterior_converged": float(record["converged"]), "posterior_seconds": record["cost"]["seconds"]}
        if d["tau_max"] is not None:
            metrics["posterior_tau_max"] = d["tau_max"]
        for n in record["names"]:
            for key in ("median", "q05", "q95", "rhat", "ess_bulk"):
                if d[key][n] is not None:
                    metrics[f"posterior_{key}_{n}"] = d[key][n]
        for k, v in metrics.items():
            client.log_metric(run_id, k, float(v))
        return run_id
    except Exception as err:  # noqa: BLE001 (any store problem: the files are the record)
        log.warning("posterior: could not log to MLflow run in %s: %s", state, err)
        return None


def point_offsets(cfg, asset, seq) -> np.ndarray:
    """[n_fit, 3] `forecast.silhouette_offsets` of the identified asset's own prediction (rendered
    at the sequence's cameras over its fit frames) against the sequence's silhouettes."""
    from sgdr.asset.predict import physical_params, predict
    from sgdr.posterior.forecast import silhouette_offsets

    n_fit = min(int(asset.n_fit), int(seq.n_fit))
    model, binding = asset.build()
    params = physical_params(model, asset.physics, asset.values)
    ground = Ground(asset.ground_point, asset.ground_normal)
    pred = predict(model, params, binding, asset.gaussians, ground, n_fit, asset.fps, int(asset.n_substeps),
                   asset.physics, seq.cameras, cfg.render)  # fmt: skip
    alpha = pred.images[..., 3].astype(np.float64) / 255.0  # [F, V, H, W]
    return silhouette_offsets(seq, alpha, pred.centres.mean(axis=1))
