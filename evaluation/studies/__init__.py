"""Studies: each answers a question about the method, on sgdr's runs or its twins, rather than
reconstructing an object. One module each, run as `python -m evaluation.studies.<name>`:

- `oracle` (+ its config schema `config`): the spring-mass model fitted to the generator's
  particle tracks, an upper bound on identification from images (`experiments/oracle.py`,
  `make oracle`: a Hydra driver like the others);
- `baseline_twins`: the Table 2 baselines on their twins, with variants;
- `calibrate_posterior`: simulation-based calibration of the posterior on twin sequences;
- `posterior_objects`: the posterior on the seven MPM objects (coverage, future CD);
- `diagnose_suite`: the diagnosis on injected and null MPM cases (`make diagnose-suite`);
- `discrepancy_profile`: the diagnosis's discrepancy of a run at fixed physics settings;
- `refit_gain`: what the diagnosis's refits buy in the future;
- `search_choice`: which of the global search's candidates the asset should start from;
- `realcap_check`: how well a simulated real capture's reconstruction recovered its truth.

The diagnosis suite is a study like the others (it measures whether the diagnosis names injected
effects and stays silent on nulls, as `calibrate_posterior` measures the posterior), and the
studies share its JSON-lines results (`posterior_objects` reads them with its `read_results`),
so it lives here rather than in a folder of its own.
"""
