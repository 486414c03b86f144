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


def _yaml_keys(path):
    import yaml

    def leaves(d, prefix=""):
        for k, v in d.items():
            if isinstance(v, dict):
                yield from leaves(v, f"{prefix}{k}.")
            else:
                yield f"{prefix}{k}"

    return set(leaves(yaml.safe_load(path.read_text())))


def test_presets_set_scale_and_methods_set_method_never_both():
    """conf/config.yaml's rule: a preset changes only how much is computed, a method only what."""
    from pathlib import Path

    conf = Path(__file__).resolve().parent.parent / "conf"
    presets = {p.stem: _yaml_keys(p) - {"preset"} for p in (conf / "preset").glob("*.yaml")}
    methods = {p.stem: _yaml_keys(p) - {"method"} for p in (conf / "method").glob("*.yaml")}
    assert {"tiny", "small", "paper"} <= presets.keys() and {"spring_gaus", "official"} <= methods.keys()
    for preset, p_keys in presets.items():
        for method, m_keys in methods.items():
            assert not p_keys & m_keys, (preset, method, p_keys & m_keys)


def test_default_method_is_the_recommended_one_at_every_preset():
    for preset in ("tiny", "small", "paper"):
        cfg = compose([f"preset={preset}"])
        assert cfg.method == "spring_gaus"
        assert (cfg.physics.contact, cfg.anchors.binding, cfg.recon.mode) == ("coulomb", "displacement", "full")
    official = compose(["preset=small", "method=official"])
    assert (official.physics.contact, official.anchors.binding, official.recon.mode) == (
        "project",
        "official",
        "truncated",
    )
    assert official.anchors.n_anchors == 512  # the scale stays the preset's


def test_a_thread_count_change_drops_every_frozen_recording():
    """No `dr.freeze` recording made for one thread pool is replayed on another."""
    before = dr.thread_count()
    f = backend.frozen(lambda x: x * 2 + 1)
    t = backend.ad()
    try:
        assert f(t.Float(1.0, 2.0)).numpy().tolist() == [3.0, 5.0]
        assert f.n_recordings == 1
        backend.init("llvm", threads=1 if before != 1 else 2)
        assert f.n_recordings == 0
        assert f(t.Float(1.0, 2.0)).numpy().tolist() == [3.0, 5.0]  # recorded again
    finally:
        backend.init("llvm", threads=before)
        backend._FROZEN.remove(f)
