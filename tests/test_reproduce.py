"""`python -m evaluation.reproduce` (`make reproduce`): the paper's Tables 1-3 from the run folders.

Fast: the table writer on synthetic metrics.json files (the means, the PAC-NeRF / Spring-Gaus
ratio, Table 3's direction, a missing run, a method not in the checkout, a null score with its
reason; the four files). Slow: the multirun itself through submitit's local executor
(`hydra/launcher=submitit_local`) at tiny on two methods x one object, then the tables with those
cells filled from the runs and every other cell marked missing.
"""

import csv
import json
import math

import pytest

from evaluation.reproduce.cells import DEFAULT_METHOD, collect, run_dir_name
from evaluation.reproduce.cli import main
from evaluation.reproduce.formats import write_tables
from evaluation.reproduce.launch import needed_cells, plan_multiruns
from evaluation.reproduce.tables import MEAN, OBJECTS, TABLES

SCORES = ("fit_cd", "fit_emd", "fit_psnr", "fit_ssim", "future_cd", "future_emd", "future_psnr", "future_ssim")


def write_run(out, method, obj, preset="tiny", missing=None, commit="abc123", **scores):
    """A run folder with a metrics.json as the pipeline writes it (null + reason for `missing`)."""
    d = out / run_dir_name(obj, preset, method, 0)
    d.mkdir(parents=True)
    metrics = {k: scores.get(k, 1.0) for k in SCORES}
    for key in missing or {}:
        metrics[key] = None
    metrics.update(missing=dict(missing or {}), minutes=0.5, provenance={"git_commit": commit})
    (d / "metrics.json").write_text(json.dumps(metrics))
    return d


@pytest.fixture
def conf(tmp_path):
    """A conf/ with the methods that 'exist': everything but deform4d."""
    (tmp_path / "conf" / "method").mkdir(parents=True)
    for m in ("spring_gaus", "pacnerf", "dyngaus", "no_soft_vector", "single_k"):
        (tmp_path / "conf" / "method" / f"{m}.yaml").write_text(f"method: {m}\n")
    return tmp_path / "conf"


def by_key(res):
    return {(c.table, c.metric, c.method, c.obj): c for c in res.cells}


def test_run_dir_name_is_the_pipelines_rule():
    from types import SimpleNamespace

    from sgdr.run_folder import DEFAULT_METHOD as RUN_DEFAULT_METHOD
    from sgdr.run_folder import default_run_name

    assert RUN_DEFAULT_METHOD == DEFAULT_METHOD
    for method in ("spring_gaus", "pacnerf"):
        cfg = SimpleNamespace(
            method=method,
            preset="small",
            seed=3,
            sequence="",
            data_dir="data",
            synth=SimpleNamespace(object="cream"),
            recon=SimpleNamespace(run_name=""),
        )
        assert default_run_name(cfg) == run_dir_name("cream", "small", method, 3)


def test_tables_means_ratio_direction_and_missing_cells(tmp_path, conf):
    out = tmp_path / "outputs"
    for i, obj in enumerate(OBJECTS):  # Spring-Gaus future CD 1..7 (mean 4), PAC-NeRF twice that
        write_run(out, "spring_gaus", obj, future_cd=i + 1.0, fit_cd=0.1 * (i + 1))
        write_run(out, "pacnerf", obj, future_cd=2.0 * (i + 1), fit_cd=1.0)
    for obj in OBJECTS[:6]:  # Dy-Gaus has no future (fit-only); banana was never run
        write_run(out, "dyngaus", obj, missing={"future_cd": "fit frames only: no simulation to predict with"})
    (out / run_dir_name("torus_hetero", "tiny", "single_k", 0)).mkdir()  # started, never finished
    write_run(out, "spring_gaus", "torus_hetero", fit_cd=0.5, future_cd=3.0, commit="old")
    write_run(out, "no_soft_vector", "torus_hetero", fit_cd=0.4, future_cd=4.0)
    write_run(out, "pacnerf", "torus_hetero", fit_cd=2.0, future_cd=None, missing={"future_cd": "diverged"})

    res = collect(out, "tiny", 0, conf_dir=conf, meta={"commit": "abc123"})
    cells = by_key(res)

    # means over the seven objects, beside the paper's
    mean = cells[(1, "future_cd", "spring_gaus", MEAN)]
    assert mean.status == "ok" and math.isclose(mean.value, 4.0) and mean.paper == 5.16
    assert math.isclose(cells[(2, "fit_cd", "spring_gaus", MEAN)].value, 0.4)
    assert cells[(1, "future_cd", "spring_gaus", "banana")].paper == 18.48
    # PAC-NeRF / Spring-Gaus mean future CD: 8 / 4 measured, 17.94 / 5.16 in the paper
    assert math.isclose(res.ratio["measured"], 2.0) and math.isclose(res.ratio["paper"], 17.94 / 5.16)
    assert "2.00x lower" in res.ratio["sentence"]

    # a missing run: the cell and the mean say so, no number
    banana = cells[(2, "fit_cd", "dyngaus", "banana")]
    assert banana.status == "missing" and banana.value is None and "not run" in banana.reason
    dmean = cells[(2, "fit_cd", "dyngaus", MEAN)]
    assert dmean.value is None and dmean.reason == "1 of 7 objects have no number"
    # a method not in this checkout
    assert "no conf/method/deform4d.yaml" in cells[(2, "fit_emd", "deform4d", "torus")].reason
    # a started run without metrics.json
    assert "unfinished or failed" in cells[(3, "fit_cd", "single_k", "torus_hetero")].reason
    # a null score shows the run's reason
    null = cells[(3, "future_cd", "pacnerf", "torus_hetero")]
    assert (null.status, null.value, null.reason) == ("null", None, "diverged")

    # Table 3's direction among the methods that have the number, and the paper's
    d = res.direction
    assert d["fit_cd"]["order"] == ["no_soft_vector", "spring_gaus", "pacnerf"]
    assert d["future_cd"]["lowest"] == "spring_gaus" and d["future_cd"]["without_number"] == ["single_k", "pacnerf"]
    assert d["fit_cd"]["paper_lowest"] == "spring_gaus"
    assert d["future_cd"]["paper_order"] == ["spring_gaus", "pacnerf", "single_k", "no_soft_vector"]

    # the files
    paths = write_tables(res, tmp_path / "results")
    assert [p.name for p in paths] == [
        "tables.md",
        "table1.csv",
        "table2.csv",
        "table3.csv",
        "tables.json",
        "tables.html",
    ]
    md = (tmp_path / "results" / "tables.md").read_text()
    assert "| future CD (x1e3) | Spring-Gaus (ours) | 1.00 (2.38) |" in md
    assert "| fit CD (x1e3) | Dy-Gaus [26], simplified | 1.00 (579.00) |" in md
    assert "n/a [2] (5.70)" in md and "[2] diverged" in md  # Table 3: the null cell and its footnote
    assert "torus_hetero_tiny_s0 (old)" in md  # a run made on another commit is named
    rows = list(csv.DictReader(open(tmp_path / "results" / "table3.csv")))
    assert len(rows) == 4 * 6 and rows[0]["run"].endswith("torus_hetero_tiny_s0")
    data = json.loads((tmp_path / "results" / "tables.json").read_text())
    assert data["commit"] == "abc123" and [t["number"] for t in data["tables"]] == [1, 2, 3]
    cell = next(c for c in data["tables"][0]["cells"] if c["method"] == "spring_gaus" and c["object"] == "torus")
    assert cell["run_commit"] == "abc123" and cell["value"] == 1.0
    assert data["runs"]["deform4d/torus"]["finished"] is False
    page = (tmp_path / "results" / "tables.html").read_text()
    assert page.startswith("<!DOCTYPE html>") and "Table 3: Ablation" in page and "<script" not in page


def test_the_ratio_is_not_made_up_from_part_of_the_objects(tmp_path, conf):
    out = tmp_path / "outputs"
    for obj in OBJECTS:
        write_run(out, "spring_gaus", obj, future_cd=3.0)
    write_run(out, "pacnerf", "torus", future_cd=1.5)
    res = collect(out, "tiny", 0, conf_dir=conf)
    assert res.ratio["measured"] is None and "Not measured" in res.ratio["sentence"]
    # measured as it is, whichever way it goes
    for obj in OBJECTS[1:]:
        write_run(out, "pacnerf", obj, future_cd=1.5)
    res = collect(out, "tiny", 0, conf_dir=conf)
    assert math.isclose(res.ratio["measured"], 0.5) and "2.00x higher" in res.ratio["sentence"]


def test_cells_are_grouped_into_exact_sweeps():
    cells = needed_cells()
    assert len(cells) == 4 * 7 + 4  # Tables 1+2: 4 methods x 7 objects; Table 3: 4 methods on torus_hetero
    plans = plan_multiruns(cells)
    assert sorted((m, o) for methods, objs in plans for m in methods for o in objs) == sorted(cells)
    assert plans[0] == (("spring_gaus", "pacnerf", "dyngaus", "deform4d"), OBJECTS)
    assert plans[1] == (("spring_gaus", "no_soft_vector", "single_k", "pacnerf"), ("torus_hetero",))
    narrow = needed_cells(methods=["spring_gaus", "single_k"], objects=["torus", "torus_hetero"])
    assert plan_multiruns(narrow) == [(("spring_gaus",), ("torus",)), (("spring_gaus", "single_k"), ("torus_hetero",))]
    assert all(spec.paper for spec in TABLES)


@pytest.mark.slow
def test_multirun_through_submitit_local_fills_its_cells(tmp_path, capsys):
    """Two methods x one object at tiny (fewer iterations), run by Hydra's submitit local launcher."""
    pytest.importorskip("hydra_plugins.hydra_submitit_launcher")
    out, results = tmp_path / "outputs", tmp_path / "results"
    argv = [
        "--preset=tiny",
        "--launcher=submitit_local",
        "--methods=spring_gaus,no_soft_vector",
        "--objects=torus_hetero",
        f"--output-dir={out}",
        f"--data-dir={tmp_path / 'data'}",
        f"--results={results}",
        f"tracking.uri=sqlite:///{tmp_path / 'mlflow.db'}",
        "static_fit.iterations=60",
        "recon.iterations=2",
        "recon.refine_iterations=10",
        "recon.v0_iterations=8",
    ]
    assert main(argv) == 0
    printed = capsys.readouterr().out
    assert "[reproduce] 1/2 " in printed and "[reproduce] 2/2 " in printed  # a progress line per cell
    assert "launcher submitit_local" in printed
    assert (out / "multirun" / ".submitit").is_dir()  # the jobs went through submitit's local executor

    data = json.loads((results / "tables.json").read_text())
    t3 = {(c["method"], c["metric"]): c for c in data["tables"][2]["cells"]}
    for method in ("spring_gaus", "no_soft_vector"):
        run = json.loads((out / run_dir_name("torus_hetero", "tiny", method, 0) / "metrics.json").read_text())
        for key in ("fit_cd", "fit_psnr", "fit_ssim", "future_cd", "future_psnr", "future_ssim"):
            cell = t3[(method, key)]
            assert cell["status"] == "ok" and cell["value"] == run[key], (method, key)
            assert cell["run_commit"] == run["provenance"]["git_commit"]
    for method in ("single_k", "pacnerf"):
        assert t3[(method, "fit_cd")]["status"] == "missing" and t3[(method, "fit_cd")]["value"] is None
    assert all(c["status"] == "missing" for c in data["tables"][0]["cells"])  # no Table 1 object was run
    assert data["direction"]["fit_cd"]["order"] and set(data["direction"]["fit_cd"]["order"]) <= {
        "spring_gaus",
        "no_soft_vector",
    }
    assert any("reconstruct.py -m" in c and "hydra/launcher=submitit_local" in c for c in data["multirun_commands"])

    # a second call skips the finished cells and runs nothing
    assert main(argv) == 0
    again = capsys.readouterr().out
    assert "2/2 cells finished before, skipped" in again and "multirun:" not in again
