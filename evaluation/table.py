"""Results table of reconstruction runs: `python -m evaluation.table RUN_DIR [RUN_DIR ...]`.

Reads each run folder's `metrics.json` (written by `experiments/reconstruct.py`) and prints
one Markdown table, a row per run in the order given: fit (frames 0..n_fit-1, re-simulated
from frame 0) and future (frames n_fit..) Chamfer distance (x1e3), EMD, PSNR, SSIM; the
physics-free baseline's future CD (issue 6's definition: the better of ballistic and held
still); the identified parameters; the run's minutes. A folder without `metrics.json` is
listed as missing rather than skipped, so an unfinished sweep shows what is absent.

    python -m evaluation.table outputs/*_small_s0          # e.g. after `make reproduce`
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

COLUMNS = (
    ("fit CD", "fit_cd", "{:.2f}"),
    ("fit EMD", "fit_emd", "{:.3f}"),
    ("fit PSNR", "fit_psnr", "{:.2f}"),
    ("fit SSIM", "fit_ssim", "{:.3f}"),
    ("future CD", "future_cd", "{:.2f}"),
    ("future EMD", "future_emd", "{:.3f}"),
    ("future PSNR", "future_psnr", "{:.2f}"),
    ("future SSIM", "future_ssim", "{:.3f}"),
    ("baseline future CD", "baseline_future_cd", "{:.2f}"),
)


def _fmt(fmt: str, value) -> str:
    return "-" if value is None else fmt.format(value)


def identified_text(ident: dict) -> str:
    """The identified values of one run in a few words, whichever model made it."""
    if not ident:
        return "-"
    if "log10_k_mean" in ident:  # the spring-mass model
        return (
            f"log10 k {ident['log10_k_mean']:.2f} ± {ident['log10_k_std']:.2f}, κ {ident['kappa']:.2f}, "
            f"μ {ident['friction']:.2f}, e {ident['restitution']:.2f}"
        )
    if "E" in ident:  # the PAC-NeRF baseline
        return f"E {ident['E']:.3g} Pa, ν {ident['nu']:.2f}"
    return ", ".join(f"{k} {v:.3g}" for k, v in ident.items() if isinstance(v, (int, float))) or "-"


def row(metrics: dict) -> list[str]:
    """Table cells of one run's metrics.json."""
    params = identified_text(metrics.get("identified", {}))
    return [
        str(metrics.get("sequence_name", metrics.get("object", "?"))),
        *(_fmt(fmt, metrics.get(key)) for _, key, fmt in COLUMNS),
        params,
        _fmt("{:.1f}", metrics.get("minutes")),
    ]


def table(run_dirs: list[Path]) -> str:
    head = ["object", *(name for name, _, _ in COLUMNS), "identified", "minutes"]
    lines = ["| " + " | ".join(head) + " |", "|" + " --- |" * len(head)]
    for d in run_dirs:
        path = Path(d) / "metrics.json"
        if path.is_file():
            cells = row(json.loads(path.read_text()))
        else:
            cells = [f"{Path(d).name}: no metrics.json"] + ["-"] * (len(head) - 1)
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv: list[str]) -> int:
    if not argv:
        print(__doc__, file=sys.stderr)
        return 2
    print(table([Path(a) for a in argv]))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
