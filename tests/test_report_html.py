"""The run report: ground compositing, labelled video frames, the verdict rules, strict JSON
scores (also without ground truth), and report.html built by the report stage's own code from
a fixture sequence, opened in headless Chromium."""

import copy
import json
import math
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest
from omegaconf import OmegaConf

from sgdr.asset.predict import Prediction
from sgdr.cameras import Camera
from sgdr.config import compose
from sgdr.data import load_sequence
from sgdr.evaluate.score import evaluate_prediction, strict_json
from sgdr.report.media import FIT_COLOUR, FUTURE_COLOUR, composite_ground, playback, video_frame
from sgdr.report.verdict import judge, momentum_note
from tests.browser import assert_report_reads_well

DATA = Path(__file__).parent / "data"


@pytest.fixture(scope="module")
def cfg():
    return OmegaConf.to_object(compose(["preset=tiny"]))


# ------------------------------------------------------------------------------ ground and frames
def test_ground_is_drawn_below_the_horizon_behind_the_object():
    # a level camera 1 unit above the ground z = 0, looking along +y: the lower half sees the ground
    cam = Camera.look_at([0, 0, 1], [0, 1, 1], [0, 0, 1], 60.0, 40, 30)
    rgb = np.zeros((30, 40, 3))
    alpha = np.zeros((30, 40))
    rgb[:, :5], alpha[:, :5] = 1.0, 1.0  # an opaque white object on the left
    out = composite_ground(rgb, alpha, cam, [0, 0, 0], [0, 0, 2.0])
    assert out.shape == (30, 40, 3) and out.dtype == np.uint8
    assert (out[:14, 5:] == 0).all()  # sky stays black
    below = out[17:, 5:, 0].astype(float)
    assert below.min() > 10 and np.unique(below).size > 2  # a lit checkerboard (two tones, fading)
    assert (out[:, :5] == 255).all()  # the object covers the ground
    # a camera under the ground sees none of it
    under = Camera.look_at([0, 0, -1], [0, 1, -1], [0, 0, 1], 60.0, 40, 30)
    assert (composite_ground(rgb * 0, alpha * 0, under, [0, 0, 0], [0, 0, 1]) == 0).all()
    with pytest.raises(ValueError, match="differ in size"):  # names the sizes
        composite_ground(rgb[:10], alpha[:10], cam, [0, 0, 0], [0, 0, 1])


def test_video_frames_are_labelled_and_slow_enough():
    views = [np.full((32, 32, 3), 0.5)] * 3
    fit, future = video_frame(views, views, 2, 12, 8), video_frame(views, views, 9, 12, 8)
    assert fit.shape == future.shape and fit.shape[0] > 96  # cells enlarged to >= 96 px plus banner
    banner_fit, banner_future = fit[:26].reshape(-1, 3), future[:26].reshape(-1, 3)
    assert (banner_fit == FIT_COLOUR).all(1).sum() > 100 and not (banner_fit == FUTURE_COLOUR).all(1).any()
    assert (banner_future == FUTURE_COLOUR).all(1).sum() > 100
    assert not np.array_equal(fit[:26], future[:26])  # the frame counter differs
    for n in (1, 4, 12, 30, 120):
        fps, repeat = playback(n)
        assert n * repeat / fps >= 4.0 and fps / repeat <= 6
    assert playback(30) == (6.0, 1) and playback(12) == (2.4, 1) and playback(1) == (2.0, 8)


# ------------------------------------------------------------------------------ verdict rules
def _scores(fit_psnr=30.0, future_cd=1.88, base=0.64, cv=2.5):
    return {
        "fit_psnr": fit_psnr,
        "fit_cd": 0.5,
        "future_cd": future_cd,
        "future_psnr": 20.0,
        "baseline_future_cd": base,
        "baseline_variant": "still",
        "baseline_future_cd_by_variant": {"still": base, "ballistic": 0.9, "constant_velocity": cv},
        "missing": {},
    }


def _dyn(k=None, **kw):
    d = {
        "log10_k": np.full(10, 3.0) if k is None else np.asarray(k, float),
        "kappa": 0.1,
        "friction": 0.5,
        "restitution": 0.3,
        "n_substeps": 40,
        "pass_losses": [0.3, 0.2],
        "eval_loss_initial": 0.3,
        "eval_loss_final": 0.2,
        "log10_k_grid_losses": {},
    }
    d.update(kw)
    return d


def test_verdict_states_fit_quality_and_future_against_the_baseline(cfg):
    v = judge(_scores(), _dyn(), cfg.recon, cfg.physics)
    assert v.fit_quality == "good" and v.future == "worse"
    assert v.headline == "Fit good, future 2.9x worse than the physics-free baseline."
    assert "30.0 dB" in v.sentences[0] and "2.9x worse" in v.sentences[1]
    # worse than 'still' and 'ballistic' but not than constant velocity (2.5 > 1.88)
    assert sum("worse than the physics-free" in w for w in v.warnings) == 2
    assert not any("constant" in s for s in v.sentences)
    for psnr, quality in ((27.9, "fair"), (22.0, "fair"), (21.9, "poor"), (None, "unknown")):
        assert judge(_scores(fit_psnr=psnr), _dyn(), cfg.recon, cfg.physics).fit_quality == quality
    assert "infinitely worse" in judge(_scores(base=0.0), _dyn(), cfg.recon, cfg.physics).headline
    # a near tie reads as a percentage (0.717 against 0.686 is not "1.0x worse")
    close = judge(_scores(future_cd=0.717, base=0.686), _dyn(), cfg.recon, cfg.physics).headline
    assert close == "Fit good, future 4.5% worse than the physics-free baseline."
    good = judge(_scores(future_cd=0.3, cv=0.2), _dyn(), cfg.recon, cfg.physics)
    assert good.future == "better" and "2.1x better" in good.headline
    assert any("constant-velocity" in s for s in good.sentences)
    assert [w for w in good.warnings if "baseline" in w] == [
        "The future prediction (Chamfer distance 0.300) is worse than the physics-free 'constant velocity' baseline "
        "(0.200), 1.5x worse."
    ]


def test_verdict_without_ground_truth_scores_images_only(cfg):
    s = _scores(future_cd=None, base=None)
    s["missing"] = {"future_cd": "the sequence has no ground-truth particles (gt/)"}
    s["baseline_future_cd_by_variant"] = {}
    v = judge(s, _dyn(), cfg.recon, cfg.physics)
    assert v.future == "not scored"
    assert "cannot be scored geometrically: the sequence has no ground-truth particles (gt/)" in v.sentences[1]
    assert "20.0 dB" in v.sentences[1]
    s = _scores(base=None)
    s["missing"] = {"baseline_future_cd": "fewer than 2 fit frames"}
    v = judge(s, _dyn(), cfg.recon, cfg.physics)
    assert v.future == "not scored" and v.headline == "Fit good, future not compared with a baseline."
    assert "1.88" in v.sentences[1] and "fewer than 2 fit frames" in v.sentences[1]


def test_warnings_name_parameters_at_bounds_and_losses_that_do_not_fall(cfg):
    r = cfg.recon
    assert judge(_scores(future_cd=0.1), _dyn(), r, cfg.physics).warnings == []
    k = np.full(10, r.log10_k_min)
    k[:3] = 1.0  # 70% at the lower clamp
    w = judge(_scores(future_cd=0.1), _dyn(k), r, cfg.physics).warnings
    assert len(w) == 1 and "lower bound" in w[0] and "70%" in w[0]
    grid_run = OmegaConf.to_object(compose(["preset=tiny", "recon.log10_k_grid=[2.7,3.0,3.3]"]))
    w = judge(
        _scores(future_cd=0.1),
        _dyn(log10_k_grid_losses={"2.7": 0.1, "3": 0.2, "3.3": 0.3}),
        grid_run.recon,
        cfg.physics,
    ).warnings
    assert len(w) == 1 and "lowest value of recon.log10_k_grid" in w[0]
    w = judge(_scores(future_cd=0.1), _dyn(friction=0.0, eval_loss_final=0.4, pass_losses=[0.2, 0.3]), r, cfg.physics)
    assert len(w.warnings) == 3 and "no friction" in w.warnings[0] and "did not decrease" in w.warnings[1]
    w = judge(_scores(future_cd=0.1), _dyn(pass_losses=[], eval_loss_final=0.3), r, cfg.physics).warnings
    assert any("No dynamic pass ran" in x for x in w)
    coulomb = OmegaConf.to_object(compose(["preset=tiny", "physics.contact=coulomb"]))
    assert any(
        "Restitution" in x for x in judge(_scores(future_cd=0.1), _dyn(restitution=1.0), r, coulomb.physics).warnings
    )
    assert not judge(
        _scores(future_cd=0.1), _dyn(restitution=1.0), r, cfg.physics.__class__(contact="project")
    ).warnings


def _search(spread=0.0, ambiguous=False, best_k=3.0):
    return {
        "names": ["log10_k", "friction"],
        "lo": [1.5, 0.0],
        "hi": [5.0, 1.0],
        "best": {"log10_k": best_k, "friction": 0.4},
        "best_loss": 0.02,
        "n_evaluations": 3,
        "n_generations": 1,
        "n_substeps": 40,
        "image_scale": 1,
        "candidates": [[best_k, 0.4], [3.5, 0.2], [2.0, 0.9]],
        "losses": [0.02, 0.0205, 0.05],
        "generation": [0, 0, 0],
        "landscape": {"equivalent": [0, 1], "future_spread": spread, "ambiguous": ambiguous},
    }


def test_the_global_search_warns_when_equally_good_candidates_part_and_at_a_range_end(cfg, tmp_path):
    from sgdr.report.html import identification_body

    r = cfg.recon
    quiet = _dyn(search=_search(0.1, False), best_pass=-1, eval_loss_final=0.3)  # the start kept: no loss warning
    assert judge(_scores(future_cd=0.1), quiet, r, cfg.physics).warnings == []
    w = judge(_scores(future_cd=0.1), _dyn(search=_search(0.8, True)), r, cfg.physics).warnings
    assert len(w) == 1 and "2 candidates" in w[0] and "0.8 x the object's size" in w[0]
    w = judge(_scores(future_cd=0.1), _dyn(search=_search(best_k=5.0)), r, cfg.physics).warnings
    assert len(w) == 1 and "upper end" in w[0] and "recon.search.log10_k_range" in w[0] and "stability" in w[0]
    prior = {"strengths": ["inf", "1"], "holdout_frames": 2, "holdout_losses": {"inf": 0.03, "1": 0.02}, "chosen": "1"}
    body = identification_body(tmp_path, _dyn(search=_search(0.8, True), field_prior=prior))
    assert (tmp_path / "search.png").stat().st_size > 1000
    assert (
        "3 candidates (0 space-filling, then CMA-ES in 1 generations)" in body and "do not pin the physics down" in body
    )
    assert "no field: the global level" in body and "Chosen: 1" in body
    swept = identification_body(tmp_path, _dyn(search={**_search(), "n_evaluations": 11, "n_swept": 8}))
    assert "11 candidates (0 space-filling, 8 in coordinate sweeps, then CMA-ES in 1 generations)" in swept


# ------------------------------------------------------------------------------ strict JSON scores
def test_strict_json_replaces_non_finite_values_with_null_and_a_reason():
    missing = {"a": "already explained"}
    clean = strict_json({"a": float("nan"), "b": [np.float32(1.5), np.inf], "c": np.int64(3), "d": (True,)}, missing)
    assert clean == {"a": None, "b": [1.5, None], "c": 3, "d": [True]}
    assert missing == {"a": "already explained", "b[1]": "not finite (inf)"}
    json.dumps(clean, allow_nan=False)


def _perfect_prediction(seq):
    """The sequence's own ground truth as the 'prediction': centres = gt particles (or a dummy
    cloud without gt), images = the input views as RGBA uint8."""
    imgs = np.stack([np.stack([seq.image(v, f) for v in range(seq.n_views)]) for f in range(seq.n_frames)])
    gts = [seq.gt_particles(f) for f in range(seq.n_frames)]
    centres = np.stack(gts) if gts[0] is not None else np.zeros((seq.n_frames, 5, 3))
    rgba = (imgs * 255 + 0.5).astype(np.uint8)
    return Prediction(centres[:, :8], centres, rgba)


def test_scores_without_ground_truth_are_null_with_a_reason():
    seq = load_sequence(DATA / "spring_gaus")
    s = evaluate_prediction(_perfect_prediction(seq), seq, with_emd=True)
    for key in ("fit_cd", "future_cd", "fit_emd", "baseline_future_cd"):
        assert s[key] is None and "no ground-truth particles" in s["missing"][key]
    assert math.isfinite(s["future_psnr"]) and s["future_psnr"] > 40  # the input images themselves
    assert s["per_frame"]["baseline_cd"]["still"] == [None] * seq.n_frames
    json.dumps(s, allow_nan=False)


def test_scores_with_ground_truth_have_per_frame_baselines():
    seq = load_sequence(DATA / "sgdr_seq")
    s = evaluate_prediction(_perfect_prediction(seq), seq, with_emd=False)
    assert s["fit_cd"] == pytest.approx(0.0, abs=1e-9) and s["missing"]["fit_emd"] == "recon.eval_emd is false"
    for name, per_frame in s["per_frame"]["baseline_cd"].items():
        assert per_frame[: seq.n_fit] == [None] * seq.n_fit
        assert np.mean(per_frame[seq.n_fit :]) == pytest.approx(s["baseline_future_cd_by_variant"][name])


# ------------------------------------------------------------------------------ report.html
class _Text(HTMLParser):
    def __init__(self):
        super().__init__()
        self.ids, self.srcs = [], []

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if "id" in a:
            self.ids.append(a["id"])
        if tag in ("img", "video", "script", "link"):
            self.srcs.append((tag, a.get("src") or a.get("href") or ""))


@pytest.mark.parametrize("fixture", ["sgdr_seq", "spring_gaus"])
def test_report_stage_writes_a_self_contained_page(tmp_path, cfg, fixture):
    from sgdr.pipeline.flow import RunContext, report_produce

    seq = load_sequence(DATA / fixture)
    pred = _perfect_prediction(seq)
    cfg = copy.deepcopy(cfg)
    cfg.recon.write_plys = False  # (the PLYs need the refined Gaussians)
    ctx = RunContext(cfg, seq, None, False)
    rng = np.random.default_rng(0)
    ctx.values.update(
        predict=pred,
        evaluate=strict_json(evaluate_prediction(pred, seq, with_emd=False)),
        dynamics=_dyn(k=rng.uniform(2.5, 3.5, 8)),
        velocity={"v0": [0.1, 0.0, -0.2], "losses": [0.5, 0.4, 0.3], "frames": [1]},
        refine=(None, [0.2, 0.1, 0.05]),
        anchors=rng.random((8, 3)),
    )
    out = tmp_path / "run" / "report"
    out.mkdir(parents=True)
    report_produce(ctx, out, None)
    page = (out / "report.html").read_text()
    parser = _Text()
    parser.feed(page)
    assert parser.ids[:2] == ["verdict", "warnings"]
    assert {"scores", "videos", "losses", "stiffness-field", "identified-parameters"} <= set(parser.ids)
    assert all(src.startswith("data:") for tag, src in parser.srcs), parser.srcs  # nothing external
    assert sum(tag == "video" for tag, _ in parser.srcs) == 2
    if fixture == "spring_gaus":
        assert "cannot be scored geometrically" in page
    state = assert_report_reads_well(out / "report.html")
    assert len(state["images"]) == 3  # metric curves, losses, stiffness
    assert all(v["duration"] >= 4.0 for v in state["videos"])  # 3 and 1 frames, held to last 4 s


def test_a_later_driver_adds_and_replaces_a_section(tmp_path):
    from sgdr.report.html import Section, add_section, paragraph, write_report
    from sgdr.report.verdict import Verdict

    page = write_report(
        tmp_path / "report.html", "run", Verdict("good", "better", "Fit good."), [Section("Scores", "")]
    )
    add_section(page, Section("Posterior", paragraph("first <draft>")))
    add_section(page, Section("Posterior", paragraph("final")))
    text = page.read_text()
    assert text.count('id="posterior"') == 1 and "final" in text and "draft" not in text
    assert text.index('id="scores"') < text.index('id="posterior"') and 'href="#posterior"' in text
    (tmp_path / "other.html").write_text("<html></html>")
    with pytest.raises(ValueError, match="markers missing"):
        add_section(tmp_path / "other.html", Section("x", ""))


def test_metrics_json_is_strict_when_no_pass_ran(cfg, tmp_path):
    from sgdr.pipeline.run import run_metrics
    from sgdr.pipeline.stages import StageResult

    scores = {"future_cd": None, "missing": {"future_cd": "the sequence has no ground-truth particles (gt/)"}}
    dyn = _dyn(pass_losses=[], eval_loss_final=float("nan"))
    stages = {
        name: StageResult(name, value, "digest", tmp_path, False, 1.0)
        for name, value in (("evaluate", scores), ("dynamics", dyn), ("velocity", {"v0": np.zeros(3)}))
    }
    m = run_metrics(cfg, tmp_path, stages, 0.0, 0.0)
    json.dumps(m, allow_nan=False)
    assert m["dynamic_eval_loss_final"] is None and m["missing"]["dynamic_eval_loss_final"] == "not finite (nan)"
    assert m["dynamic_loss_first_pass"] is None and "no dynamic pass ran" in m["missing"]["dynamic_loss_first_pass"]
    assert m["future_cd"] is None and m["missing"]["future_cd"].startswith("the sequence has no ground-truth")
    assert m["identified"]["v0"] == [0.0, 0.0, 0.0]


def test_momentum_audit_in_words(cfg):
    """The predict stage's momentum audit: directed springs (never conserving momentum) get a
    note saying how much they add; springs that should conserve it and do not get a warning."""
    audit = {
        "springs": "directed",
        "springs_dv_max": 3.0,
        "springs_dv_max_along_ground": 0.3,
        "springs_dv_max_along_normal": 2.9,
        "ground_dv_end_along_ground": 0.25,
    }
    assert judge(_scores(future_cd=0.1), _dyn(), cfg.recon, cfg.physics, audit).warnings == []
    note = momentum_note(audit)
    assert "do not conserve momentum" in note and "0.300 scene units/s along the ground" in note
    broken = {**audit, "springs": "symmetric"}
    w = judge(_scores(future_cd=0.1), _dyn(), cfg.recon, cfg.physics, broken).warnings
    assert len(w) == 1 and "a bug" in w[0] and "3.00 scene units/s" in w[0]
    fine = {**broken, "springs_dv_max": 0.5 * cfg.recon.momentum_tolerance}
    assert judge(_scores(future_cd=0.1), _dyn(), cfg.recon, cfg.physics, fine).warnings == []
