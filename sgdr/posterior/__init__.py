"""Posterior over an identified asset's physical parameters (issue 14): how far to trust a
reconstruction. Runs on a finished reconstruction (`experiments/posterior.py`), not as a
pipeline stage.

- `batched`: S parameter samples of one asset in one Dr.Jit program (S x N_A anchors sharing
  the spring topology, per-sample parameters), forward only, with a per-sample stability mask;
- `rollouts`: the per-sample rollout contract the sampler calls (batched, or a loop of single
  rollouts as the reference);
- `likelihood`: the silhouette likelihood, its noise scale and tempering;
- `sample`: emcee ensembles and the convergence verdict;
- `predictive`: posterior predictive bands, plots and the report section;
- `run`: the whole computation; `twin`: twin sequences for calibration (the truth in the model class).
"""
