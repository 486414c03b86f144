"""Posterior over an identified asset's physical parameters (issue 14): how far to trust a
reconstruction. `likelihood` (silhouette likelihood, noise scale, tempering), `rollouts` (the
per-sample rollout contract as a loop of single rollouts; `batched` is the batched one),
`sample` (emcee ensembles and the convergence verdict), `predictive` (posterior predictive
bands, plots and the report section), `run` (the whole computation), and twin sequences for
calibration (`twin`). Runs on a finished reconstruction (`experiments/posterior.py`); not a
pipeline stage."""
