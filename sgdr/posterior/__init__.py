"""Posterior over the physical parameters of a finished reconstruction (issue 14). Runs on a
finished run (`experiments/posterior.py`), not as a pipeline stage.

- `batched`: S parameter samples of one asset simulated in one Dr.Jit program (S x N_A
  anchors sharing the spring topology, per-sample parameters), forward only, with a per-sample
  stability mask; and the Gaussian centres those anchor tracks imply (`batched_centres`). The
  sampler evaluates its walkers' likelihoods through it, S at a time.
- `twin`: twin sequences, an asset simulated by its own model with a known truth and rendered
  (the truth is in the model class: calibration).
"""
