"""Resumable pipeline stages: each writes into its own folder and is trusted only when complete.

A stage is a function `produce(out_dir: Path, ckpt: Checkpoint) -> None` that writes its
files into `out_dir`, plus a `load(out_dir: Path) -> T` that reads them back. `StageRunner`
runs it in `run_dir/<name>/` under these rules:

- **Completion marker, written last.** After `produce` returns, the runner hashes every file
  it wrote (SHA-256) and writes `DONE.json` atomically (temp file + rename) with the stage's
  *key* (its whole config sections and the digests of its inputs, as JSON), the key's hash and
  the file hashes. A stage that crashed, or was killed mid-write, has no marker.
- **Keys are portable.** A key holds config values, seeds and content digests, never paths
  or times, serialised as JSON with sorted keys (floats by their shortest repr): a run folder
  copied to another machine resumes there. When a key differs, the log line names the
  changed entries (`recon.iterations: 20 -> 30`).
- **Skip only what verifies.** A rerun skips the stage when the marker parses, its key hash
  equals the current one, every listed file exists with the recorded hash, and `load`
  succeeds. Anything else (missing marker, other config or inputs, a truncated, edited or
  unreadable file) is logged, the stage's outputs are deleted and the stage is redone; a bad
  output is never silently used. `force=True` redoes every stage.
- **Chained invalidation.** Each completed stage has a `digest` (its key hash and file
  hashes); downstream stages put their inputs' digests into their key, so redoing a stage
  with a different result redoes everything after it.
- **Checkpoints.** A long stage saves `ckpt.save(step, arrays)` every few steps into
  `out_dir/checkpoint/` (atomic .npz with the key hash inside); a rerun after a crash calls
  `ckpt.load()` and resumes from the last step. A checkpoint of another key, or one that
  cannot be read, is ignored (the stage starts over) and reported. Checkpoints are deleted
  when the stage completes, and they are never part of the stage's outputs.
"""

from __future__ import annotations

import json
import logging
import os
import shutil
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Generic, TypeVar

import numpy as np

from sgdr.digest import file_hash, key_hash, plain

log = logging.getLogger(__name__)

T = TypeVar("T")

MARKER = "DONE.json"
CHECKPOINT_DIR = "checkpoint"


def _flatten(x: Any, prefix: str = "") -> dict[str, Any]:
    """{"a.b.c": leaf} of a nested JSON-able value (lists are leaves)."""
    if isinstance(x, Mapping) and x:
        out: dict[str, Any] = {}
        for k, v in x.items():
            out.update(_flatten(v, f"{prefix}.{k}" if prefix else str(k)))
        return out
    return {prefix: x}


def changed_entries(old: Any, new: Any, limit: int = 6) -> str:
    """The entries of two stage keys that differ, as `name: old -> new`, comma separated."""
    a, b = (
        _flatten(json.loads(json.dumps(plain(old), default=str))),
        _flatten(json.loads(json.dumps(plain(new), default=str))),
    )
    names = sorted(k for k in a.keys() | b.keys() if a.get(k, "<absent>") != b.get(k, "<absent>"))

    def show(v) -> str:
        text = json.dumps(v) if v != "<absent>" else v
        return text if len(text) <= 40 else text[:16] + "..." + text[-8:]

    parts = [f"{k}: {show(a.get(k, '<absent>'))} -> {show(b.get(k, '<absent>'))}" for k in names[:limit]]
    return ", ".join(parts) + (f" and {len(names) - limit} more" if len(names) > limit else "")


def _atomic_write_text(path: Path, text: str) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text)
    os.replace(tmp, path)


class StageError(RuntimeError):
    """A stage's output is unusable right after it was produced (its `load` fails)."""


# ---------------------------------------------------------------------------- checkpoints
class Checkpoint:
    """Step checkpoints of one stage: `save(step, arrays)`, `load() -> (step, arrays) | None`.

    arrays: {name: np.ndarray}; saved as one .npz (written to a temp file, then renamed) with
    the stage's key hash, so a checkpoint from another config is never resumed.
    """

    def __init__(self, folder: Path, key: str):
        self.folder = Path(folder)
        self.key = key
        self.path = self.folder / "last.npz"

    def save(self, step: int, arrays: Mapping[str, np.ndarray]) -> None:
        self.folder.mkdir(parents=True, exist_ok=True)
        tmp = self.folder / "last.tmp.npz"
        np.savez(
            tmp, __step__=np.int64(step), __key__=np.array(self.key), **{k: np.asarray(v) for k, v in arrays.items()}
        )
        os.replace(tmp, self.path)

    def load(self) -> tuple[int, dict[str, np.ndarray]] | None:
        if not self.path.exists():
            return None
        try:
            with np.load(self.path, allow_pickle=False) as z:
                if str(z["__key__"]) != self.key:
                    log.warning("checkpoint %s belongs to another config; starting over", self.path)
                    return None
                step = int(z["__step__"])
                arrays = {k: z[k] for k in z.files if k not in ("__step__", "__key__")}
        except Exception as exc:  # noqa: BLE001 - any unreadable checkpoint means: start over
            log.warning("checkpoint %s is unreadable (%s); starting over", self.path, exc)
            return None
        log.info("resuming from checkpoint %s at step %d", self.path, step)
        return step, arrays

    def clear(self) -> None:
        shutil.rmtree(self.folder, ignore_errors=True)


# ---------------------------------------------------------------------------- stages
@dataclass
class StageResult(Generic[T]):
    name: str
    value: T  # what the stage's `load` returned
    digest: str  # key hash + file hashes; put it into downstream keys
    out_dir: Path
    skipped: bool  # True when a verified earlier output was reused
    seconds: float = 0.0  # wall time of this call (verifying, or producing and hashing)


class StageRunner:
    """Runs stages in `run_dir/<name>/`, skipping verified completed ones (see module doc)."""

    def __init__(self, run_dir, force: bool = False, donors=()):
        """donors: other run folders whose completed stage of the same name and the same key is
        copied instead of recomputed (verified there first, then here); see `run`."""
        self.run_dir = Path(run_dir)
        self.force = bool(force)
        self.donors = [Path(d) for d in donors if Path(d).resolve() != self.run_dir.resolve()]
        self.run_dir.mkdir(parents=True, exist_ok=True)

    def _from_donor(self, name: str, out_dir: Path, key: Any, khash: str, load: Callable[[Path], T]):
        """Copy stage `name` from the first donor where it verifies with this key; the result of
        verifying the copy here, or None."""
        for donor in self.donors:
            src = donor / name
            if not (src / MARKER).is_file():
                continue
            ok, _, _, _ = self._verify(src, key, khash, load)
            if not ok:
                continue
            self._clear_outputs(out_dir, keep_checkpoint=False)
            shutil.copytree(src, out_dir, dirs_exist_ok=True, ignore=shutil.ignore_patterns(CHECKPOINT_DIR))
            ok, _, value, digest = self._verify(out_dir, key, khash, load)
            if ok:
                log.info("stage %s: the same stage (same key) copied from %s", name, donor)
                return value, digest
        return None

    def stage_dir(self, name: str) -> Path:
        return self.run_dir / name

    def _verify(self, out_dir: Path, key: Any, khash: str, load: Callable[[Path], T]) -> tuple[bool, str, Any, str]:
        """(ok, reason, loaded value, digest) of an existing output folder."""
        marker = out_dir / MARKER
        if not marker.exists():
            return False, "no completion marker (never run, or interrupted)", None, ""
        try:
            meta = json.loads(marker.read_text())
            files = dict(meta["files"])
            recorded_key = str(meta["key_hash"])
            digest = str(meta["digest"])
        except Exception as exc:  # noqa: BLE001
            return False, f"unreadable marker ({exc})", None, ""
        if recorded_key != khash:
            if "key" not in meta:
                return False, "config or inputs changed (the marker predates recorded keys)", None, ""
            return False, f"config or inputs changed: {changed_entries(meta['key'], key)}", None, ""
        for rel, h in files.items():
            p = out_dir / rel
            if not p.is_file():
                return False, f"output {rel} is missing", None, ""
            if file_hash(p) != h:
                return False, f"output {rel} does not match its recorded hash (corrupt or edited)", None, ""
        try:
            value = load(out_dir)
        except Exception as exc:  # noqa: BLE001
            return False, f"outputs cannot be loaded ({type(exc).__name__}: {exc})", None, ""
        return True, "", value, digest

    def run(
        self,
        name: str,
        key: Any,
        produce: Callable[[Path, Checkpoint], None],
        load: Callable[[Path], T],
    ) -> StageResult[T]:
        """Run (or reuse) stage `name`.

        key: JSON-able description of everything the result depends on (config section,
          upstream digests, seeds). produce(out_dir, ckpt) writes the outputs; load(out_dir)
          reads them back (and must raise on anything malformed).
        """
        t0 = time.perf_counter()
        out_dir = self.stage_dir(name)
        khash = key_hash(key)
        if not self.force:
            reason = ""
            if out_dir.exists():
                ok, reason, value, digest = self._verify(out_dir, key, khash, load)
                if ok:
                    log.info("stage %s: complete and verified, skipped", name)
                    return StageResult(name, value, digest, out_dir, skipped=True, seconds=time.perf_counter() - t0)
            shared = self._from_donor(name, out_dir, key, khash, load) if self.donors else None
            if shared is not None:
                return StageResult(name, *shared, out_dir, skipped=True, seconds=time.perf_counter() - t0)
            if reason:
                log.warning("stage %s: redoing it, %s", name, reason)
        else:
            log.info("stage %s: force=true, redoing it", name)
        self._clear_outputs(out_dir, keep_checkpoint=not self.force)
        out_dir.mkdir(parents=True, exist_ok=True)
        ckpt = Checkpoint(out_dir / CHECKPOINT_DIR, khash)
        produce(out_dir, ckpt)
        ckpt.clear()
        files = {
            str(p.relative_to(out_dir)): file_hash(p)
            for p in sorted(out_dir.rglob("*"))
            if p.is_file() and p.name != MARKER
        }
        digest = key_hash({"key": khash, "files": files})
        try:
            value = load(out_dir)
        except Exception as exc:
            raise StageError(f"stage {name}: its fresh outputs in {out_dir} cannot be loaded: {exc}") from exc
        marker = {"key_hash": khash, "digest": digest, "files": files, "key": plain(key)}
        _atomic_write_text(out_dir / MARKER, json.dumps(marker, indent=1, default=str))
        seconds = time.perf_counter() - t0
        log.info("stage %s: done in %.1f s", name, seconds)
        return StageResult(name, value, digest, out_dir, skipped=False, seconds=seconds)

    @staticmethod
    def _clear_outputs(out_dir: Path, keep_checkpoint: bool) -> None:
        if not out_dir.exists():
            return
        for p in out_dir.iterdir():
            if keep_checkpoint and p.name == CHECKPOINT_DIR:
                continue
            if p.is_dir():
                shutil.rmtree(p)
            else:
                p.unlink()
