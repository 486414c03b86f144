"""Small helpers around Mitsuba's Adam (`mi.ad.Adam`, i.e. `drjit.opt.Adam`).

We never write an optimiser: these only build one with per-parameter learning rates, and
move its state (parameter values and Adam moments) to and from NumPy so a long stage can
checkpoint and resume exactly (`sgdr.pipeline.stages.Checkpoint`).
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from sgdr.arrays import to_numpy


def make_adam(params: Mapping[str, tuple[object, float]]):
    """Adam over {name: (Dr.Jit value, learning rate)}; each value is copied and made
    differentiable by the optimiser (read them back with `opt[name]`)."""
    import mitsuba as mi

    if not params:
        raise ValueError("make_adam: no parameters to optimise")
    first_lr = next(iter(params.values()))[1]
    opt = mi.ad.Adam(lr=float(first_lr))
    for name, (value, _) in params.items():
        opt[name] = value
    opt.set_learning_rate({name: float(lr) for name, (_, lr) in params.items()})
    return opt


def adam_to_numpy(opt) -> dict[str, np.ndarray]:
    """Flatten an Adam's parameters and moments into {"<name>/value|t|m|v": array}."""
    out: dict[str, np.ndarray] = {}
    for name, (value, _promoted, _lr, extra) in opt.state.items():
        t, m_t, v_t, _vmax = extra
        out[f"{name}/value"] = to_numpy(value.array, None)
        out[f"{name}/t"] = to_numpy(t, None).reshape(-1)
        out[f"{name}/m"] = to_numpy(m_t, None)
        out[f"{name}/v"] = to_numpy(v_t, None)
    return out


def adam_from_numpy(opt, arrays: Mapping[str, np.ndarray]) -> None:
    """Restore values and moments saved by `adam_to_numpy` into an Adam with the same keys."""
    for name in list(opt.state.keys()):
        value, promoted, lr, extra = opt.state[name]
        flat_t = type(value.array)
        new_flat = flat_t(np.asarray(arrays[f"{name}/value"]))
        if np.asarray(arrays[f"{name}/value"]).shape != to_numpy(value.array, None).shape:
            raise ValueError(f"checkpoint: parameter {name!r} does not have the optimiser's shape")
        opt[name] = type(value)(new_flat)
        value, promoted, lr, extra = opt.state[name]
        t_type = type(extra[0])
        m = flat_t(np.asarray(arrays[f"{name}/m"]))
        v = flat_t(np.asarray(arrays[f"{name}/v"]))
        t = t_type(np.asarray(arrays[f"{name}/t"]).astype(np.uint32))
        opt.state[name] = (value, promoted, lr, (t, m, v, extra[3]))
