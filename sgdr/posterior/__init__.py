"""Posterior over the physical parameters of a finished reconstruction (issue 14).

- `batched`: S parameter samples of one asset simulated in one Dr.Jit program (S x N_A
  anchors sharing the spring topology, per-sample parameters), forward only, with a per-sample
  stability mask; and the Gaussian centres those anchor tracks imply (`batched_centres`). The
  sampler evaluates its walkers' likelihoods through it, S at a time.
"""

from sgdr.posterior.batched import (
    SAMPLE_FIELDS,
    BatchedRollout,
    batched_centres,
    batched_rollout,
    replicate_model,
)

__all__ = ["SAMPLE_FIELDS", "BatchedRollout", "batched_centres", "batched_rollout", "replicate_model"]
