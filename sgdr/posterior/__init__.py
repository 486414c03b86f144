"""Posterior over an identified asset's physical parameters (issue 14): batched rollouts, the
likelihood, the emcee sampler and its diagnostics, and twin sequences for calibration
(`twin`). Runs on a finished reconstruction (`experiments/posterior.py`); not a pipeline stage."""
