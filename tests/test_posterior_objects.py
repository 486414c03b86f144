"""The seven objects' study: the discrepancy's leave-one-object-out calibration over draws of runs."""

import numpy as np

from evaluation.studies.posterior_objects import leave_one_out


def _case(speed: float, seed: int, t: int = 30, n_fit: int = 10) -> dict:
    """A ball case whose truth leaves the asset's (still) prediction at `speed` sizes per second."""
    rng = np.random.default_rng(seed)
    h = np.maximum(np.arange(t) - n_fit + 1, 0) / 24.0
    truth = np.zeros((t, 3))
    truth[:, 0] = speed * 0.5 * h + rng.normal(0, 0.0005, t)
    return {"draws": np.zeros((4, t, 3)), "centre": np.zeros((t, 3)), "truth": truth,
            "sigma_fit": np.full(n_fit, 0.002), "fps": 24.0, "size": 0.5}  # fmt: skip


def test_a_pooled_draw_joins_the_calibration_and_leaves_with_its_object():
    """Three objects that follow their asset: γ = 0 and each held-out object is covered. A second
    draw in which a and b drift raises c's γ (both drifting runs calibrate it) more than b's (b's
    own run leaves with b); a drifting run of a alone never calibrates a, and pooled runs are not
    scored themselves."""
    still = {o: {"ball": _case(0.0, k)} for k, o in enumerate("abc")}
    alone = leave_one_out(still)
    assert alone["growth_all"] == 0.0 and alone["calibration_runs"] == 3
    assert all(v["growth"] == 0.0 and v["inside_future"] == 1.0 for v in alone["objects"].values())

    drifting = {"a": {"ball": _case(0.6, 10)}, "b": {"ball": _case(0.6, 11)}}
    pooled = leave_one_out(still, pool=(drifting,))
    assert pooled["calibration_runs"] == 5 and pooled["growth_all"] > 0
    # c is calibrated on both drifting runs, b on one (a's): b's own run is left out with b
    assert pooled["objects"]["c"]["growth"] > 0
    assert pooled["objects"]["b"]["growth"] < pooled["objects"]["c"]["growth"]

    only_a = leave_one_out(still, pool=({"a": {"ball": _case(0.6, 12)}},))
    assert only_a["objects"]["a"]["growth"] == 0.0  # a's own drifting run never calibrates a
    assert only_a["objects"]["b"]["growth"] > 0
    assert set(only_a["objects"]) == {"a", "b", "c"}  # pooled runs are not scored


def test_balls_with_and_without_the_offset_are_never_calibrated_together():
    """posterior.discrepancy_offset moves a ball's draws: a γ over runs of both kinds would mix
    two discrepancy models, so the calibration refuses them and names the way out; a case that
    has its offset already is scored as it is."""
    import pytest

    from evaluation.studies.posterior_objects import offset_case

    plain = {o: {"ball": _case(0.0, k)} for k, o in enumerate("ab")}
    moved = {"c": {"ball": {**_case(0.0, 5), "offset": [0.01, 0.0, 0.0]}}}
    with pytest.raises(ValueError, match="--offsets"):
        leave_one_out(plain, pool=(moved,))
    assert leave_one_out(moved | {"d": {"ball": {**_case(0.0, 6), "offset": [0.0, 0.0, 0.0]}}})["calibration_runs"] == 2
    assert offset_case(moved["c"], cfg=None) is moved["c"]["ball"]  # no run folder needed


def test_the_objects_runs_over_the_draws_are_scored_as_ensembles():
    """Two draws: object a's runs lie on either side of its truth (each misses, together they
    cover), b's both follow it; every combination of one run is each run alone."""
    from evaluation.studies.posterior_objects import ensemble_summary, ensembles

    def case(offset, seed):
        c = _case(0.0, seed)
        c["draws"] = c["draws"] + np.r_[np.zeros(10), np.full(20, offset)][None, :, None] * [1, 0, 0]
        return c

    d0 = {"a": {"ball": case(+0.05, 1)}, "b": {"ball": _case(0.0, 2)}}
    d1 = {"a": {"ball": case(-0.05, 3)}, "b": {"ball": _case(0.0, 4)}}
    assert [len(g) for g in ensembles(d0, (d1,)).values()] == [1, 1]
    assert [len(g) for g in ensembles(d0, (d1,), size=1).values()] == [2, 2]
    together = ensemble_summary(d0, (d1,))
    assert together["objects"]["a"]["inside_future_mean"] == 1.0 and together["growth_all"] == 0.0
    alone = ensemble_summary(d0, (d1,), size=1)
    assert alone["objects"]["a"]["inside_future_min"] == 0.0
    assert alone["growth_all"] > 0.0
    import pytest

    with pytest.raises(ValueError, match="--ensemble-size 3"):
        ensemble_summary(d0, (d1,), size=3)  # two draws hold two runs of each object
