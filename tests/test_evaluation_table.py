"""The results table of `python -m evaluation.reproduce.run_table` (the seven-object table of docs/reconstruction-results.md)."""

import json

from evaluation.reproduce.run_table import table


def test_table_has_a_row_per_run_and_marks_missing_ones(tmp_path):
    run = tmp_path / "torus_small_s0"
    run.mkdir()
    metrics = {
        "object": "torus",
        "fit_cd": 0.804,
        "fit_emd": 0.0375,
        "fit_psnr": 24.936,
        "fit_ssim": 0.8904,
        "future_cd": 2.18,
        "future_emd": 0.0796,
        "future_psnr": 17.87,
        "future_ssim": 0.8116,
        "baseline_future_cd": 2.03,
        "minutes": 9.36,
        "identified": {
            "log10_k_mean": 3.27,
            "log10_k_std": 0.167,
            "kappa": 0.06,
            "friction": 0.84,
            "restitution": 0.35,
        },
    }
    (run / "metrics.json").write_text(json.dumps(metrics))
    lines = table([run, tmp_path / "cross_small_s0"]).splitlines()
    assert len(lines) == 4
    cells = [c.strip() for c in lines[2].strip("|").split("|")]
    assert cells[:10] == ["torus", "0.80", "0.037", "24.94", "0.890", "2.18", "0.080", "17.87", "0.812", "2.03"]
    assert cells[-1] == "9.4" and "log10 k 3.27 ± 0.17" in cells[10]
    assert lines[3].startswith("| cross_small_s0: no metrics.json")
