import drjit as dr
import mitsuba as mi
import pytest

import sgdr.backend as backend
from sgdr.config import compose


def test_backend_is_llvm_and_maximum_works():
    b = backend.current()
    assert b.variant == "llvm_ad_rgb"
    assert mi.variant() == "llvm_ad_rgb"
    Float = backend.ad().Float
    # dr.maximum aborted with libLLVM 14/15: this is the check that setup installed >= 16
    assert dr.allclose(dr.maximum(Float(1.0, -2.0), Float(0.5, 0.5)), Float(1.0, 0.5))


def test_backend_rejects_unknown_and_switching():
    with pytest.raises(backend.BackendError, match="is not a known backend"):
        backend.init("metal")
    with pytest.raises(backend.BackendError, match="already initialised"):
        backend.init("cuda")


def test_llvm_version_parsing():
    assert backend._llvm_version("/usr/lib/x86_64-linux-gnu/libLLVM-19.so.1") == 19
    assert backend._llvm_version("/usr/lib/llvm-17/lib/libLLVM.so") == 17


@pytest.mark.parametrize("preset,n_anchors", [("tiny", 64), ("small", 512), ("paper", 2048)])
def test_presets_compose(preset, n_anchors):
    cfg = compose([f"preset={preset}"])
    assert cfg.preset == preset
    assert cfg.anchors.n_anchors == n_anchors
    assert cfg.physics.zeta0 == pytest.approx(0.1)


def test_schema_rejects_unknown_field():
    with pytest.raises(Exception, match="nonexistent"):
        compose(["physics.nonexistent=1"])
