"""Experiment tracking: MLflow (SQLite store by default) plus config and metrics.json."""

from sgdr.tracking.tracker import RunTracker, ensure_store, flatten_config, git_provenance, repo_root, resolve_uri

__all__ = ["RunTracker", "ensure_store", "flatten_config", "git_provenance", "repo_root", "resolve_uri"]
