"""The CUDA backend: a short rollout and its gradient on `cuda` against the same on `llvm`.

One process uses one backend (`sgdr.backend.init`), and the test session runs on LLVM, so
each backend runs the same script in a child process. Skipped where Dr.Jit finds no CUDA
device (`sgdr.backend.cuda_available`).
"""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from sgdr import backend

ROOT = Path(__file__).resolve().parent.parent

# 96 anchors falling onto the ground (contact included), 6 frames of 40 substeps, full
# gradients through the hand-written adjoint; prints the last anchor positions and d loss /
# d log10 k_i as JSON.
SCRIPT = r"""
import json, sys
import numpy as np
import drjit as dr
import sgdr.backend
sgdr.backend.init(sys.argv[1])
from sgdr.arrays import array3_to_points, to_numpy
from sgdr.physics import Ground, PhysicsConfig, PhysParams, SimState, build_spring_model, rollout

x_rest = np.random.default_rng(0).uniform(0.3, 0.5, (96, 3))
cfg = PhysicsConfig(n_c=8, contact="coulomb", restitution_init=0.3, friction_init=0.4)
model = build_spring_model(x_rest, 16, cfg)
params = PhysParams.init(model, cfg, v0=(0.2, 0.0, -1.0))
dr.enable_grad(params.log10_k)
states = rollout(model, params, SimState.at_rest(model, params.v0), Ground([0, 0, 0.25], [0, 0, 1]), 6, 1 / 30, cfg,
                 grad_mode="full", n_substeps=40)
loss = 0.0
for s in states[1:]:
    loss = loss + dr.sum(dr.squared_norm(s.x))
dr.backward(loss)
print(json.dumps({"x": array3_to_points(states[-1].x).tolist(), "grad": to_numpy(dr.grad(params.log10_k)).tolist()}))
"""


def _run(name: str) -> dict:
    done = subprocess.run(
        [sys.executable, "-c", SCRIPT, name], cwd=ROOT, capture_output=True, text=True, timeout=600, check=False
    )
    assert done.returncode == 0, done.stderr[-2000:]
    return json.loads(done.stdout.strip().splitlines()[-1])


@pytest.mark.gpu
@pytest.mark.skipif(not backend.cuda_available(), reason="Dr.Jit finds no CUDA device")
def test_rollout_and_gradient_on_cuda_match_llvm():
    cuda, llvm = _run("cuda"), _run("llvm")
    x_cuda, x_llvm = np.asarray(cuda["x"]), np.asarray(llvm["x"])
    assert np.all(np.isfinite(x_cuda)) and x_cuda.shape == (96, 3)
    # float32 on both; the two compilers may fuse multiply-adds differently (rounding only)
    np.testing.assert_allclose(x_cuda, x_llvm, atol=1e-4)
    g_cuda, g_llvm = np.asarray(cuda["grad"]), np.asarray(llvm["grad"])
    assert np.abs(g_llvm).max() > 0
    np.testing.assert_allclose(g_cuda, g_llvm, rtol=1e-3, atol=1e-3 * np.abs(g_llvm).max())
