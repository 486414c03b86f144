"""Experiment tracking: MLflow (SQLite store by default) plus config and metrics.json."""

from sgdr.tracking.tracker import RunTracker, ensure_store, flatten_config, resolve_uri

__all__ = ["RunTracker", "ensure_store", "flatten_config", "resolve_uri"]
