"""One run's record: `config.yaml` and `metrics.json` in its output folder, plus MLflow.

The output folder always gets the composed config (`config.yaml`) and the final scores
(`metrics.json`), whether or not MLflow is enabled, so a run can be read without any server.
MLflow (`TrackingConfig.enabled`) gets the flattened config as parameters, metrics (with a
step for curves) and artifacts. The default store is a local SQLite file
(`sqlite:///mlflow.db`); a relative SQLite path is resolved against the current directory
and its artifacts go to `mlartifacts/` beside the database. Any other URI (`http://...`) is
passed to MLflow unchanged.

Create the SQLite store once before a parallel sweep (`ensure_store`), so concurrent jobs do
not race on its schema migration.
"""

from __future__ import annotations

import json
import logging
import math
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from sgdr.tracking.config import TrackingConfig

log = logging.getLogger(__name__)

_MLFLOW_PARAM_MAX = 6000  # MLflow's limit on one parameter value's length


def flatten_config(cfg: Any, prefix: str = "") -> dict[str, Any]:
    """Nested mappings (dicts, DictConfigs, dataclasses) -> {"a.b.c": leaf}; lists stay leaves."""
    from dataclasses import asdict, is_dataclass

    if is_dataclass(cfg) and not isinstance(cfg, type):
        cfg = asdict(cfg)
    from omegaconf import DictConfig, ListConfig, OmegaConf  # OmegaConf containers -> plain Python

    if isinstance(cfg, (DictConfig, ListConfig)):
        cfg = OmegaConf.to_container(cfg, resolve=True)
    out: dict[str, Any] = {}
    if isinstance(cfg, Mapping):
        for key, value in cfg.items():
            name = f"{prefix}.{key}" if prefix else str(key)
            if isinstance(value, Mapping) or (hasattr(value, "__dataclass_fields__")):
                out.update(flatten_config(value, name))
            else:
                out[name] = value
    else:
        out[prefix or "value"] = cfg
    return out


def _to_plain(cfg: Any) -> Any:
    from dataclasses import asdict, is_dataclass

    if is_dataclass(cfg) and not isinstance(cfg, type):
        return asdict(cfg)
    from omegaconf import DictConfig, ListConfig, OmegaConf

    if isinstance(cfg, (DictConfig, ListConfig)):
        return OmegaConf.to_container(cfg, resolve=True)
    return cfg


def resolve_uri(uri: str, base: Path | None = None) -> str:
    """Make a relative `sqlite:///file.db` absolute (against `base` or the cwd)."""
    prefix = "sqlite:///"
    if uri.startswith(prefix):
        path = Path(uri[len(prefix) :])
        if not path.is_absolute():
            path = (base or Path.cwd()) / path
        return prefix + str(path.resolve())
    return uri


def ensure_store(tracking: TrackingConfig, base: Path | None = None) -> str | None:
    """Create the SQLite database and the experiment if missing; return the experiment id.

    Call once before launching parallel jobs. Returns None when tracking is disabled.
    """
    if not tracking.enabled:
        return None
    from mlflow.tracking import MlflowClient

    uri = resolve_uri(tracking.uri, base)
    client = MlflowClient(tracking_uri=uri)
    exp = client.get_experiment_by_name(tracking.experiment)
    if exp is not None:
        return exp.experiment_id
    artifact_location = None
    if uri.startswith("sqlite:///"):
        db = Path(uri[len("sqlite:///") :])
        artifact_location = (db.parent / "mlartifacts").as_uri()
    return client.create_experiment(tracking.experiment, artifact_location=artifact_location)


class RunTracker:
    """Records one run. Use as a context manager:

        with RunTracker(out_dir, cfg, cfg.tracking, run_name="torus") as run:
            run.log_metrics({"loss": 0.1}, step=3)
            run.log_artifact(out_dir / "video.mp4")
            run.finish({"future_cd": 1.2})   # writes metrics.json, logs final metrics

    out_dir: the run's output folder (created). cfg: the composed config (DictConfig,
    dataclass or dict); written to `out_dir/config.yaml` on entry.
    """

    def __init__(self, out_dir, cfg: Any, tracking: TrackingConfig, run_name: str = "run"):
        self.out_dir = Path(out_dir)
        self.cfg = cfg
        self.tracking = tracking
        self.run_name = run_name
        self.run_id: str | None = None
        self.tracking_uri: str | None = None
        self._client = None
        self._metrics: dict[str, float] = {}

    # ------------------------------------------------------------------ lifecycle
    def __enter__(self) -> RunTracker:
        import yaml

        self.out_dir.mkdir(parents=True, exist_ok=True)
        (self.out_dir / "config.yaml").write_text(yaml.safe_dump(_to_plain(self.cfg), sort_keys=False))
        if self.tracking.enabled:
            from mlflow.tracking import MlflowClient

            self.tracking_uri = resolve_uri(self.tracking.uri)
            exp_id = ensure_store(self.tracking)
            self._client = MlflowClient(tracking_uri=self.tracking_uri)
            run = self._client.create_run(exp_id, run_name=self.run_name)
            self.run_id = run.info.run_id
            self._log_params(flatten_config(self.cfg))
            self._client.log_artifact(self.run_id, str(self.out_dir / "config.yaml"))
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if self._client is not None and self.run_id is not None:
            self._client.set_terminated(self.run_id, status="FAILED" if exc_type else "FINISHED")
        return None

    # ------------------------------------------------------------------ logging
    def _log_params(self, params: dict[str, Any]) -> None:
        from mlflow.entities import Param

        items = [Param(k, str(v)[:_MLFLOW_PARAM_MAX]) for k, v in params.items()]
        for i in range(0, len(items), 100):  # MLflow's batch limit on parameters
            self._client.log_batch(self.run_id, params=items[i : i + 100])

    def log_metrics(self, metrics: Mapping[str, float], step: int | None = None) -> None:
        """Log scalar metrics (non-finite values are kept in metrics.json but not sent)."""
        values = {k: float(v) for k, v in metrics.items()}
        self._metrics.update(values)
        if self._client is None:
            return
        from mlflow.entities import Metric

        now = int(time.time() * 1000)
        batch = [Metric(k, v, now, step or 0) for k, v in values.items() if math.isfinite(v)]
        for i in range(0, len(batch), 1000):
            self._client.log_batch(self.run_id, metrics=batch[i : i + 1000])

    def log_artifact(self, path, artifact_path: str | None = None) -> None:
        """Attach a file or a folder of the run's outputs to the MLflow run."""
        if self._client is None:
            return
        path = Path(path)
        if path.is_dir():
            self._client.log_artifacts(self.run_id, str(path), artifact_path)
        else:
            self._client.log_artifact(self.run_id, str(path), artifact_path)

    def finish(self, metrics: Mapping[str, Any]) -> Path:
        """Write `metrics.json` (all of `metrics`, nested allowed) and log its scalar leaves."""
        path = self.out_dir / "metrics.json"
        path.write_text(json.dumps(metrics, indent=2, sort_keys=True, default=float))
        scalars = {
            k: v
            for k, v in flatten_config(dict(metrics)).items()
            if isinstance(v, (int, float)) and not isinstance(v, bool)
        }
        self.log_metrics(scalars)
        self.log_artifact(path)
        return path
