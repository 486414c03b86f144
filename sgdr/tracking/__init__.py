"""Experiment tracking: MLflow (SQLite store by default) plus config and metrics.json."""
