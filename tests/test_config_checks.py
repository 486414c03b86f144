"""Bad inputs fail before any work, naming the key or the file (issue 13, "errors in seconds").

- every config field but the bools has a check, and every check names a real field;
- every preset x method combination passes; the bad values users hit fail with the key named;
- every registry chosen by a config key is checked against the registry itself;
- a corrupt image fails before the first stage, naming the file;
- a run folder is never reused for another sequence, and runs are named after the sequence;
- Ctrl-C ends a run with one line saying what was saved.
"""

import dataclasses
import importlib
import json
import pkgutil
import shutil
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from omegaconf import OmegaConf

import sgdr
from sgdr.checks import ConfigError
from sgdr.config import CHECKS as TOP_CHECKS
from sgdr.config import SECTION_CHECKS, Config, compose, validate
from sgdr.registry import Registry

FIXTURE = Path(__file__).parent / "data" / "sgdr_seq"


def _cfg(*overrides):
    return OmegaConf.to_object(compose(["preset=tiny", *overrides]))


def _sections():
    """(dotted path, dataclass instance) of every config section, nested ones included."""
    out, todo = [], [("", Config())]
    while todo:
        path, obj = todo.pop()
        out.append((path, obj))
        for f in dataclasses.fields(obj):
            value = getattr(obj, f.name)
            if dataclasses.is_dataclass(value):
                todo.append((f"{path}.{f.name}".lstrip("."), value))
    return out


def test_every_field_has_a_check():
    tables = {"": TOP_CHECKS, **SECTION_CHECKS}
    for path, obj in _sections():
        fields = {
            f.name: getattr(obj, f.name)
            for f in dataclasses.fields(obj)
            if not dataclasses.is_dataclass(getattr(obj, f.name))
        }
        checks = tables[path]
        unchecked = [n for n, v in fields.items() if not isinstance(v, bool) and n not in checks]
        assert not unchecked, f"config section {path or '<top>'}: fields without a check: {unchecked}"
        assert set(checks) <= set(fields), f"{path}: checks of missing fields {set(checks) - set(fields)}"


@pytest.mark.parametrize("preset", ["tiny", "small", "paper"])
@pytest.mark.parametrize("method", ["spring_gaus", "official"])
def test_shipped_configs_pass(preset, method):
    validate(OmegaConf.to_object(compose([f"preset={preset}", f"method={method}"])))


@pytest.mark.parametrize(
    "override, key",
    [
        ("physics.contact=bogus", "physics.contact"),
        ("recon.mode=bogus", "recon.mode"),
        ("anchors.n_k=0", "anchors.n_k"),
        ("recon.iterations=-1", "recon.iterations"),
        ("recon.simulate.stiffness_scale=0", "recon.simulate.stiffness_scale"),
        ("recon.simulate.gravity=[0,-9.8]", "recon.simulate.gravity"),
        ("render.background=[0,0]", "render.background"),
        ("recon.substep_growth=[]", "recon.substep_growth"),
        ("recon.run_name=a/b", "recon.run_name"),
        ("anchors.n_k=100000", "anchors.n_anchors"),  # a rule between two fields names both
        ("recon.log10_k_grid=[1.0,9.0]", "recon.log10_k_max"),
        ("recon.search.parameters=[stiffness]", "recon.search.parameters"),
        ("recon.search.friction_range=[0.5,0.1]", "recon.search.friction_range"),
        ("recon.search.log10_k_range=[1.0,9.0]", "recon.log10_k_max"),
        ("recon.search.popsize=1", "recon.search.popsize"),
        ("recon.field_prior_strengths=[0.0]", "recon.field_prior_strengths"),
        ("backend=metal", "backend"),
    ],
)
def test_bad_values_name_their_key(override, key):
    with pytest.raises(ConfigError, match=key.replace(".", r"\.")):
        validate(_cfg(override))


def test_all_problems_are_listed_at_once():
    with pytest.raises(ConfigError) as err:
        validate(_cfg("physics.contact=bogus", "recon.mode=bogus", "anchors.n_k=0"))
    text = str(err.value)
    assert text.startswith("3 config values cannot work")
    assert all(k in text for k in ("physics.contact", "recon.mode", "anchors.n_k"))


def _config_registries():
    """Every Registry in sgdr whose `setting` is a config key (dotted path into Config)."""
    for info in pkgutil.walk_packages(sgdr.__path__, "sgdr."):
        importlib.import_module(info.name)
    found = {}
    for info in pkgutil.walk_packages(sgdr.__path__, "sgdr."):
        for value in vars(importlib.import_module(info.name)).values():
            # LAYOUTS names `sequence` for its errors, but the layout is detected, not named
            if isinstance(value, Registry) and value.setting and value.setting != "sequence":
                obj = Config()
                try:
                    for part in value.setting.split("."):
                        obj = getattr(obj, part)
                except AttributeError:
                    continue  # chosen by a function argument (grad_mode), not by the config
                found[value.setting] = value
    return found


def test_every_config_registry_is_checked_against_itself():
    registries = _config_registries()
    assert {"physics.contact", "recon.mode", "anchors.sampler", "synth.object"} <= set(registries)
    for setting, registry in registries.items():
        obj = Config()
        for part in setting.split("."):
            obj = getattr(obj, part)
        form = "[{}]" if isinstance(obj, list) else "{}"  # a list-valued setting names its choices in a list
        for name in registry:
            validate(_cfg(f"{setting}={form.format(name)}"))
        with pytest.raises(ConfigError, match=setting.replace(".", r"\.")):
            validate(_cfg(f"{setting}={form.format('not_a_' + registry.what.replace(' ', '_'))}"))


# ---------------------------------------------------------------------------- the sequence
def test_corrupt_image_fails_before_any_stage(tmp_path):
    from sgdr.data.sequence import SequenceError
    from sgdr.pipeline.run import run_pipeline

    seq = tmp_path / "my_banana"
    shutil.copytree(FIXTURE, seq)
    bad = sorted((seq / "images").rglob("*.png"))[3]
    bad.write_bytes(bad.read_bytes()[:60])  # a truncated PNG
    cfg = _cfg(f"sequence={seq}", f"recon.output_dir={tmp_path / 'out'}", "tracking.enabled=false")
    with pytest.raises(SequenceError, match=bad.name):
        run_pipeline(cfg, progress=False)
    assert not (tmp_path / "out").exists()


def test_runs_are_named_after_the_sequence(tmp_path):
    from sgdr.run_folder import default_run_name

    assert default_run_name(_cfg(f"sequence={tmp_path / 'my banana'}")) == "my-banana_tiny_s0"
    assert default_run_name(_cfg("synth.object=apple", "seed=3", "method=official")) == "apple_tiny_official_s3"
    assert default_run_name(_cfg(f"sequence={tmp_path / 'x'}", "recon.run_name=mine")) == "mine"


def test_a_run_folder_is_never_reused_for_another_sequence(tmp_path, caplog):
    from sgdr.run_folder import OWNER, RunFolderError, claim_run_dir

    run = tmp_path / "outputs" / "torus_small_s0"
    a, b = tmp_path / "data" / "torus", tmp_path / "mine" / "torus"
    claim_run_dir(run, a, "digest-a")
    assert json.loads((run / OWNER).read_text()) == {"sequence": str(a.resolve()), "digest": "digest-a"}
    claim_run_dir(run, a, "digest-a")  # the same sequence again: a resume
    claim_run_dir(run, b, "digest-a")  # a copy of the same data elsewhere: the same sequence
    with caplog.at_level("WARNING"):
        claim_run_dir(run, b, "digest-b")  # regenerated in place: redone, and said so
    assert "changed since" in caplog.text
    with pytest.raises(RunFolderError, match="recon.run_name"):
        claim_run_dir(run, a, "digest-c")  # another sequence: refused
    # a folder written before RUN.json: judged by the sequence its config.yaml records
    old = tmp_path / "outputs" / "old"
    old.mkdir()
    (old / "config.yaml").write_text(f"sequence: ''\ndata_dir: {tmp_path / 'data'}\nsynth:\n  object: torus\n")
    claim_run_dir(old, a, "digest-a")
    (old / OWNER).unlink()
    with pytest.raises(RunFolderError):
        claim_run_dir(old, tmp_path / "mine" / "banana", "digest-z")


# ---------------------------------------------------------------------------- Ctrl-C
def test_interrupt_says_what_was_saved(tmp_path, monkeypatch):
    from sgdr.pipeline import run as run_mod
    from sgdr.pipeline.stages import Checkpoint

    def done(ctx, out, ckpt):
        (out / "x.txt").write_text("x")

    def interrupted(ctx, out, ckpt):
        ckpt.save(7, {"a": np.zeros(2)})
        raise KeyboardInterrupt

    stages = (
        run_mod.Stage("first", (), (), done, lambda ctx, out: "ok", reads_sequence=False),
        run_mod.Stage("second", (), ("first",), interrupted, lambda ctx, out: "ok", reads_sequence=False),
    )
    monkeypatch.setitem(run_mod.MODELS, "spring_mass", run_mod.Model(stages, run_mod.spring_identified))
    with pytest.raises(run_mod.RunInterrupted) as err:
        run_mod._run_stages(_cfg(), SimpleNamespace(cameras=[]), "digest", tmp_path, None, False)
    msg = str(err.value)
    assert "\n" not in msg
    assert "during stage second" in msg and "stages first are complete" in msg
    assert "saved up to step 7" in msg and "run the same command again" in msg
    assert Checkpoint(tmp_path / "second" / "checkpoint", "").path.is_file()


def test_entry_point_fails_in_seconds_with_one_line(tmp_path):
    """The issue's bad values at the command line: exit status 2, one `error:` line naming every
    key, no traceback, nothing generated or written."""
    import subprocess
    import sys

    root = Path(__file__).resolve().parent.parent
    cmd = [
        sys.executable,
        "experiments/reconstruct.py",
        "preset=tiny",
        f"data_dir={tmp_path / 'data'}",
        f"recon.output_dir={tmp_path / 'out'}",
        f"hydra.run.dir={tmp_path / 'hydra'}",
        "physics.contact=bogus",
        "recon.iterations=-1",
    ]
    res = subprocess.run(cmd, cwd=root, capture_output=True, text=True, timeout=300)
    assert res.returncode == 2, res.stderr[-2000:]
    assert "Traceback" not in res.stderr
    assert res.stderr.startswith("error: 2 config values cannot work")
    assert "physics.contact='bogus'" in res.stderr and "recon.iterations=-1" in res.stderr
    assert not (tmp_path / "data").exists() and not (tmp_path / "out").exists()
