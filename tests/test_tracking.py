"""Run tracking: config.yaml and metrics.json always; MLflow in a temporary SQLite store."""

import json
from dataclasses import dataclass, field

import yaml

from sgdr.tracking.config import TrackingConfig
from sgdr.tracking.tracker import RunTracker, flatten_config, git_provenance, repo_root, resolve_uri


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


# ---------------------------------------------------------------- one run per folder, status, log


def _store(tmp_path, experiment="test"):
    db = tmp_path / "store" / "mlflow.db"
    db.parent.mkdir(exist_ok=True)
    return TrackingConfig(enabled=True, uri=f"sqlite:///{db}", experiment=experiment), f"sqlite:///{db}"


def _fake_stages(run, n=3):
    """A stand-in for the pipeline: a few 'stages' that log and record a metric."""
    import logging

    for i in range(n):
        logging.getLogger("sgdr.fake").warning("stage %d done", i)
        run.log_metrics({"stage_loss": 1.0 / (i + 1)}, step=i)


def test_one_mlflow_run_across_resumes_with_the_log_in_the_run_folder(tmp_path):
    from mlflow.tracking import MlflowClient

    tracking, uri = _store(tmp_path)
    out = tmp_path / "run"
    ids = []
    for _ in range(2):
        with RunTracker(out, _Cfg(), tracking, run_name="torus", log_file="reconstruct.log") as run:
            _fake_stages(run)
            run.finish({"future_cd": 1.25})
        ids.append(run.run_id)
    assert ids[0] == ids[1] and run.resumed
    client = MlflowClient(tracking_uri=uri)
    r = client.get_run(ids[0])
    assert r.info.status == "FINISHED"
    assert len(client.search_runs([r.info.experiment_id])) == 1
    state = json.loads((out / "mlflow_run.json").read_text())
    assert state["run_id"] == ids[0] and state["tracking_uri"] == uri and state["experiment"] == "test"
    assert [i["status"] for i in state["invocations"]] == ["FINISHED", "FINISHED"]
    text = (out / "reconstruct.log").read_text()
    assert text.count("==== ") == 2 and text.count("stage 2 done") == 2
    assert "reconstruct.log" in {a.path for a in client.list_artifacts(ids[0])}
    # the handler is gone after the run: later records do not reach the file
    import logging

    logging.getLogger("sgdr.fake").warning("after the run")
    assert "after the run" not in (out / "reconstruct.log").read_text()


def test_commit_is_a_tag_and_in_metrics(tmp_path, monkeypatch):
    import subprocess

    from mlflow.tracking import MlflowClient

    tracking, uri = _store(tmp_path)
    with RunTracker(tmp_path / "run", _Cfg(), tracking) as run:
        run.finish({"x": 1.0})
    tags = MlflowClient(tracking_uri=uri).get_run(run.run_id).data.tags
    head = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True, cwd=repo_root())
    expected = head.stdout.strip() if head.returncode == 0 else "unknown"
    assert tags["mlflow.source.git.commit"] == expected
    assert tags["sgdr.git.dirty"] in ("true", "false", "none")
    prov = json.loads((tmp_path / "run" / "metrics.json").read_text())["provenance"]
    assert prov["git_commit"] == expected and prov["mlflow_run_id"] == run.run_id
    # resumed on other code: the tag follows, the list keeps both
    import sgdr.tracking.tracker as tracker_module

    monkeypatch.setattr(tracker_module, "git_provenance", lambda *a: {"git_commit": "0" * 40, "git_dirty": False})
    with RunTracker(tmp_path / "run", _Cfg(), tracking) as again:
        pass
    tags = MlflowClient(tracking_uri=uri).get_run(again.run_id).data.tags
    assert again.run_id == run.run_id and tags["mlflow.source.git.commit"] == "0" * 40
    assert tags["sgdr.git.commits"] == f"{expected},{'0' * 40}"


def test_commit_unknown_without_git(tmp_path, monkeypatch):
    import subprocess

    assert git_provenance(tmp_path) == {"git_commit": "unknown", "git_dirty": None}  # not a repository

    def no_git(*args, **kwargs):
        raise FileNotFoundError("git")

    monkeypatch.setattr(subprocess, "run", no_git)
    assert git_provenance() == {"git_commit": "unknown", "git_dirty": None}


def test_ctrl_c_ends_killed_an_exception_failed(tmp_path):
    import pytest
    from mlflow.tracking import MlflowClient

    tracking, uri = _store(tmp_path)
    client = MlflowClient(tracking_uri=uri)
    with pytest.raises(KeyboardInterrupt):
        with RunTracker(tmp_path / "a", _Cfg(), tracking) as run:
            raise KeyboardInterrupt
    assert client.get_run(run.run_id).info.status == "KILLED"
    with pytest.raises(RuntimeError):
        with RunTracker(tmp_path / "b", _Cfg(), tracking) as failed:
            raise RuntimeError("boom")
    assert client.get_run(failed.run_id).info.status == "FAILED"
    # Ctrl-C inside a Dr.Jit custom op reaches us wrapped in a RuntimeError: still KILLED
    with pytest.raises(RuntimeError):
        with RunTracker(tmp_path / "c", _Cfg(), tracking, log_file="reconstruct.log") as wrapped:
            try:
                raise KeyboardInterrupt
            except KeyboardInterrupt as exc:
                raise RuntimeError("drjit.custom(...): error while performing a custom operation") from exc
    assert client.get_run(wrapped.run_id).info.status == "KILLED"
    # the pipeline turns Ctrl-C into RunInterrupted "from None" (one line for the user): still KILLED
    from sgdr.pipeline.run import RunInterrupted

    with pytest.raises(RunInterrupted):
        with RunTracker(tmp_path / "d", _Cfg(), tracking) as converted:
            try:
                raise KeyboardInterrupt
            except KeyboardInterrupt:
                raise RunInterrupted("interrupted during stage dynamics") from None
    assert client.get_run(converted.run_id).info.status == "KILLED"
    assert "KeyboardInterrupt" in (tmp_path / "c" / "reconstruct.log").read_text()  # the traceback, in the log
    # the interrupted run is resumed as the same run, RUNNING while it goes, FINISHED after
    with RunTracker(tmp_path / "a", _Cfg(), tracking) as again:
        assert client.get_run(again.run_id).info.status == "RUNNING"
    assert again.run_id == run.run_id and client.get_run(run.run_id).info.status == "FINISHED"
    statuses = [i["status"] for i in json.loads((tmp_path / "a" / "mlflow_run.json").read_text())["invocations"]]
    assert statuses == ["KILLED", "FINISHED"]


def test_new_run_when_the_store_lost_it_or_an_acting_setting_changed(tmp_path, caplog):
    from dataclasses import replace

    from mlflow.tracking import MlflowClient

    tracking, uri = _store(tmp_path)
    client = MlflowClient(tracking_uri=uri)
    out = tmp_path / "run"
    with RunTracker(out, _Cfg(), tracking, volatile={"seed"}) as first:
        pass
    # a volatile setting may change: same run, the change recorded as a tag
    with RunTracker(out, replace(_Cfg(), seed=4), tracking, volatile={"seed"}) as same:
        pass
    assert same.run_id == first.run_id
    assert client.get_run(first.run_id).data.tags["sgdr.resume_changes"] == "seed: 3 -> 4"
    # an acting one cannot (MLflow parameters are immutable): a new run, linked both ways
    with caplog.at_level("WARNING", logger="sgdr.tracking.tracker"):
        with RunTracker(out, _Cfg(recon=_Inner(lr=0.02)), tracking) as changed:
            pass
    assert changed.run_id != first.run_id and "recon.lr: 0.01 -> 0.02" in caplog.text
    assert client.get_run(changed.run_id).data.tags["sgdr.resumed_from"] == first.run_id
    assert client.get_run(first.run_id).data.tags["sgdr.continued_in"] == changed.run_id
    # the store lost the run: a new one, and the log says so
    client.delete_run(changed.run_id)
    caplog.clear()
    with caplog.at_level("WARNING", logger="sgdr.tracking.tracker"):
        with RunTracker(out, _Cfg(recon=_Inner(lr=0.02)), tracking) as fresh:
            pass
    assert fresh.run_id not in (first.run_id, changed.run_id) and "deleted" in caplog.text
    state = json.loads((out / "mlflow_run.json").read_text())
    assert state["run_id"] == fresh.run_id and state["earlier_run_ids"] == [first.run_id, changed.run_id]


def test_relative_store_resolves_against_the_repository_root(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert resolve_uri("sqlite:///mlflow.db") == f"sqlite:///{repo_root() / 'mlflow.db'}"
    assert (repo_root() / "conf" / "config.yaml").exists()


def test_reconstruction_logs_only_the_settings_that_act(tmp_path):
    """Params: the stages' sections and the run settings, never oracle.*, recon.simulate.*,
    tracking.*; synth only when the run generated its sequence (else synth.object)."""
    from omegaconf import OmegaConf

    from sgdr.config import compose
    from sgdr.pipeline.run import RECON_NEVER_IN_KEYS, tracked_sections

    cfg = OmegaConf.to_object(compose(["preset=tiny"]))
    tracking, _ = _store(tmp_path)
    for generated in (False, True):
        tracker = RunTracker(
            tmp_path / "run",
            cfg,
            tracking,
            sections=tracked_sections(cfg, generated),
            exclude=("recon.simulate",),
            volatile=[f"recon.{k}" for k in RECON_NEVER_IN_KEYS],
        )
        keys = set(tracker.params)
        assert not any(k.startswith(("oracle.", "recon.simulate.", "tracking.", "threads")) for k in keys)
        assert {"seed", "preset", "method", "backend", "sequence", "recon.iterations", "physics.springs"} <= keys
        assert {"anchors.n_anchors", "static_fit.iterations", "render.tile_size"} <= keys
        synth = {k for k in keys if k.startswith("synth.")}
        if generated:  # the generator's settings made the data
            assert {"synth.object", "synth.n_views", "synth.resolution"} <= synth
        else:  # the default-located sequence: its object names the data, nothing else of synth acted
            assert synth == {"synth.object"}
    cfg.sequence = "/some/sequence"
    assert not any(
        k.startswith("synth") for k in RunTracker(tmp_path, cfg, tracking, sections=tracked_sections(cfg, False)).params
    )


def _store_in_a_process(uri: str, start, out) -> None:
    from sgdr.tracking.tracker import ensure_store

    start.wait()  # every process past its imports, then all at once
    try:
        out.put(("ok", ensure_store(TrackingConfig(enabled=True, uri=uri, experiment="sgdr"))))
    except Exception as exc:  # noqa: BLE001 - the parent asserts on what each process met
        out.put(("error", repr(exc)))


def test_jobs_started_together_on_a_fresh_store_all_get_its_experiment(tmp_path):
    """Two reconstructions started at once on a new SQLite store: one of them used to fail
    creating the schema the other was creating ("table alembic_version already exists")."""
    import multiprocessing as mp

    import mlflow.tracking  # noqa: F401 - imported before the fork, so the processes start at once

    ctx = mp.get_context("fork")
    start, out = ctx.Barrier(4), ctx.Queue()
    uri = f"sqlite:///{tmp_path / 'store' / 'mlflow.db'}"
    procs = [ctx.Process(target=_store_in_a_process, args=(uri, start, out)) for _ in range(4)]
    for p in procs:
        p.start()
    results = [out.get(timeout=120) for _ in procs]
    for p in procs:
        p.join(timeout=60)
    assert all(kind == "ok" for kind, _ in results), results
    assert len({value for _, value in results}) == 1, results
