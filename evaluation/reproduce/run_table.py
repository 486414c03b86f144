"""Results table of reconstruction runs: `python -m evaluation.reproduce.run_table RUN_DIR [RUN_DIR ...]`.

Reads each run folder's `metrics.json` (written by `experiments/reconstruct.py`) and prints
one Markdown table, a row per run in the order given: fit (frames 0..n_fit-1, re-simulated
from frame 0) and future (frames n_fit..) Chamfer distance (x1e3), EMD, PSNR, SSIM; the
physics-free baseline's future CD (issue 6's definition: the better of ballistic and held
still); the identified parameters; the run's minutes. A folder without `metrics.json` is
listed as missing rather than skipped, so an unfinished sweep shows what is absent. The scores
and their formats are the paper tables' (`evaluation.reproduce.tables`).

    python -m evaluation.reproduce.run_table outputs/*_small_s0          # e.g. after `make reproduce`
"""

from __future__ import annotations

import sys
from pathlib import Path

from evaluation.reproduce.cells import read_metrics
from evaluation.reproduce.formats import fmt_value, markdown_table
from evaluation.reproduce.tables import (
    BASELINE_FUTURE_CD,
    FIT_CD,
    FIT_EMD,
    FIT_PSNR,
    FIT_SSIM,
    FUTURE_CD,
    FUTURE_EMD,
    FUTURE_PSNR,
    FUTURE_SSIM,
)

MISSING = "-"
# (column header, score)
COLUMNS = (
    ("fit CD", FIT_CD),
    ("fit EMD", FIT_EMD),
    ("fit PSNR", FIT_PSNR),
    ("fit SSIM", FIT_SSIM),
    ("future CD", FUTURE_CD),
    ("future EMD", FUTURE_EMD),
    ("future PSNR", FUTURE_PSNR),
    ("future SSIM", FUTURE_SSIM),
    ("baseline future CD", BASELINE_FUTURE_CD),
)


def identified_text(ident: dict) -> str:
    """The identified values of one run in a few words, whichever model made it."""
    if not ident:
        return MISSING
    if "log10_k_mean" in ident:  # the spring-mass model
        return (
            f"log10 k {ident['log10_k_mean']:.2f} ± {ident['log10_k_std']:.2f}, κ {ident['kappa']:.2f}, "
            f"μ {ident['friction']:.2f}, e {ident['restitution']:.2f}"
        )
    if "E" in ident:  # the PAC-NeRF baseline
        return f"E {ident['E']:.3g} Pa, ν {ident['nu']:.2f}"
    return ", ".join(f"{k} {v:.3g}" for k, v in ident.items() if isinstance(v, (int, float))) or MISSING


def row(metrics: dict) -> list[str]:
    """Table cells of one run's metrics.json."""
    params = identified_text(metrics.get("identified", {}))
    return [
        str(metrics.get("sequence_name", metrics.get("object", "?"))),
        *(fmt_value(m.fmt, metrics.get(m.key), MISSING) for _, m in COLUMNS),
        params,
        fmt_value("{:.1f}", metrics.get("minutes"), MISSING),
    ]


def table(run_dirs: list[Path]) -> str:
    header = ["object", *(name for name, _ in COLUMNS), "identified", "minutes"]
    rows = []
    for d in run_dirs:
        metrics = read_metrics(d)
        if metrics is not None:
            rows.append(row(metrics))
        else:
            rows.append([f"{Path(d).name}: no metrics.json"] + [MISSING] * (len(header) - 1))
    return "\n".join(markdown_table(header, rows))


def main(argv: list[str]) -> int:
    if not argv or argv[0] in ("-h", "--help"):
        print(__doc__, file=sys.stderr)
        return 0 if argv else 2
    print(table([Path(a) for a in argv]))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
