"""One run's record: `config.yaml`, `metrics.json`, the log and one MLflow run per run folder.

The output folder always gets the composed config (`config.yaml`) and the final scores
(`metrics.json`, with the git commit under `provenance`), whether or not MLflow is enabled, so
a run can be read without any server. With `log_file`, everything logged during the run is
appended to `<out_dir>/<log_file>` (e.g. `reconstruct.log`), one header line per invocation
(time, command-line overrides, git commit).

MLflow (`TrackingConfig.enabled`) gets the config sections the caller names as parameters
(only the settings that act on the run), metrics (with a step for curves), artifacts, and the
git commit as the tag `mlflow.source.git.commit` (plus `sgdr.git.dirty`; "unknown" without git
or .git; a resume on another commit sets the tag to the latest and lists all in `sgdr.git.commits`). One run folder is one MLflow run across resumes: its id is kept in
`<out_dir>/mlflow_run.json` and the run is reopened (RUNNING again, then FINISHED) by the next
invocation on the same folder. A new run is started instead, and the log says why, when the
store no longer has that run, the store or experiment changed, or a setting that acts on the
results changed (MLflow parameters cannot change): the new run carries the tag
`sgdr.resumed_from` (the old run, `sgdr.continued_in`). Settings the caller calls `volatile`
(they change no output, e.g. recon.force) may change on a resume; the change goes to the tag
`sgdr.resume_changes`. A run ends FINISHED, FAILED on an exception, KILLED on Ctrl-C
(KeyboardInterrupt). Metrics logged again by a resume (re-read stages) appear twice in their
history, at the same steps.

The store: the default is a local SQLite file (`sqlite:///mlflow.db`). A relative SQLite path
is resolved against the repository root (the folder holding `conf/`, `repo_root`), not the
current directory, so every driver run from anywhere uses one store; without a repository
(an installed package) it falls back to the current directory. The artifacts go to
`mlartifacts/` beside the database. Any other URI (`http://...`) is passed to MLflow unchanged.
The absolute store is logged on entry.

Jobs started together on a fresh SQLite store (two reconstructions at once) create it one at a
time: `ensure_store` holds an exclusive lock on `<database>.lock` beside it while it creates
the schema and the experiment (without it the second job failed on "table alembic_version
already exists").
"""

from __future__ import annotations

import datetime
import json
import logging
import math
import subprocess
import sys
import time
from collections.abc import Mapping
from dataclasses import asdict, is_dataclass
from pathlib import Path
from typing import Any

import yaml
from omegaconf import DictConfig, ListConfig, OmegaConf

from sgdr.tracking.config import TrackingConfig

log = logging.getLogger(__name__)

_MLFLOW_PARAM_MAX = 6000  # MLflow's limit on one parameter value's length


def flatten_config(cfg: Any, prefix: str = "") -> dict[str, Any]:
    """Nested mappings (dicts, DictConfigs, dataclasses) -> {"a.b.c": leaf}; lists stay leaves."""

    if is_dataclass(cfg) and not isinstance(cfg, type):
        cfg = asdict(cfg)

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
    if is_dataclass(cfg) and not isinstance(cfg, type):
        return asdict(cfg)

    if isinstance(cfg, (DictConfig, ListConfig)):
        return OmegaConf.to_container(cfg, resolve=True)
    return cfg


def repo_root() -> Path | None:
    """The repository this package runs from (the folder holding `conf/` and `sgdr/`), or None
    for an installed package without one."""
    root = Path(__file__).resolve().parents[2]
    return root if (root / "conf").is_dir() else None


def resolve_uri(uri: str, base: Path | None = None) -> str:
    """Make a relative `sqlite:///file.db` absolute: against `base`, else the repository root
    (`repo_root`), else the current directory. Other URIs are returned unchanged."""
    prefix = "sqlite:///"
    if uri.startswith(prefix):
        path = Path(uri[len(prefix) :])
        if not path.is_absolute():
            path = (base or repo_root() or Path.cwd()) / path
        return prefix + str(path.resolve())
    return uri


def git_provenance(root: Path | None = None) -> dict:
    """{"git_commit": HEAD's sha or "unknown", "git_dirty": tracked files modified (None when
    unknown)} of the repository at `root` (default `repo_root()`); "unknown" without git, without
    .git (a tarball) or outside a repository, never an error."""
    root = root or repo_root() or Path(__file__).resolve().parents[2]

    def git(*args):
        return subprocess.run(["git", "-C", str(root), *args], capture_output=True, text=True, timeout=20)

    try:
        head = git("rev-parse", "HEAD")
        if head.returncode != 0:
            return {"git_commit": "unknown", "git_dirty": None}
        status = git("status", "--porcelain", "--untracked-files=no")
        dirty = bool(status.stdout.strip()) if status.returncode == 0 else None
        return {"git_commit": head.stdout.strip(), "git_dirty": dirty}
    except (OSError, subprocess.SubprocessError):
        return {"git_commit": "unknown", "git_dirty": None}


def command_line() -> str:
    """The invocation's overrides (Hydra's, when under @hydra.main), else sys.argv."""
    try:
        from hydra.core.hydra_config import HydraConfig

        if HydraConfig.initialized():
            return f"{Path(sys.argv[0]).name} " + " ".join(HydraConfig.get().overrides.task)
    except (ImportError, ValueError):
        pass
    return " ".join([Path(sys.argv[0]).name, *sys.argv[1:]]) if sys.argv else ""


def select_params(flat: Mapping[str, Any], sections=None, exclude=()) -> dict[str, Any]:
    """The entries of a flattened config under the dotted prefixes `sections` (None = all),
    without those under `exclude` (e.g. "recon.simulate")."""

    def under(key, prefixes):
        return any(key == p or key.startswith(p + ".") for p in prefixes)

    return {k: v for k, v in flat.items() if (sections is None or under(k, sections)) and not under(k, tuple(exclude))}


def ensure_store(tracking: TrackingConfig, base: Path | None = None) -> str | None:
    """Create the SQLite database and the experiment if missing; return the experiment id.
    Safe to call from jobs started together (an SQLite store is created under a file lock).
    Returns None when tracking is disabled.
    """
    if not tracking.enabled:
        return None
    import contextlib
    import fcntl

    from mlflow.tracking import MlflowClient

    uri = resolve_uri(tracking.uri, base)
    db = Path(uri[len("sqlite:///") :]) if uri.startswith("sqlite:///") else None
    with contextlib.ExitStack() as stack:
        if db is not None:
            db.parent.mkdir(parents=True, exist_ok=True)
            lock = stack.enter_context(open(db.with_name(db.name + ".lock"), "a"))
            fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes
        client = MlflowClient(tracking_uri=uri)
        exp = client.get_experiment_by_name(tracking.experiment)
        if exp is not None:
            return exp.experiment_id
        artifact_location = (db.parent / "mlartifacts").as_uri() if db is not None else None
        return client.create_experiment(tracking.experiment, artifact_location=artifact_location)


def _interrupted(exc: BaseException | None) -> bool:
    """Was the run stopped rather than broken: a KeyboardInterrupt (Ctrl-C) or SystemExit, also
    when wrapped in another exception: a Dr.Jit custom op turns one into a RuntimeError, the
    pipeline into `RunInterrupted` (raised `from None`, which hides the interrupt from the
    traceback but keeps it as `__context__`)."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, (KeyboardInterrupt, SystemExit)):
            return True
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return False


class RunTracker:
    """Records one run. Use as a context manager:

        with RunTracker(out_dir, cfg, cfg.tracking, run_name="torus", sections=("recon", "seed"),
                        log_file="reconstruct.log") as run:
            run.log_metrics({"loss": 0.1}, step=3)
            run.log_artifact(out_dir / "video.mp4")
            run.finish({"future_cd": 1.2})   # writes metrics.json, logs final metrics

    out_dir: the run's output folder (created). cfg: the composed config (DictConfig,
    dataclass or dict); written to `out_dir/config.yaml` on entry. sections: the dotted config
    prefixes logged as MLflow parameters (None = the whole config), minus `exclude`; volatile:
    parameters that may change on a resume of the same run (they change no output). log_file:
    a file name in out_dir that gets the run's log (appended), logged as an artifact on exit.
    """

    STATE_FILE = "mlflow_run.json"

    def __init__(
        self,
        out_dir,
        cfg: Any,
        tracking: TrackingConfig,
        run_name: str = "run",
        sections=None,
        exclude=(),
        volatile=(),
        log_file: str | None = None,
    ):
        self.out_dir = Path(out_dir)
        self.cfg = cfg
        self.tracking = tracking
        self.run_name = run_name
        self.sections = None if sections is None else tuple(sections)
        self.exclude = tuple(exclude)
        self.volatile = set(volatile)
        self.log_file = self.out_dir / log_file if log_file else None
        self.run_id: str | None = None
        self.tracking_uri: str | None = None
        self.provenance: dict = {}
        self.resumed = False  # the MLflow run of an earlier invocation was reopened
        self._client = None
        self._handler: logging.Handler | None = None
        self._started = ""
        self._state_doc: dict = {}
        self._metrics: dict[str, float] = {}

    @property
    def params(self) -> dict[str, Any]:
        """The parameters this run logs (the selected sections of the config)."""
        return select_params(flatten_config(self.cfg), self.sections, self.exclude)

    # ------------------------------------------------------------------ lifecycle
    def __enter__(self) -> RunTracker:
        self.out_dir.mkdir(parents=True, exist_ok=True)
        (self.out_dir / "config.yaml").write_text(yaml.safe_dump(_to_plain(self.cfg), sort_keys=False))
        self.provenance = git_provenance()
        self._started = datetime.datetime.now().astimezone().isoformat(timespec="seconds")
        if self.log_file is not None:
            self._open_log()
        if self.tracking.enabled:
            try:
                self._start_mlflow()
            except BaseException:
                self._close_log()
                raise
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            status = "FINISHED"
        elif _interrupted(exc):  # Ctrl-C (possibly wrapped, e.g. by a Dr.Jit custom op), SystemExit
            status = "KILLED"
        else:
            status = "FAILED"
        if self._handler is not None and exc_type is not None:  # the traceback into the log file only
            self._handler.handle(
                log.makeRecord(log.name, logging.ERROR, __file__, 0, "run %s", (status,), (exc_type, exc, tb))
            )
        if self._client is not None and self.run_id is not None:
            log.info("MLflow run %s (%s): %s", self.run_id, self.tracking_uri, status)
        self._close_log()
        if self._client is not None and self.run_id is not None:
            try:
                if self.log_file is not None and self.log_file.exists():
                    self._client.log_artifact(self.run_id, str(self.log_file))
                self._client.set_terminated(self.run_id, status=status)
                self._record_invocation(status)
            except Exception as err:  # never hide the run's own exception behind a tracking one
                if exc_type is None:
                    raise
                log.error("could not close MLflow run %s: %s", self.run_id, err)
        return None

    def _open_log(self) -> None:
        """Append the run's log to log_file, after a header line for this invocation."""
        prov = self.provenance
        dirty = " (uncommitted changes)" if prov.get("git_dirty") else ""
        with self.log_file.open("a") as f:
            f.write(f"==== {self._started} | {command_line()} | commit {prov.get('git_commit')}{dirty}\n")
        handler = logging.FileHandler(self.log_file, mode="a")
        handler.setFormatter(logging.Formatter("[%(asctime)s][%(name)s][%(levelname)s] - %(message)s"))
        logging.getLogger().addHandler(handler)
        self._handler = handler

    def _close_log(self) -> None:
        if self._handler is not None:
            logging.getLogger().removeHandler(self._handler)
            self._handler.close()
            self._handler = None

    def _state(self) -> dict:
        path = self.out_dir / self.STATE_FILE
        if not path.exists():
            return {}
        try:
            return json.loads(path.read_text())
        except json.JSONDecodeError:
            log.warning("%s is not valid JSON: starting a new MLflow run", path)
            return {}

    def _start_mlflow(self) -> None:
        """Reopen the run recorded in mlflow_run.json, or create one (saying why)."""
        from mlflow.exceptions import MlflowException
        from mlflow.tracking import MlflowClient

        self.tracking_uri = resolve_uri(self.tracking.uri)
        log.info("MLflow store: %s (experiment %s)", self.tracking_uri, self.tracking.experiment)
        exp_id = ensure_store(self.tracking)
        self._client = MlflowClient(tracking_uri=self.tracking_uri)
        params = {k: str(v)[:_MLFLOW_PARAM_MAX] for k, v in self.params.items()}
        state = self._state()
        previous, why_new = state.get("run_id"), None
        tags = {"mlflow.source.git.commit": self.provenance["git_commit"]}
        tags["sgdr.git.dirty"] = str(self.provenance["git_dirty"]).lower()
        if previous:
            old = None
            if state.get("tracking_uri") != self.tracking_uri or state.get("experiment_id") != exp_id:
                why_new = (
                    f"the store or experiment changed (was {state.get('tracking_uri')}, {state.get('experiment')})"
                )
            else:
                try:
                    old = self._client.get_run(previous)
                except MlflowException:
                    why_new = f"the store {self.tracking_uri} no longer has it"
                if old is not None and old.info.lifecycle_stage != "active":
                    why_new, old = "it was deleted from the store", None
            if old is not None:
                changed = {
                    k: (old.data.params[k], v)
                    for k, v in params.items()
                    if k in old.data.params and old.data.params[k] != v
                }
                acting = sorted(set(changed) - self.volatile)
                if acting:
                    shown = ", ".join(f"{k}: {changed[k][0]} -> {changed[k][1]}" for k in acting[:5])
                    why_new = f"settings that act on the results changed ({shown}{', ...' if len(acting) > 5 else ''})"
                else:
                    self.run_id, self.resumed = previous, True
                    self._client.update_run(previous, status="RUNNING")
                    params = {k: v for k, v in params.items() if k not in old.data.params}
                    commits = old.data.tags.get("sgdr.git.commits") or old.data.tags.get("mlflow.source.git.commit")
                    if commits and self.provenance["git_commit"] not in commits.split(","):
                        # resumed on other code: the tag is the latest commit, this lists them all
                        tags["sgdr.git.commits"] = f"{commits},{self.provenance['git_commit']}"
                    if changed:
                        tags["sgdr.resume_changes"] = "; ".join(f"{k}: {a} -> {b}" for k, (a, b) in changed.items())
                    log.info("MLflow run %s reopened (resuming %s)", previous, self.out_dir)
        if self.run_id is None:
            run = self._client.create_run(exp_id, run_name=self.run_name)
            self.run_id = run.info.run_id
            if previous:
                tags["sgdr.resumed_from"] = previous
                log.warning("new MLflow run %s for %s, not %s: %s", self.run_id, self.out_dir, previous, why_new)
                if why_new.startswith("settings"):
                    self._client.set_tag(previous, "sgdr.continued_in", self.run_id)
        for key, value in tags.items():
            self._client.set_tag(self.run_id, key, value)
        self._log_params(params)
        self._client.log_artifact(self.run_id, str(self.out_dir / "config.yaml"))
        self._write_state(exp_id, previous if previous != self.run_id else None, state)

    def _write_state(self, exp_id: str, replaced: str | None, state: dict) -> None:
        earlier = list(state.get("earlier_run_ids", []))
        if replaced and replaced not in earlier:
            earlier.append(replaced)
        self._state_doc = {
            "run_id": self.run_id,
            "tracking_uri": self.tracking_uri,
            "experiment": self.tracking.experiment,
            "experiment_id": exp_id,
            "earlier_run_ids": earlier,
            "invocations": list(state.get("invocations", [])),
        }
        self._save_state()

    def _record_invocation(self, status: str) -> None:
        self._state_doc["invocations"].append(
            {
                "started": self._started,
                "ended": datetime.datetime.now().astimezone().isoformat(timespec="seconds"),
                "status": status,
                "run_id": self.run_id,
                "command": command_line(),
                **self.provenance,
            }
        )
        self._save_state()

    def _save_state(self) -> None:
        path = self.out_dir / self.STATE_FILE
        tmp = path.with_suffix(".json.tmp")
        tmp.write_text(json.dumps(self._state_doc, indent=1))
        tmp.replace(path)

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
        """Write `metrics.json` (all of `metrics`, nested allowed, plus `provenance`: git commit,
        dirty tree, MLflow run) and log its scalar leaves."""
        path = self.out_dir / "metrics.json"
        provenance = {**self.provenance, "mlflow_run_id": self.run_id, "mlflow_tracking_uri": self.tracking_uri}
        metrics = {**metrics, "provenance": provenance}
        path.write_text(json.dumps(metrics, indent=2, sort_keys=True, default=float))
        scalars = {
            k: v
            for k, v in flatten_config(dict(metrics)).items()
            if isinstance(v, (int, float)) and not isinstance(v, bool)
        }
        self.log_metrics(scalars)
        self.log_artifact(path)
        return path
