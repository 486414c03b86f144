"""The calibration study's bookkeeping (evaluation/studies/calibrate_posterior.py): truths drawn from
the prior, SBC ranks, coverage and rank histograms."""

import numpy as np
import pytest

from evaluation.studies.calibrate_posterior import N_BINS, draw_truth, sbc_rank, summarise
from sgdr.posterior.config import PriorConfig


def test_truths_are_seeded_and_drawn_from_the_whole_prior_or_its_middle():
    priors = PriorConfig()
    names = ["log10_k_shift", "friction"]
    draws = [draw_truth(priors, names, case) for case in range(200)]
    assert draw_truth(priors, names, 3) == draws[3]  # the same case draws the same truth
    middle = [draw_truth(priors, names, case, 0.1) for case in range(200)]
    for n in names:
        lo, hi = getattr(priors, n)
        xs, inner = np.array([d[n] for d in draws]), np.array([d[n] for d in middle])
        assert np.all(xs >= lo) and np.all(xs <= hi)
        # the SBC's design: the whole box, its outer fifth included (about 40 of 200 draws)
        outer = (xs < lo + 0.1 * (hi - lo)) | (xs > hi - 0.1 * (hi - lo))
        assert 20 < outer.sum() < 60
        assert np.all(inner >= lo + 0.1 * (hi - lo)) and np.all(inner <= hi - 0.1 * (hi - lo))
        assert inner.std() > 0.15 * (hi - lo)  # spread over the box, not one value
    with pytest.raises(SystemExit, match="truth_margin"):
        draw_truth(priors, names, 0, 0.5)


def test_a_record_drawn_from_the_priors_middle_is_continued_only_with_its_margin(tmp_path):
    """Records written before truths came from the whole box have no truth_margin in their setup:
    the default refuses them with the override that continues them, which is accepted."""
    import json

    from omegaconf import OmegaConf

    from evaluation.studies.calibrate_posterior import TRUTH_MARGIN_BEFORE, calibrate, locked_record, sampler_setup
    from sgdr.config import compose

    cfg = OmegaConf.to_object(compose(["preset=tiny", f"posterior.run={tmp_path / 'no_run'}"]))
    old = sampler_setup(cfg, 1, 0.02, TRUTH_MARGIN_BEFORE)
    assert "truth_margin" not in old and sampler_setup(cfg, 1, 0.02)["truth_margin"] == 0.0
    record = tmp_path / "calibration.json"
    record.write_text(json.dumps({"cases": [{"case": 0}], "setup": old}))
    with pytest.raises(SystemExit, match=r"\+truth_margin=0.1 continues it"):
        calibrate(cfg, 1, tmp_path / "cases", progress=False, record_file=record, twin_noise=0.02)
    with locked_record(record, sampler_setup(cfg, 1, 0.02, TRUTH_MARGIN_BEFORE)) as kept:  # the old margin: its setup
        assert [c["case"] for c in kept["cases"]] == [0]
    assert not (tmp_path / "cases" / "case_000").exists()


def test_ranks_and_summary():
    kept = np.linspace(0.0, 1.0, 101)
    assert sbc_rank(kept, -1.0) == 0.0 and sbc_rank(kept, 2.0) == 1.0
    assert abs(sbc_rank(kept, 0.25) - 0.25) < 0.02
    cases = [
        {"inside": {"a": True}, "rank": {"a": 0.1}},
        {"inside": {"a": False}, "rank": {"a": 0.95}},
        {"inside": {"a": True}, "rank": {"a": 0.5}},
        {"inside": {"a": True}, "rank": {"a": float("nan")}},
    ]
    s = summarise(cases, ["a"])["a"]
    assert s["cases"] == 4 and s["coverage_90"] == 0.75
    assert len(s["rank_histogram"]) == N_BINS and sum(s["rank_histogram"]) == 3
    assert s["rank_histogram"][0] == 1 and s["rank_histogram"][-1] == 1
    assert s["coverage_50"] == pytest.approx(1 / 3)  # only the rank 0.5 is in the central half
    wide = [{"inside": {"a": True}, "rank": {"a": r}} for r in (0.3, 0.4, 0.5, 0.6, 0.7)]
    assert summarise(wide, ["a"])["a"]["coverage_50"] == 1.0  # too wide: every truth near the middle


def test_the_rank_histograms_uniformity_is_tested_against_its_sampling_error():
    from evaluation.studies.calibrate_posterior import rank_uniform_p, summarise

    assert rank_uniform_p([2, 2, 2, 2, 2]) == pytest.approx(1.0)
    assert rank_uniform_p([5, 0, 0, 0, 5]) < 0.01  # piled up at both ends: too narrow
    assert 0.05 < rank_uniform_p([3, 1, 2, 2, 2]) < 1.0  # a scatter ten cases give by chance
    assert rank_uniform_p([1, 0, 1, 0, 0]) is None  # fewer cases than bins: no test
    ends = [{"inside": {"a": False}, "rank": {"a": r}} for r in (0.0, 0.0, 1.0, 1.0, 0.02, 0.99, 1.0, 0.0, 0.0, 1.0)]
    assert summarise(ends, ["a"])["a"]["rank_uniform_p"] < 0.01


def test_a_record_of_another_sampler_setup_is_refused_before_any_work(tmp_path):
    import json

    from omegaconf import OmegaConf

    from evaluation.studies.calibrate_posterior import calibrate
    from sgdr.config import compose

    cfg = OmegaConf.to_object(compose(["preset=tiny", f"posterior.run={tmp_path / 'no_run'}"]))
    record = tmp_path / "kept" / "calibration.json"
    record.parent.mkdir()
    record.write_text(json.dumps({"cases": [], "setup": {"moves": "stretch", "n_steps": 12}}))
    with pytest.raises(SystemExit, match="calibration.json was written with"):
        calibrate(cfg, 2, tmp_path / "cases", progress=False, record_file=record)
    assert not (tmp_path / "cases" / "case_000").exists()


def test_the_setup_holds_the_design_search_in_effect_once():
    """The posterior's design-search settings enter a record's setup once, merged into the search
    they change: a record written with the same search given as recon.search.* overrides is the
    same setup."""
    from omegaconf import OmegaConf

    from evaluation.studies.calibrate_posterior import sampler_setup
    from sgdr.config import compose

    cfg = OmegaConf.to_object(compose(["preset=small", "posterior.run=none"]))
    setup = sampler_setup(cfg, 1, 0.02)
    assert "design_search" not in setup["surrogate"]
    ds = cfg.posterior.surrogate.design_search
    assert setup["design_search"]["initial_samples"] == ds.initial_samples == 128
    assert setup["design_search"]["line_points"] == ds.line_points
    assert setup["design_search"]["frame_schedule"] == [0.5, 1.0]
    assert setup["design_search"]["level"] == "effective" != cfg.recon.search.level  # the user's run: "mean"
    assert setup["design_search"]["popsize"] == cfg.recon.search.popsize  # the rest is recon.search's
    other = OmegaConf.to_object(
        compose(["preset=small", "posterior.run=none", "posterior.surrogate.design_search.generations=48"])
    )
    assert sampler_setup(other, 1, 0.02)["design_search"]["generations"] == 48 != setup["design_search"]["generations"]


def _append_cases(record_file, setup, cases):
    import json
    import time
    from pathlib import Path

    from evaluation.studies.calibrate_posterior import locked_record

    for case in cases:
        with locked_record(Path(record_file), setup) as record:
            time.sleep(0.02)  # a read-modify-write that would lose the other shard's case without the lock
            record["cases"].append({"case": case})
            Path(record_file).write_text(json.dumps(record))


def test_shards_merge_their_cases_into_one_record(tmp_path):
    import json
    import multiprocessing as mp

    from evaluation.studies.calibrate_posterior import parse_shard

    assert parse_shard(None) == (0, 1) and parse_shard("1/2") == (1, 2)
    for bad in ("2/2", "1", "a/b", "0/0"):
        with pytest.raises(SystemExit, match="shard"):
            parse_shard(bad)
    record, setup = tmp_path / "calibration.json", {"moves": "de"}
    ctx = mp.get_context("spawn")
    shards = [ctx.Process(target=_append_cases, args=(str(record), setup, range(i, 16, 2))) for i in range(2)]
    for p in shards:
        p.start()
    for p in shards:
        p.join(60)
    assert [p.exitcode for p in shards] == [0, 0]
    assert sorted(c["case"] for c in json.loads(record.read_text())["cases"]) == list(range(16))
