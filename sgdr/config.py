"""The top-level typed config schema, assembled from each stage's own schema.

Hydra composes `conf/config.yaml` (defaults: this schema, then the `preset` group (scale), the
`method` group (method), then overrides) and validates it against `Config`. `register()` puts
the schema in Hydra's ConfigStore; entry points call it before `@hydra.main` runs (see
`experiments/`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from sgdr.anchors.config import AnchorConfig
from sgdr.physics.config import PhysicsConfig
from sgdr.pipeline.config import ReconConfig
from sgdr.render.config import RenderConfig
from sgdr.static_fit.config import StaticFitConfig
from sgdr.studies.config import OracleConfig
from sgdr.synth.config import SynthConfig
from sgdr.tracking.config import TrackingConfig


@dataclass
class Config:
    preset: str = "tiny"  # scale preset name: tiny | small | paper (set by the preset group)
    method: str = "spring_gaus"  # method name: spring_gaus | official (set by the method group)
    backend: str = "llvm"  # "llvm" (CPU) | "cuda" (GPU)
    threads: int = 0  # Dr.Jit thread-pool size; 0 = all cores
    seed: int = 0  # seeds sampling, initialisation and camera choice
    data_dir: str = "data"  # where generated sequences live (relative to the repo root)
    sequence: str = ""  # path of the sequence to reconstruct ("" = data_dir/<synth.object>)
    physics: PhysicsConfig = field(default_factory=PhysicsConfig)
    anchors: AnchorConfig = field(default_factory=AnchorConfig)
    render: RenderConfig = field(default_factory=RenderConfig)
    static_fit: StaticFitConfig = field(default_factory=StaticFitConfig)
    synth: SynthConfig = field(default_factory=SynthConfig)
    recon: ReconConfig = field(default_factory=ReconConfig)
    oracle: OracleConfig = field(default_factory=OracleConfig)  # experiments/oracle.py (sgdr.studies.oracle)
    tracking: TrackingConfig = field(default_factory=TrackingConfig)


def register() -> None:
    """Store the schema as `config_schema` in Hydra's ConfigStore (idempotent)."""
    from hydra.core.config_store import ConfigStore

    ConfigStore.instance().store(name="config_schema", node=Config)


def compose(overrides: list[str] | None = None):
    """Compose the config outside `@hydra.main` (tests, notebooks): returns a DictConfig."""
    from pathlib import Path

    from hydra import compose as hydra_compose
    from hydra import initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra

    register()
    conf_dir = Path(__file__).resolve().parent.parent / "conf"
    if GlobalHydra.instance().is_initialized():
        GlobalHydra.instance().clear()
    with initialize_config_dir(config_dir=str(conf_dir), version_base="1.3"):
        return hydra_compose(config_name="config", overrides=list(overrides or []))
