"""Benchmarks, tables and reports (run from the repo root: `python -m evaluation.bench`)."""
