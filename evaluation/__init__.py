"""Research on sgdr, apart from the product (run from the repo root):

- `evaluation/bench/`: the benchmarks (`python -m evaluation.bench [NAME ...]`, `make bench`);
- `evaluation/reproduce/`: the paper's Tables 1-3 from sgdr's runs (`python -m evaluation.reproduce`,
  `make reproduce`) and the results table of any run folders (`python -m evaluation.reproduce.run_table`);
- `evaluation/studies/`: studies that answer a question about the method (`python -m
  evaluation.studies.<name>`; the oracle through `experiments/oracle.py`, `make oracle`).

sgdr never imports this package.
"""

from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent  # the repository (conf/, experiments/, results/)
