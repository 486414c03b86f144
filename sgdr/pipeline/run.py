"""The reconstruction pipeline, stage by stage, from a multi-view sequence to a scored asset.

    static fit -> anchors/springs/IDW -> refine (frame 0) -> v0 -> dynamics -> predict
               -> evaluate -> report, asset

The stages are the rows of `PIPELINE` (name, config sections, inputs, produce, load); what each
computes is `sgdr.pipeline.flow`. Each stage runs through `StageRunner` in `<run_dir>/<stage>/`: a rerun skips stages whose
outputs verify, `recon.force=true` redoes them, a damaged output is redone (see
`sgdr.pipeline.stages`). Every stage key holds the whole config sections the stage reads
(`stage_sections`), the digests of its inputs and the sequence's digest, so changing a
setting redoes that stage and everything after it; a field is left out of a key only by the
explicit lists below (`RECON_NEVER_IN_KEYS`, `RECON_STAGE_FIELDS`), so a forgotten field
errs on the side of recomputing.
The run folder also gets `config.yaml`, `metrics.json` (strict JSON, `run_metrics`), `reconstruct.log` (appended by every
invocation) and one MLflow run across resumes (`mlflow_run.json`; `sgdr.tracking`), which logs
the settings that act (`tracked_sections`), the git commit, metrics, report, asset and log.

Stage outputs (all under the run folder):
  static/gaussians.ply          3DGS PLY of the static fit (frame 0)
  anchors/anchors.npy           [N_A, 3] rest anchors (springs and IDW are rebuilt from them)
  refine/gaussians.ply          appearance refined at the IDW positions; losses.json
  velocity/velocity.json        v0 [3], loss per step, frames used
  dynamics/params.npz, dynamics.json   identified log10 k_i, κ, friction, restitution, n_t, losses
  predict/trajectory.npz        anchors [T, N_A, 3], centres [T, M, 3]; images.npy [T, V, H, W, 4] uint8 RGBA
  evaluate/scores.json          fit/future CD, EMD, PSNR, SSIM, baseline (also metrics.json); null + reason if missing
  report/                       report.html (verdict, warnings, curves, videos; self-contained), side_by_side.mp4,
                                future.mp4, metric_curves.png, losses.png, stiffness.png, ply/
  asset/                        what `experiments/simulate.py` loads (sgdr.asset.whatif)
"""

from __future__ import annotations

import contextlib
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path

import numpy as np

from sgdr.checks import ConfigError
from sgdr.config import validate
from sgdr.data import load_sequence
from sgdr.digest import file_hash, key_hash
from sgdr.evaluate.score import strict_json
from sgdr.pipeline import baselines_flow as bf
from sgdr.pipeline import flow
from sgdr.pipeline.flow import RunContext
from sgdr.pipeline.stages import CHECKPOINT_DIR, Checkpoint, StageResult, StageRunner, plain
from sgdr.registry import Registry
from sgdr.run_folder import (
    claim_run_dir,
    default_run_name,
    ensure_sequence,
    sequence_digest,
    sequence_name,
    sequence_written_since,
    sibling_runs,
)
from sgdr.tracking import RunTracker

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Stage:
    """One row of the pipeline: its name (= its folder in the run), the config sections it reads
    (whole, in its key), the stages whose outputs it reads (their digests in its key), and its
    `produce` / `load` (sgdr.pipeline.flow)."""

    name: str
    sections: tuple[str, ...]
    needs: tuple[str, ...]
    produce: Callable
    load: Callable
    seeded: bool = True  # cfg.seed in the key (the stage draws random numbers)
    reads_sequence: bool = True  # the sequence's digest in the key (it reads images or ground truth)
    extra_key: Callable | None = None  # more key entries, from the run context


# The data flow, in order. A stage's key = its sections + seed + sequence digest + its needs'
# digests (+ extra), so changing anything a stage reads redoes it and everything after it.
PIPELINE: tuple[Stage, ...] = (
    Stage("static", ("static_fit", "render"), (), flow.static_produce, flow.static_load),
    Stage("anchors", ("anchors",), ("static",), flow.anchors_produce, flow.anchors_load, reads_sequence=False),
    Stage("refine", ("recon", "anchors", "render"), ("static", "anchors"), flow.refine_produce, flow.refine_load),
    Stage("velocity", ("recon", "render"), ("refine",), flow.velocity_produce, flow.velocity_load),
    Stage(
        "dynamics",
        ("recon", "physics", "anchors", "render"),
        ("refine", "velocity"),
        flow.dynamics_produce,
        flow.dynamics_load,
    ),
    Stage(
        "predict",
        ("physics", "anchors", "render"),
        ("dynamics", "velocity"),
        flow.predict_produce,
        flow.predict_load,
        seeded=False,
        reads_sequence=False,
    ),
    Stage("evaluate", ("recon",), ("predict",), flow.evaluate_produce, flow.evaluate_load),
    Stage(
        "report",
        ("recon", "physics"),
        ("predict", "evaluate", "refine", "anchors", "velocity", "dynamics"),
        flow.report_produce,
        flow.report_load,
        seeded=False,
    ),
    Stage(
        "asset",
        ("physics", "anchors"),
        ("dynamics", "refine", "velocity"),
        flow.asset_produce,
        flow.asset_load,
        seeded=False,
        extra_key=flow.asset_key,
    ),
)
STAGES = tuple(st.name for st in PIPELINE)


@dataclass(frozen=True)
class Model:
    """A dynamic model's pipeline (`recon.model`): its stages in order, and the summary of what
    it identified for metrics.json (`identified(stages) -> dict`). Every model's dynamics stage
    value holds `pass_losses` (a list, possibly empty), `eval_loss_initial` and `eval_loss_final`."""

    stages: tuple[Stage, ...]
    identified: Callable


def spring_identified(stages: dict) -> dict:
    """The spring-mass model's identified values, summarised (metrics.json `identified`)."""
    dyn = stages["dynamics"].value
    return {
        "log10_k_mean": float(np.mean(dyn["log10_k"])),
        "log10_k_std": float(np.std(dyn["log10_k"])),
        "kappa": dyn["kappa"],
        "friction": dyn["friction"],
        "restitution": dyn["restitution"],
        "v0": list(stages["velocity"].value["v0"]),
    }


def _baseline_models() -> dict:
    """The baselines' pipelines: the shared stages (static fit, anchors, refine, v0) followed by
    their own rows (`sgdr.pipeline.baselines_flow`)."""

    shared = tuple(st for st in PIPELINE if st.name in ("static", "anchors", "refine", "velocity"))
    evaluate = next(st for st in PIPELINE if st.name == "evaluate")
    pacnerf = shared + (
        Stage("dynamics", ("baseline.pacnerf", "render"), ("refine", "velocity"), bf.pacnerf_produce, bf.pacnerf_load),
        Stage(
            "predict",
            ("baseline.pacnerf", "render"),
            ("dynamics", "refine", "velocity"),
            bf.pacnerf_predict_produce,
            bf.pacnerf_predict_load,
            seeded=False,
        ),
        evaluate,
        Stage(
            "report",
            ("recon", "baseline.pacnerf"),
            ("predict", "evaluate", "dynamics", "velocity"),
            bf.pacnerf_report_produce,
            bf.report_load,
            seeded=False,
        ),
        Stage(
            "asset",
            ("baseline.pacnerf",),
            ("dynamics", "refine", "velocity"),
            bf.pacnerf_asset_produce,
            bf.pacnerf_asset_load,
            seeded=False,
        ),
    )
    models = {"pacnerf": Model(pacnerf, bf.pacnerf_identified)}
    for name in bf.FIT_FRAME_MODELS:  # Table 2's other rows: the fit frames only (simplified Dy-Gaus, 4D-Gaus)
        section = f"baseline.{name}"
        models[name] = Model(
            shared
            + (
                Stage(
                    "dynamics",
                    (section, "render"),
                    ("refine",),
                    partial(bf.fit_frames_produce, name),
                    bf.fit_frames_load,
                ),
                Stage(
                    "predict",
                    ("render",),
                    ("dynamics", "refine"),
                    bf.fit_frames_predict_produce,
                    bf.fit_frames_predict_load,
                    seeded=False,
                    reads_sequence=False,
                ),
                Stage("evaluate", ("recon",), ("predict",), bf.fit_frames_evaluate_produce, flow.evaluate_load),
                Stage(
                    "report",
                    ("recon", section),
                    ("predict", "evaluate", "dynamics"),
                    partial(bf.fit_frames_report_produce, name),
                    bf.report_load,
                    seeded=False,
                ),
                Stage(
                    "asset",
                    (section,),
                    ("dynamics", "refine"),
                    partial(bf.fit_frames_asset_produce, name),
                    partial(bf.fit_frames_asset_load, name),
                    seeded=False,
                ),
            ),
            bf.fit_frames_identified,
        )
    return models


# The dynamic models a method chooses with `recon.model` (conf/method/): spring_mass is Spring-Gaus
# (every method of the spring family: spring_gaus, official, the ablations), the others are the
# paper's baselines (docs/baselines.md).
MODELS = Registry("dynamic model", "recon.model", ConfigError, {"spring_mass": Model(PIPELINE, spring_identified)})
MODELS.update(_baseline_models())


def model_stages(cfg) -> tuple[Stage, ...]:
    """The stages of `cfg.recon.model`'s pipeline."""
    return MODELS.get_named(cfg.recon.model).stages


@dataclass
class RunOutputs:
    run_dir: Path
    metrics: dict  # what metrics.json holds
    stages: dict[str, StageResult] = field(default_factory=dict)


# ------------------------------------------------------------------------------ stage keys
# recon fields that change no stage's outputs: where the run goes, whether to redo, how many
# processes score the EMD (the scores do not depend on it), how often to checkpoint (a resume
# is exact), and the settings of experiments/simulate.py.
RECON_NEVER_IN_KEYS = (
    "output_dir",
    "run_name",
    "force",
    "eval_workers",
    "checkpoint_every",
    "simulate",
    "share_stages",
)
# recon fields that only one stage reads: the other stages leave them out of their keys (a
# stage after it sees them through its input digests). A recon field in none of these lists
# is in the key of every stage that reads `recon`.
RECON_STAGE_FIELDS = {
    "refine": ("refine_iterations", "lr_scale", "lr_color", "lr_opacity", "refine_lambda_dssim"),
    "velocity": ("v0_iterations", "lr_v0", "v0_lambda_dssim", "v0_views_per_step"),
    "dynamics": (
        "model",
        "iterations",
        "lambda_dssim",
        "substep_growth",
        "cameras_per_frame",
        "lr_log10_k",
        "lr_kappa",
        "lr_friction",
        "lr_restitution",
        "mode",
        "log10_k_grid",
        "stiffness",
        "log10_k_min",
        "log10_k_max",
        "friction_max",
        "contact_margin",
    ),
    "evaluate": ("eval_emd",),
    "report": ("render_videos", "write_plys", "momentum_tolerance"),
}


def recon_section(cfg, stage: str) -> dict:
    """The `recon` section as stage `stage` sees it for its key: every field except
    `RECON_NEVER_IN_KEYS` and the fields other stages own (`RECON_STAGE_FIELDS`)."""

    others = {f for name, fields in RECON_STAGE_FIELDS.items() if name != stage for f in fields}
    return {k: v for k, v in plain(cfg.recon).items() if k not in others and k not in RECON_NEVER_IN_KEYS}


# The config sections each stage of the spring-mass pipeline reads, whole, in its key (besides
# seeds and input digests); a baseline's stages name their own (`MODELS`).
STAGE_SECTIONS = {st.name: st.sections for st in PIPELINE}


def _section(cfg, name: str):
    for part in name.split("."):  # a dotted name is a nested section ("baseline.pacnerf")
        cfg = getattr(cfg, part)
    return cfg


def stage_sections(cfg, stage: str, pipeline: tuple[Stage, ...] = PIPELINE) -> dict:
    """{section: its whole config} for the sections `stage` of `pipeline` (default: the
    spring-mass model's; a run passes its `model_stages`) reads (`recon` via `recon_section`)."""
    sections = next(st.sections for st in pipeline if st.name == stage)
    return {name: recon_section(cfg, stage) if name == "recon" else _section(cfg, name) for name in sections}


# Top-level settings that act on every reconstruction, besides the stages' sections.
RUN_SETTINGS = ("preset", "method", "seed", "sequence", "backend")


def tracked_sections(cfg, sequence_generated: bool) -> tuple[str, ...]:
    """What a reconstruction's MLflow run logs as parameters: the settings that act on it.

    The sections the PIPELINE stages read (`STAGE_SECTIONS`, recon without recon.simulate: the
    caller excludes it), `RUN_SETTINGS`, and of `synth`: all of it when this invocation
    generated the sequence (its settings made the data), else only `synth.object` when the
    sequence is the default-located one (`<data_dir>/<synth.object>`: it names the data), and
    nothing with `sequence=`. Never oracle.*, tracking.* or recon.simulate.* (they do not act on
    a reconstruction); the oracle and simulate drivers log their own."""
    sections = [*RUN_SETTINGS, *dict.fromkeys(s for st in model_stages(cfg) for s in st.sections)]
    if sequence_generated:
        sections.append("synth")
    elif not cfg.sequence:
        sections.append("synth.object")
    return tuple(sections)


# ------------------------------------------------------------------------------ the run
def run_pipeline(cfg, progress: bool = True, run_dir: Path | None = None) -> RunOutputs:
    """Reconstruct, predict, evaluate and report one sequence; returns the run's outputs.

    cfg: the composed `sgdr.config.Config` (a dataclass instance: `OmegaConf.to_object`).
    The backend must be initialised by the caller (`sgdr.backend.init`).
    """

    t_start = time.time()
    validate(cfg)  # every config value, before any work
    seq_root = ensure_sequence(cfg)
    t_sequence = time.time() - t_start  # generation when the sequence was missing
    seq = load_sequence(seq_root, scene_file=cfg.scene_file)
    seq.check_images(progress)  # every image decodes, before any work
    name = default_run_name(cfg)
    run_dir = Path(run_dir) if run_dir is not None else Path(cfg.recon.output_dir) / name
    seq_hash = sequence_digest(seq_root)
    if cfg.scene_file:  # the scene is part of the data: another scene file redoes the stages
        seq_hash = key_hash({"sequence": seq_hash, "scene_file": file_hash(Path(cfg.scene_file))})
    claim_run_dir(run_dir, seq_root, seq_hash, cfg.scene_file)
    with RunTracker(
        run_dir,
        cfg,
        cfg.tracking,
        run_name=name,
        sections=tracked_sections(cfg, sequence_written_since(seq_root, t_start)),
        exclude=("recon.simulate",),
        volatile=tuple(f"recon.{k}" for k in RECON_NEVER_IN_KEYS),
        log_file="reconstruct.log",
    ) as tracker:
        out = _run_stages(cfg, seq, seq_hash, run_dir, tracker, progress)
        metrics = run_metrics(cfg, seq_root, out.stages, t_sequence, t_start)
        dyn = out.stages["dynamics"].value
        for i, loss in enumerate(dyn["pass_losses"]):
            tracker.log_metrics({"dynamic_pass_loss": loss}, step=i)
        tracker.finish(metrics)
        tracker.log_artifact(run_dir / "report", "report")
        if (run_dir / "asset").is_dir():
            tracker.log_artifact(run_dir / "asset", "asset")
        out.metrics = metrics
    return out


def run_metrics(cfg, seq_root: Path, stages: dict[str, StageResult], t_sequence: float, t_start: float) -> dict:
    """What metrics.json holds: the evaluate stage's scores, the run's identity, the dynamic
    losses, the identified parameters and the timings; strict JSON (a value that is not a
    finite number is null, with the reason in `missing`)."""

    scores = dict(stages["evaluate"].value)
    missing = dict(scores.pop("missing", {}))
    dyn = stages["dynamics"].value
    passes = dyn["pass_losses"]
    if not passes:
        for key in ("dynamic_loss_first_pass", "dynamic_loss_last_pass"):
            missing[key] = (
                "no dynamic pass ran: the global search's values are the asset (recon.field_prior_strengths = [.inf])"
                if (dyn.get("field_prior") or {}).get("chosen") == "inf"
                else "no dynamic pass ran (recon.iterations = 0)"
            )
    metrics = {
        **scores,
        "sequence_name": sequence_name(cfg),
        "preset": cfg.preset,
        "seed": cfg.seed,
        "sequence": str(seq_root),
        "dynamic_loss_first_pass": passes[0] if passes else None,
        "dynamic_loss_last_pass": passes[-1] if passes else None,
        "dynamic_eval_loss_initial": dyn["eval_loss_initial"],
        "dynamic_eval_loss_final": dyn["eval_loss_final"],
        "method": cfg.method,
        "model": cfg.recon.model,
        "identified": MODELS.get_named(cfg.recon.model).identified(stages),
        "momentum": stages["predict"].value.momentum if "predict" in stages else None,
        "stages_skipped": [n for n, r in stages.items() if r.skipped],
        "stage_seconds": {"sequence": t_sequence, **{n: r.seconds for n, r in stages.items()}},
        "minutes": (time.time() - t_start) / 60.0,
    }
    metrics = strict_json(metrics, missing)
    metrics["missing"] = missing
    return metrics


class RunInterrupted(Exception):
    """Ctrl-C during a run; the message says what was saved and how to resume."""


def _run_stages(cfg, seq, seq_hash: str, run_dir: Path, tracker, progress: bool) -> RunOutputs:
    """Run the model's stages in order through the stage runner (skip, copy from a sibling run,
    resume or redo each stage)."""
    donors = sibling_runs(run_dir, seq_hash) if cfg.recon.share_stages else []
    runner = StageRunner(run_dir, force=cfg.recon.force, donors=donors)
    ctx = RunContext(cfg, seq, tracker, progress)
    stages: dict[str, StageResult] = {}
    pipeline = model_stages(cfg)
    st = pipeline[0]
    try:
        for st in pipeline:
            key = dict(stage_sections(cfg, st.name, pipeline))
            if st.seeded:
                key["seed"] = cfg.seed
            if st.reads_sequence:
                key["sequence"] = seq_hash
            key["input"] = [stages[n].digest for n in st.needs]
            if st.extra_key is not None:
                key.update(st.extra_key(ctx))
            stages[st.name] = runner.run(st.name, key, partial(st.produce, ctx), partial(st.load, ctx))
            ctx.values[st.name] = stages[st.name].value
    except KeyboardInterrupt:
        raise RunInterrupted(interrupted_message(run_dir, st.name, list(stages))) from None
    except Exception as exc:
        if not caused_by_interrupt(exc):
            raise
        raise RunInterrupted(interrupted_message(run_dir, st.name, list(stages))) from None
    return RunOutputs(run_dir, {}, stages)


def caused_by_interrupt(exc: BaseException) -> bool:
    """True when Ctrl-C is somewhere in the chain of `exc`: Dr.Jit re-raises an interrupt inside
    a custom op as a RuntimeError caused by it."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, KeyboardInterrupt):
            return True
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return False


def interrupted_message(run_dir: Path, stage: str, done: list[str]) -> str:
    """One line: where the run stopped, what is saved, how to resume."""

    saved = f"stages {', '.join(done)} are complete" if done else "no stage was complete"
    ckpt = Checkpoint(run_dir / stage / CHECKPOINT_DIR, "")
    if ckpt.path.is_file():
        with contextlib.suppress(Exception), np.load(ckpt.path, allow_pickle=False) as z:
            saved += f", stage {stage} is saved up to step {int(z['__step__'])}"  # unreadable: not reported
    return f"interrupted during stage {stage}: {saved} (in {run_dir}); run the same command again to resume from there"
