"""Run tracking: config.yaml and metrics.json always; MLflow in a temporary SQLite store."""

import json
from dataclasses import dataclass, field

import yaml

from sgdr.tracking.config import TrackingConfig
from sgdr.tracking.tracker import RunTracker, flatten_config, resolve_uri


@dataclass
class _Inner:
    lr: float = 0.01
    schedule: list = field(default_factory=lambda: [100, 150])


@dataclass
class _Cfg:
    seed: int = 3
    recon: _Inner = field(default_factory=_Inner)


def test_flatten_config_dotted_keys():
    flat = flatten_config(_Cfg())
    assert flat == {"seed": 3, "recon.lr": 0.01, "recon.schedule": [100, 150]}


def test_relative_sqlite_uri_is_made_absolute(tmp_path):
    assert resolve_uri("sqlite:///x/mlflow.db", tmp_path) == f"sqlite:///{tmp_path}/x/mlflow.db"
    assert resolve_uri("http://host:5000") == "http://host:5000"


def test_files_without_mlflow(tmp_path):
    out = tmp_path / "run"
    with RunTracker(out, _Cfg(), TrackingConfig(enabled=False)) as run:
        run.log_metrics({"loss": 0.5}, step=1)
        run.finish({"future_cd": 1.25, "per_frame": {"cd": [1.0, 2.0]}})
    assert yaml.safe_load((out / "config.yaml").read_text())["recon"]["schedule"] == [100, 150]
    assert json.loads((out / "metrics.json").read_text())["per_frame"]["cd"] == [1.0, 2.0]


def test_mlflow_sqlite_run_records_params_metrics_artifacts(tmp_path):
    from mlflow.tracking import MlflowClient

    db = tmp_path / "store" / "mlflow.db"
    db.parent.mkdir()
    tracking = TrackingConfig(enabled=True, uri=f"sqlite:///{db}", experiment="test")
    out = tmp_path / "run"
    with RunTracker(out, _Cfg(), tracking, run_name="torus") as run:
        for step, loss in enumerate([0.3, 0.2, 0.1]):
            run.log_metrics({"loss": loss}, step=step)
        (out / "plot.txt").write_text("x")
        run.log_artifact(out / "plot.txt")
        run.finish({"future_cd": 1.25, "nested": {"psnr": 30.0}})
    client = MlflowClient(tracking_uri=f"sqlite:///{db}")
    r = client.get_run(run.run_id)
    assert r.info.status == "FINISHED"
    assert r.data.params["recon.lr"] == "0.01" and r.data.params["seed"] == "3"
    assert r.data.metrics["future_cd"] == 1.25 and r.data.metrics["nested.psnr"] == 30.0
    assert [m.value for m in client.get_metric_history(run.run_id, "loss")] == [0.3, 0.2, 0.1]
    names = {a.path for a in client.list_artifacts(run.run_id)}
    assert {"config.yaml", "metrics.json", "plot.txt"} <= names
    assert (db.parent / "mlartifacts").is_dir()
