"""The memory cost of differentiating a rollout, as documented in sgdr/physics/simulate.py:
per anchor and substep, both adjoints keep the substep's x, v and the evaluated spring force f
(36 bytes; 36-40 measured on LLVM) and nothing per spring, so the tape grows linearly in frames x substeps x N_A,
independent of n_k."""

import gc
import re

import drjit as dr
import numpy as np
import pytest

from sgdr.physics import Ground, PhysicsConfig, PhysParams, SimState, build_spring_model, rollout
from tests.physics_variants import ADJOINT_NAMES

UNITS = {"B": 1, "KiB": 2**10, "MiB": 2**20, "GiB": 2**30}


def _llvm_bytes_in_use() -> float:
    """Bytes held by Dr.Jit's LLVM allocator (from `dr.whos`)."""
    m = re.search(r"LLVM\s*:\s*([\d.]+)\s*(\w+)/", dr.whos(True))
    assert m, "dr.whos() no longer reports the LLVM allocator"
    return float(m.group(1)) * UNITS[m.group(2)]


BUDGET = 48  # bytes per anchor and substep: x, v, f (36 B) with allocator slack


@pytest.mark.parametrize("adjoint", ADJOINT_NAMES)
@pytest.mark.parametrize("mode", ["full", "truncated"])
def test_tape_memory_is_the_substep_states_only(mode, adjoint):
    rng = np.random.default_rng(0)
    n, n_frames = 512, 2
    x_rest = rng.uniform(0.3, 0.7, (n, 3))
    ground = Ground([0.0, 0.0, 0.28], [0.0, 0.0, 1.0])
    grown = {}
    for n_k in (16, 48):
        cfg = PhysicsConfig(n_c=8, adjoint=adjoint)
        model = build_spring_model(x_rest, n_k, cfg)
        for n_sub in (5, 15):
            params = PhysParams.init(model, cfg, v0=(0.1, 0.0, -1.0))
            dr.enable_grad(params)
            gc.collect()
            before = _llvm_bytes_in_use()
            states = rollout(
                model,
                params,
                SimState.at_rest(model, params.v0),
                ground,
                n_frames + 1,
                1 / 30,
                cfg,
                grad_mode=mode,
                n_substeps=n_sub,
            )
            grown[n_k, n_sub] = _llvm_bytes_in_use() - before
            loss = 0.0
            for s in states[1:]:
                loss = loss + dr.sum(dr.squared_norm(s.x))
            dr.backward(loss)
            assert np.abs(dr.grad(params.log10_k).numpy()).max() > 0
            del states, loss, params
    # marginal bytes per anchor and substep: x, v and f (36 B), a little slack for the
    # allocator; a tape that kept per-spring
    # intermediates would need >= 4 n_k B (192 at n_k = 48)
    per_substep = {n_k: (grown[n_k, 15] - grown[n_k, 5]) / (10 * n_frames * n) for n_k in (16, 48)}
    assert all(8 <= b <= BUDGET for b in per_substep.values()), per_substep
    assert abs(per_substep[48] - per_substep[16]) < 2.0  # independent of n_k
