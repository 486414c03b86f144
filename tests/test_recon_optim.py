"""Adam checkpoints resume exactly: save after 3 steps, restore into a fresh optimiser, and
the next 4 steps match an uninterrupted run (values and moments)."""

import drjit as dr
import numpy as np

from sgdr.backend import ad
from sgdr.identify.adam import adam_from_numpy, adam_to_numpy, make_adam


def _fresh():
    t = ad()
    return make_adam({"x": (t.Array3f([0.0, 0.5], [0.0, 0.1], [0.0, 0.0]), 0.1), "k": (t.Float([0.0, 1.0, 2.0]), 0.5)})


def _steps(opt, n):
    t = ad()
    for _ in range(n):
        loss = dr.sum(dr.squared_norm(opt["x"] - t.Array3f(1, 2, 3))) + dr.sum(dr.square(opt["k"] - 5))
        dr.backward(loss)
        opt.step()


def test_per_parameter_learning_rates():
    opt = _fresh()
    _steps(opt, 1)  # Adam's first step moves every entry by about its learning rate
    np.testing.assert_allclose(adam_to_numpy(opt)["k/value"], [0.5, 1.5, 2.5], atol=1e-4)
    np.testing.assert_allclose(adam_to_numpy(opt)["x/value"][:, 0], [0.1, 0.1, 0.1], atol=1e-4)


def test_checkpoint_resumes_exactly():
    ref = _fresh()
    _steps(ref, 3)
    saved = adam_to_numpy(ref)
    _steps(ref, 4)
    resumed = _fresh()
    adam_from_numpy(resumed, saved)
    _steps(resumed, 4)
    a, b = adam_to_numpy(ref), adam_to_numpy(resumed)
    assert a.keys() == b.keys()
    for key in a:
        np.testing.assert_allclose(b[key], a[key], rtol=1e-6, err_msg=key)
    assert int(a["k/t"][0]) == 7
