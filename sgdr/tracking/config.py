"""Typed config schema of experiment tracking (group key `tracking`)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class TrackingConfig:
    enabled: bool = True  # log to MLflow
    uri: str = "sqlite:///mlflow.db"  # SQLite store by default; an http:// URI for a server
    experiment: str = "sgdr"  # MLflow experiment name
