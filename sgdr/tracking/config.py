"""Typed config schema of experiment tracking (group key `tracking`)."""

from __future__ import annotations

from dataclasses import dataclass

from sgdr.checks import non_empty_text


@dataclass
class TrackingConfig:
    enabled: bool = True  # log to MLflow
    uri: str = "sqlite:///mlflow.db"  # SQLite store by default, a relative path resolved against the
    #                                   repository root (not the current directory): one store for every
    #                                   driver wherever it runs; an absolute path or an http:// URI as given
    experiment: str = "sgdr"  # MLflow experiment name


# Allowed values, checked before any work (sgdr.checks).
CHECKS = {"uri": non_empty_text(), "experiment": non_empty_text()}
