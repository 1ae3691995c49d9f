# pdr: `make` runs the pipeline on raw/, `make test` runs the tests.
# Both create their own virtual environment on a fresh machine.

PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
PDR    := $(VENV)/bin/pdr
STAMP  := $(VENV)/.installed-stamp

.PHONY: all run test test-all test-fast bench bench-discovery bench-discovery-shipped bench-calibration gate setup clean bytecode mutation

all: run

include firmware/firmware.mk

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[test]'
	$(PY) -m pipeline.model.compile
	$(PY) -m pipeline.ingest.compile
	touch $(STAMP)

setup: $(STAMP)

# Byte-compile the package (only what changed): where PYTHONDONTWRITEBYTECODE is set, as on these
# machines, every process would otherwise recompile every pipeline module on import (~0.15 s each
# for pdr run's main process and its forkserver, every run).
bytecode: $(STAMP)
	@$(PY) -m compileall -q pipeline

run: bytecode
	$(PDR) run

# The headless Rerun viewer test needs a Vulkan driver, Mesa's software one (lavapipe): .ci/run installs it;
# without it that one test is skipped with the reason in the summary.  `make test` leaves out the tests
# marked `long` (whole discoveries re-run for a search path; the matrices are `make bench-discovery`);
# `make test-all` runs them too, and CI runs it.
test: bytecode
	WGPU_BACKEND=vulkan $(PY) -m pytest -n 2 -q -m "not long"

test-all: bytecode
	WGPU_BACKEND=vulkan $(PY) -m pytest -n 2 -q

test-fast: bytecode
	$(PY) -m pytest -n 2 -q -m "not slow and not viewer and not long"

gate: bytecode
	$(PDR) gate

bench: bytecode
	$(PY) -m benchmarks.run_all

bench-discovery: bytecode
	$(PY) -m benchmarks.discovery_matrix

# pdr calibrate on six rigs off Table I (fresh seed, printed): calibration, then discovery on new recordings
bench-calibration: bytecode
	$(PY) -m benchmarks.bench_calibration

bench-discovery-shipped: bytecode
	$(PY) -m benchmarks.discovery_matrix --shipped

# Mutation testing of derive/, validate/, discover/search.py and criterion.py (pyproject [tool.mutmut]); not part of
# `make test`: hours on two cores.  MUTANTS narrows it, e.g. make mutation MUTANTS='pipeline.derive.energy*'.
# Results: mutants/ (`.venv/bin/mutmut results`, `mutmut show NAME`); the last score is in docs/MUTATION.md.
MUTANTS ?=
MUTATION_JOBS ?= 2
mutation: bytecode
	$(PY) -m pip install -q -e '.[test,mutation]'
	$(VENV)/bin/mutmut run --max-children $(MUTATION_JOBS) $(MUTANTS)

clean:
	rm -rf processed
