"""Posterior of an identified asset's physics (issue 14): how far to trust a reconstruction.

`likelihood` (silhouette likelihood, noise scale, tempering), `rollouts` (the per-sample
rollout contract, a loop of single rollouts), `sample` (emcee ensembles, convergence
diagnostics), `predictive` (posterior predictive bands and the report section).
"""
