"""Stage framework: skipping, force, invalidation, corruption detection, resumption."""

import json

import numpy as np
import pytest

from sgdr.pipeline.stages import MARKER, StageRunner


class _Counter:
    """A cheap stage writing `value.npy` = scale * arange(4); counts its runs."""

    def __init__(self, scale=1.0):
        self.scale = scale
        self.calls = 0

    def produce(self, out, ckpt):
        self.calls += 1
        np.save(out / "value.npy", self.scale * np.arange(4.0))

    @staticmethod
    def load(out):
        v = np.load(out / "value.npy", allow_pickle=False)
        if v.shape != (4,):
            raise ValueError("bad shape")
        return v


def test_completed_stage_is_skipped_and_force_redoes(tmp_path):
    s = _Counter()
    r1 = StageRunner(tmp_path).run("a", {"lr": 1}, s.produce, s.load)
    r2 = StageRunner(tmp_path).run("a", {"lr": 1}, s.produce, s.load)
    assert (s.calls, r1.skipped, r2.skipped) == (1, False, True)
    np.testing.assert_array_equal(r2.value, np.arange(4.0))
    assert r1.digest == r2.digest
    StageRunner(tmp_path, force=True).run("a", {"lr": 1}, s.produce, s.load)
    assert s.calls == 2


def test_changed_config_redoes_and_invalidates_downstream(tmp_path):
    up, down = _Counter(1.0), _Counter()
    runner = StageRunner(tmp_path)
    a = runner.run("a", {"lr": 1}, up.produce, up.load)
    runner.run("b", {"input": a.digest}, down.produce, down.load)
    runner.run("b", {"input": a.digest}, down.produce, down.load)
    assert down.calls == 1
    up.scale = 2.0  # upstream recomputed with another config gives another result
    a2 = runner.run("a", {"lr": 2}, up.produce, up.load)
    assert up.calls == 2 and a2.digest != a.digest
    runner.run("b", {"input": a2.digest}, down.produce, down.load)
    assert down.calls == 2


@pytest.mark.parametrize("damage", ["marker", "truncate", "edit", "delete", "marker_garbage"])
def test_damaged_output_is_detected_and_redone(tmp_path, damage):
    s = _Counter()
    runner = StageRunner(tmp_path)
    runner.run("a", {}, s.produce, s.load)
    out = tmp_path / "a"
    f = out / "value.npy"
    if damage == "marker":
        (out / MARKER).unlink()
    elif damage == "truncate":
        f.write_bytes(f.read_bytes()[:20])
    elif damage == "edit":
        np.save(f, np.arange(4.0) + 1)  # readable, but not what the stage produced
    elif damage == "delete":
        f.unlink()
    elif damage == "marker_garbage":
        (out / MARKER).write_text("{not json")
    r = runner.run("a", {}, s.produce, s.load)
    assert s.calls == 2 and not r.skipped
    np.testing.assert_array_equal(r.value, np.arange(4.0))
    assert json.loads((out / MARKER).read_text())["files"].keys() == {"value.npy"}


def test_unloadable_output_is_redone_even_with_matching_hashes(tmp_path):
    s = _Counter()
    runner = StageRunner(tmp_path)
    runner.run("a", {}, s.produce, s.load)

    def strict_load(out):
        raise ValueError("format version too old")

    produced = []
    with pytest.raises(Exception, match="cannot be loaded"):
        runner.run("a", {}, lambda o, c: produced.append(1) or s.produce(o, c), strict_load)
    assert produced == [1]  # the verified-but-unloadable output was not used
    assert not (tmp_path / "a" / MARKER).exists()


def test_interrupted_stage_leaves_no_marker_and_resumes_from_checkpoint(tmp_path):
    steps_run = []

    def make_produce(crash_at):
        def produce(out, ckpt):
            start, x = 0, np.zeros(3)
            resumed = ckpt.load()
            if resumed is not None:
                start, arrays = resumed
                x = arrays["x"]
            for step in range(start, 10):
                if step == crash_at:
                    (out / "partial.npy").write_bytes(b"half")
                    raise KeyboardInterrupt
                x = x + step
                steps_run.append(step)
                ckpt.save(step + 1, {"x": x})
            np.save(out / "x.npy", x)

        return produce

    load = lambda out: np.load(out / "x.npy")  # noqa: E731
    runner = StageRunner(tmp_path)
    with pytest.raises(KeyboardInterrupt):
        runner.run("long", {"n": 10}, make_produce(crash_at=6), load)
    assert not (tmp_path / "long" / MARKER).exists()
    r = runner.run("long", {"n": 10}, make_produce(crash_at=None), load)
    assert steps_run == list(range(10))  # steps 0-5, then 6-9 after resuming: none twice
    np.testing.assert_array_equal(r.value, np.full(3, 45.0))
    assert not (tmp_path / "long" / "partial.npy").exists()
    assert not (tmp_path / "long" / "checkpoint").exists()


def test_checkpoint_of_another_config_is_not_resumed(tmp_path):
    seen = []

    def crash(out, ckpt):
        ckpt.save(5, {"x": np.ones(2)})
        raise RuntimeError("killed")

    def fresh(out, ckpt):
        seen.append(ckpt.load())
        np.save(out / "x.npy", np.zeros(2))

    runner = StageRunner(tmp_path)
    with pytest.raises(RuntimeError):
        runner.run("s", {"lr": 1}, crash, lambda o: np.load(o / "x.npy"))
    runner.run("s", {"lr": 2}, fresh, lambda o: np.load(o / "x.npy"))
    assert seen == [None]


# ---------------------------------------------------------------------------- pipeline keys
def _changed(value):
    """Another value of the same type (a stand-in for any edit of a setting)."""
    if isinstance(value, bool):
        return not value
    if isinstance(value, (int, float)):
        return value + 1
    if isinstance(value, str):
        return value + "_other"
    if isinstance(value, list):
        return [*value, 1.0]
    raise TypeError(type(value))


def _leaves(d, prefix=""):
    for k, v in d.items():
        if isinstance(v, dict):
            yield from _leaves(v, f"{prefix}{k}.")
        else:
            yield f"{prefix}{k}", v


def _stage_key_hashes(cfg):
    from sgdr.digest import key_hash
    from sgdr.pipeline.run import STAGE_SECTIONS, stage_sections

    return {stage: key_hash(stage_sections(cfg, stage)) for stage in STAGE_SECTIONS}


def test_every_field_of_a_stage_section_is_in_its_key_except_the_listed_ones():
    """Changing any field of a section a stage reads redoes the stage; the fields listed as
    changing no output (RECON_NEVER_IN_KEYS) redo nothing; a recon field one stage owns
    (RECON_STAGE_FIELDS) redoes that stage (its followers see it through their inputs)."""
    from omegaconf import OmegaConf

    from sgdr.config import compose
    from sgdr.pipeline.run import RECON_NEVER_IN_KEYS, RECON_STAGE_FIELDS, STAGE_SECTIONS

    cfg = OmegaConf.to_object(compose(["preset=tiny"]))
    base = _stage_key_hashes(cfg)
    owner = {f: stage for stage, fields in RECON_STAGE_FIELDS.items() for f in fields}
    plain = OmegaConf.to_container(compose(["preset=tiny"]))
    for section in sorted({s for sections in STAGE_SECTIONS.values() for s in sections}):
        for name, value in _leaves(plain[section]):
            top = name.split(".")[0]
            edited = OmegaConf.to_object(compose(["preset=tiny", f"{section}.{name}={json.dumps(_changed(value))}"]))
            now = _stage_key_hashes(edited)
            redone = {stage for stage in base if now[stage] != base[stage]}
            readers = {stage for stage, sections in STAGE_SECTIONS.items() if section in sections}
            if section == "recon" and top in RECON_NEVER_IN_KEYS:
                assert redone == set(), (name, redone)
            elif section == "recon" and top in owner:
                assert redone == {owner[top]}, (name, redone)
            else:
                assert redone == readers, (f"{section}.{name}", redone, readers)


def test_a_changed_key_is_logged_by_name(tmp_path, caplog):
    s = _Counter()
    StageRunner(tmp_path).run("a", {"recon": {"iterations": 20, "mode": "full"}, "input": "x"}, s.produce, s.load)
    with caplog.at_level("WARNING", logger="sgdr.pipeline.stages"):
        StageRunner(tmp_path).run("a", {"recon": {"iterations": 30, "mode": "full"}, "input": "x"}, s.produce, s.load)
    assert s.calls == 2
    assert "config or inputs changed: recon.iterations: 20 -> 30" in caplog.text


def test_a_run_folder_moved_elsewhere_resumes(tmp_path):
    """Keys hold values and digests, never paths: a copied run folder skips its stages."""
    import shutil

    s = _Counter()
    key = {"recon": {"lr": 0.05, "grid": [2.7, 3.0]}, "seed": 0}
    StageRunner(tmp_path / "here").run("a", key, s.produce, s.load)
    shutil.copytree(tmp_path / "here", tmp_path / "there")
    assert StageRunner(tmp_path / "there").run("a", json.loads(json.dumps(key)), s.produce, s.load).skipped
    assert s.calls == 1


def test_a_stage_with_the_same_key_is_copied_from_a_sibling_run(tmp_path):
    """Another run folder's completed stage with the same key is copied and verified, not
    recomputed; another key, or a damaged donor, is recomputed."""
    a, b = _Counter(), _Counter(scale=2.0)
    key = {"static_fit": {"iterations": 10}, "seed": 0, "sequence": "abc"}
    first = StageRunner(tmp_path / "torus_small_s0").run("static", key, a.produce, a.load)
    shared = StageRunner(tmp_path / "torus_small_pacnerf_s0", donors=[tmp_path / "torus_small_s0"]).run(
        "static", key, b.produce, b.load
    )
    assert b.calls == 0 and shared.skipped and shared.digest == first.digest
    np.testing.assert_array_equal(shared.value, np.arange(4.0))
    assert (tmp_path / "torus_small_pacnerf_s0" / "static" / "DONE.json").is_file()
    other = StageRunner(tmp_path / "torus_small_s1", donors=[tmp_path / "torus_small_s0"])
    other.run("static", {**key, "seed": 1}, b.produce, b.load)
    assert b.calls == 1  # another seed: its own stage
    np.save(tmp_path / "torus_small_s0" / "static" / "value.npy", np.zeros(4))  # the donor edited
    c = _Counter(scale=3.0)
    StageRunner(tmp_path / "third", donors=[tmp_path / "torus_small_s0"]).run("static", key, c.produce, c.load)
    assert c.calls == 1
