"""The paper's Tables 1-3 reproduced from sgdr's runs (`python -m evaluation.reproduce`, `make
reproduce`; docs/reproduce.md), one module per job:

- `tables`: the tables as data (`TABLES`: methods, objects, scores; the paper's numbers);
- `cells`: each cell's run folder and metrics.json, the means, what the tables say;
- `launch`: the runs behind the cells (Hydra multiruns of `experiments/`, the launchers);
- `formats`: the Markdown, CSV, JSON and HTML writers;
- `provenance`: this checkout's commit, the machine, the command, the runs' own commits;
- `cli`: the command line (`__main__`);
- `run_table`: one Markdown row per run folder, for any runs (`python -m
  evaluation.reproduce.run_table RUN_DIR ...`).
"""
