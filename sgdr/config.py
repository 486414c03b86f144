"""The top-level typed config schema, assembled from each stage's own schema.

Hydra composes `conf/config.yaml` (defaults: this schema, then the `preset` group (scale), the
`method` group (method), then overrides) and validates it against `Config`. `register()` puts
the schema in Hydra's ConfigStore; entry points call it before `@hydra.main` runs (see
`experiments/`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from sgdr.anchors import config as anchors_config
from sgdr.anchors.config import AnchorConfig
from sgdr.asset import config as simulate_config
from sgdr.baselines import config as baseline_config
from sgdr.baselines.config import BaselineConfig
from sgdr.checks import ConfigError, any_text, choice, non_empty_text, non_negative, section_problems
from sgdr.discrepancy import config as diagnose_config
from sgdr.discrepancy.config import DiagnoseConfig
from sgdr.identify import config as recon_config
from sgdr.identify.config import ReconConfig
from sgdr.physics import config as physics_config
from sgdr.physics.config import PhysicsConfig
from sgdr.posterior import config as posterior_config
from sgdr.posterior.config import PosteriorConfig
from sgdr.render import config as render_config
from sgdr.render.config import RenderConfig
from sgdr.static_fit import config as static_fit_config
from sgdr.static_fit.config import StaticFitConfig
from sgdr.synth import capture_config as realcap_config
from sgdr.synth import config as synth_config
from sgdr.synth.capture_config import RealCaptureSimConfig
from sgdr.synth.config import SynthConfig
from sgdr.tracking import config as tracking_config
from sgdr.tracking.config import TrackingConfig


@dataclass
class Config:
    preset: str = "small"  # scale preset name: tiny | small | paper (set by the preset group)
    method: str = "spring_gaus"  # method name: spring_gaus | official (set by the method group)
    backend: str = "llvm"  # "llvm" (CPU) | "cuda" (GPU)
    threads: int = 0  # Dr.Jit thread-pool size; 0 = all cores
    seed: int = 0  # seeds sampling, initialisation and camera choice
    data_dir: str = "data"  # where generated sequences live (relative to the repo root)
    sequence: str = ""  # path of the sequence to reconstruct ("" = data_dir/<synth.object>)
    # the scene of a foreign-layout sequence (sgdr_scene.json form, official Spring-Gaus .yaml or PAC-NeRF .py
    # config); "" = the folder's sgdr_scene.json (a real capture: the one *.yaml in its folder)
    scene_file: str = ""
    physics: PhysicsConfig = field(default_factory=PhysicsConfig)
    anchors: AnchorConfig = field(default_factory=AnchorConfig)
    render: RenderConfig = field(default_factory=RenderConfig)
    static_fit: StaticFitConfig = field(default_factory=StaticFitConfig)
    synth: SynthConfig = field(default_factory=SynthConfig)
    recon: ReconConfig = field(default_factory=ReconConfig)
    tracking: TrackingConfig = field(default_factory=TrackingConfig)
    posterior: PosteriorConfig = field(default_factory=PosteriorConfig)  # experiments/posterior.py
    diagnose: DiagnoseConfig = field(default_factory=DiagnoseConfig)  # experiments/diagnose.py
    realcap: RealCaptureSimConfig = field(default_factory=RealCaptureSimConfig)  # experiments/simulate_capture.py
    baseline: BaselineConfig = field(default_factory=BaselineConfig)  # the paper's baselines (recon.model)


# ---------------------------------------------------------------------------- checks
# Allowed values: the top-level fields here, each section's in its own module (`CHECKS`), the
# nested sections by their dotted path. `validate` applies every one of them.
CHECKS = {
    "preset": any_text("the preset's name, set by the preset group"),
    "method": any_text("the method's name, set by the method group"),
    "backend": choice("sgdr.backend:_VARIANTS"),
    "threads": non_negative("0: every core"),
    "seed": non_negative(),
    "data_dir": non_empty_text(),
    "sequence": any_text("a sequence folder; empty: <data_dir>/<synth.object>"),
    "scene_file": any_text("a scene file for a foreign layout; empty: the folder's own"),
}
SECTION_CHECKS = {
    "physics": physics_config.CHECKS,
    "anchors": anchors_config.CHECKS,
    "render": render_config.CHECKS,
    "static_fit": static_fit_config.CHECKS,
    "synth": synth_config.CHECKS,
    "synth.effects": synth_config.EFFECTS_CHECKS,
    "recon": recon_config.CHECKS,
    "recon.simulate": simulate_config.SIMULATE_CHECKS,
    "recon.search": recon_config.SEARCH_CHECKS,
    "tracking": tracking_config.CHECKS,
    "posterior": posterior_config.CHECKS,
    "diagnose": diagnose_config.CHECKS,
    "posterior.priors": posterior_config.PRIOR_CHECKS,
    "posterior.surrogate": posterior_config.SURROGATE_CHECKS,
    "posterior.surrogate.design_search": posterior_config.DESIGN_SEARCH_CHECKS,
    "realcap": realcap_config.CHECKS,
    "baseline": baseline_config.CHECKS,
    "baseline.pacnerf": baseline_config.PACNERF_CHECKS,
    "baseline.dyngaus": baseline_config.DYNGAUS_CHECKS,
    "baseline.deform4d": baseline_config.DEFORM4D_CHECKS,
}


def _in_k_bounds(cfg) -> str | None:
    r = cfg.recon
    outside = [v for v in [cfg.physics.log10_k_init, *r.log10_k_grid] if not r.log10_k_min <= v <= r.log10_k_max]
    if outside:
        return (
            f"physics.log10_k_init / recon.log10_k_grid hold {outside}, outside [recon.log10_k_min, "
            f"recon.log10_k_max] = [{r.log10_k_min}, {r.log10_k_max}]"
        )
    return None


def _search_ranges(cfg) -> str | None:
    s = cfg.recon.search
    bad = [n for n in s.parameters if not float(getattr(s, f"{n}_range")[0]) < float(getattr(s, f"{n}_range")[1])]
    if bad:
        return "; ".join(
            f"recon.search.{n}_range={list(getattr(s, f'{n}_range'))} must be [low, high], low < high" for n in bad
        )
    k = list(s.log10_k_range)
    if "log10_k" in s.parameters and not (cfg.recon.log10_k_min <= k[0] and k[1] <= cfg.recon.log10_k_max):
        return (
            f"recon.search.log10_k_range={k} must lie within [recon.log10_k_min, recon.log10_k_max] = "
            f"[{cfg.recon.log10_k_min}, {cfg.recon.log10_k_max}]"
        )
    return None


# Rules between fields: each returns None or the error line (naming every key involved).
RULES = (
    _search_ranges,
    lambda c: (
        None
        if c.anchors.n_k < c.anchors.n_anchors
        else f"anchors.n_k={c.anchors.n_k} must be < anchors.n_anchors={c.anchors.n_anchors} (springs to other anchors)"
    ),
    lambda c: (
        None
        if c.anchors.n_b <= c.anchors.n_anchors
        else f"anchors.n_b={c.anchors.n_b} must be <= anchors.n_anchors={c.anchors.n_anchors}"
    ),
    lambda c: (
        None
        if c.physics.max_substeps >= c.physics.n_substeps
        else f"physics.max_substeps={c.physics.max_substeps} must be >= physics.n_substeps={c.physics.n_substeps}"
    ),
    lambda c: (
        None
        if c.recon.log10_k_min < c.recon.log10_k_max
        else f"recon.log10_k_min={c.recon.log10_k_min} must be < recon.log10_k_max={c.recon.log10_k_max}"
    ),
    _in_k_bounds,
    lambda c: (
        None
        if c.render.tile_size % c.render.pixels_per_thread == 0
        else f"render.pixels_per_thread={c.render.pixels_per_thread} must divide render.tile_size={c.render.tile_size}"
    ),
    lambda c: (
        None
        if c.render.alpha_min < c.render.alpha_max
        else f"render.alpha_min={c.render.alpha_min} must be < render.alpha_max={c.render.alpha_max}"
    ),
    lambda c: (
        None
        if c.synth.n_fit < c.synth.n_frames
        else f"synth.n_fit={c.synth.n_fit} must be < synth.n_frames={c.synth.n_frames} (the rest is the future)"
    ),
    lambda c: (
        None
        if c.synth.hit_frame < c.synth.n_frames
        else f"synth.hit_frame={c.synth.hit_frame} must be < synth.n_frames={c.synth.n_frames}"
    ),
    lambda c: posterior_config.rule_problem(c.posterior),
    lambda c: realcap_config.rule_problem(c.realcap),
)


def validate(cfg, section_checks: dict = SECTION_CHECKS) -> None:
    """Check every config value (`CHECKS`, `SECTION_CHECKS`) and the rules between them (`RULES`)
    before any work; raise one `ConfigError` listing every problem, each naming its key.

    cfg: the composed config (a `Config` instance or a DictConfig).
    section_checks: the sections' checks (default sgdr's; a schema extending `Config` passes its own).
    """
    problems = section_problems("", cfg, CHECKS)
    for path, checks in section_checks.items():
        section = cfg
        for part in path.split("."):
            section = getattr(section, part)
        problems += section_problems(path, section, checks)
    if not problems:  # the rules compare values that each passed their own check
        problems = [p for rule in RULES if (p := rule(cfg))]
    if problems:
        lines = "\n".join(f"  {p}" for p in problems)
        s = "s" if len(problems) > 1 else ""
        raise ConfigError(
            f"{len(problems)} config value{s} cannot work (fix them on the command line or in conf/):\n{lines}"
        )


def register() -> None:
    """Store the schema as `config_schema` in Hydra's ConfigStore (idempotent)."""
    from hydra.core.config_store import ConfigStore

    ConfigStore.instance().store(name="config_schema", node=Config)


def compose(overrides: list[str] | None = None):
    """Compose the config outside `@hydra.main` (tests, notebooks): returns a DictConfig."""

    from hydra import compose as hydra_compose
    from hydra import initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra

    register()
    conf_dir = Path(__file__).resolve().parent.parent / "conf"
    if GlobalHydra.instance().is_initialized():
        GlobalHydra.instance().clear()
    with initialize_config_dir(config_dir=str(conf_dir), version_base="1.3"):
        return hydra_compose(config_name="config", overrides=list(overrides or []))
