# sgdr: the commands a user types. `make setup` then `make test` is all CI runs.
# The virtual environment made by `make setup`; falls back to python3 when there is none.
PYTHON ?= $(shell [ -x .venv/bin/python ] && echo .venv/bin/python || echo python3)
BENCH ?=
PRESET ?= small

.PHONY: setup test test-all bench data demo reproduce oracle posterior diagnose diagnose-suite clean help

help:
	@echo "make setup      install libLLVM + sgdr with pinned dependencies (idempotent)"
	@echo "make test       lint (ruff check, ruff format --check) and run the test suite on the tiny preset"
	@echo "make bench      run benchmarks, one JSON line each (BENCH=sim|render|... for one)"
	@echo "make data       generate the 7-object benchmark at the small preset into data/"
	@echo "make demo       generate + reconstruct + predict + evaluate the torus (small preset)"
	@echo "make reproduce  the paper's Tables 1-3 (docs/reproduce.md): every method on every object (Hydra multirun, 2 jobs), then results/tables.*"
	@echo "make oracle     the spring-mass model fitted to the torus's ground-truth particle tracks (OBJECT=...)"
	@echo "make posterior  posterior of a finished run's physics from its rendered images (RUN=outputs/torus_small_s0, SEQUENCE= a twin)"
	@echo "make diagnose   which model extension a finished run's data ask for (RUN=, SEQUENCE=)"
	@echo "make diagnose-suite  the diagnosis on injected and null MPM cases (resumable; hours), then its bars"

setup:
	bash scripts/setup.sh

test:
	$(PYTHON) -m ruff check .
	$(PYTHON) -m ruff format --check .
	$(PYTHON) -m pytest -q tests

bench:
	$(PYTHON) -m evaluation.bench $(BENCH)

# The 8-object benchmark (docs/benchmark-objects.md) at the small preset (128x128, 10 views, 30 frames) into data/;
# complete sequences are skipped.
data:
	$(PYTHON) experiments/generate.py preset=$(PRESET) synth.object=all data_dir=data

# The default method (conf/method/spring_gaus.yaml) at the small preset; METHOD=official for the
# official code's method.
METHOD ?= spring_gaus
# the run folders' <preset>[_<method>] part (sgdr.run_folder.default_run_name)
RUN_TAG = $(PRESET)$(if $(filter spring_gaus,$(METHOD)),,_$(METHOD))
demo:
	$(PYTHON) experiments/reconstruct.py preset=small method=$(METHOD) synth.object=torus

# The paper's Tables 1-3 (docs/reproduce.md): every (method, object) cell the tables need, generated and
# reconstructed through Hydra multiruns (LAUNCHER=joblib with JOBS processes locally; submitit_local,
# submitit_slurm or slurm on a cluster), finished cells skipped, a progress line per finished cell; then
# results/tables.md, table{1,2,3}.csv, tables.json, tables.html (results/<preset>/ for another preset).
# Methods not in this checkout stay "missing". METHODS=a,b / OBJECTS=a,b narrow the cells run; ARGS= more
# options or overrides for every run (e.g. ARGS="--rerun" or ARGS="recon.iterations=10").
LAUNCHER ?= joblib
JOBS ?= 2
METHODS ?=
OBJECTS ?=
ARGS ?=
reproduce:
	$(PYTHON) -m evaluation.reproduce --preset $(PRESET) --launcher $(LAUNCHER) --jobs $(JOBS) \
		$(if $(METHODS),--methods $(METHODS),) $(if $(OBJECTS),--objects $(OBJECTS),) $(ARGS)

# The identification upper bound: the model fitted to the generator's particle tracks instead of
# images (docs/reconstruction-results.md). About 2.5 min for the small torus on the 2-core machine.
OBJECT ?= torus
oracle:
	$(PYTHON) experiments/oracle.py preset=$(PRESET) method=$(METHOD) synth.object=$(OBJECT)

# The posterior of a finished run's physics (docs/posterior.md): a global log10 k shift, kappa,
# friction, restitution from the rendered images (emcee on a checked Gaussian-process surrogate
# started from the run's global search); writes <run>/posterior/ and adds a section to the
# run's report.html. Default: the demo's run. SEQUENCE= observes another sequence (e.g. a twin).
# ENSEMBLE=a,b: combine RUN's finished posterior with those of other runs of its sequence (other
# seeds) into one forecast instead (sgdr/posterior/ensemble.py; writes <RUN>/posterior_ensemble/).
RUN ?= outputs/torus_$(RUN_TAG)_s0
SEQUENCE ?=
ENSEMBLE ?=
posterior:
	$(PYTHON) experiments/posterior.py preset=$(PRESET) method=$(METHOD) posterior.run=$(RUN) \
		$(if $(SEQUENCE),posterior.sequence=$(SEQUENCE),) $(if $(ENSEMBLE),'posterior.ensemble=[$(ENSEMBLE)]',)

# Which model extension a finished run's data ask for (docs/discrepancy.md): air drag, gravity's
# magnitude, the ground's height, fitted on half the views and judged on the other half.
diagnose:
	$(PYTHON) experiments/diagnose.py preset=$(PRESET) method=$(METHOD) diagnose.run=$(RUN) \
		$(if $(SEQUENCE),diagnose.sequence=$(SEQUENCE),)

# The diagnosis suite (docs/discrepancy.md): injected-effect and null MPM sequences generated,
# reconstructed and diagnosed one after another; finished cases are skipped, so it resumes.
# Hours at small on 2 cores; results in results/diagnose_suite_<preset>.jsonl. MAX_CASES=n stops after n.
MAX_CASES ?= 0
diagnose-suite:
	$(PYTHON) -m evaluation.studies.diagnose_suite --preset $(PRESET) --max-cases $(MAX_CASES)
	$(PYTHON) -m evaluation.studies.diagnose_suite --preset $(PRESET) --summary

clean:
	rm -rf outputs multirun .pytest_cache

distclean: clean
	rm -rf .venv
