# pdr: `make` runs the pipeline on raw/, `make test` runs the tests.
# Both create their own virtual environment on a fresh machine.

PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
PDR    := $(VENV)/bin/pdr
STAMP  := $(VENV)/.installed-stamp

.PHONY: all run test test-fast bench bench-discovery gate setup clean viewer-deps

all: run

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[test]'
	$(PY) -m pipeline.model.compile
	touch $(STAMP)

setup: $(STAMP)

# The headless Rerun viewer test needs a Vulkan driver: Mesa's software one (lavapipe).
SUDO := $(shell [ "$$(id -u)" = 0 ] || echo sudo)
viewer-deps:
	@if ! ls /usr/share/vulkan/icd.d/lvp_icd.*.json >/dev/null 2>&1; then \
	  echo "installing mesa-vulkan-drivers (software Vulkan for the headless viewer test)"; \
	  $(SUDO) apt-get update -qq && DEBIAN_FRONTEND=noninteractive $(SUDO) apt-get install -y -qq mesa-vulkan-drivers; \
	fi

run: $(STAMP)
	$(PDR) run

test: $(STAMP) viewer-deps
	WGPU_BACKEND=vulkan $(PY) -m pytest -n 2 -q

test-fast: $(STAMP)
	$(PY) -m pytest -n 2 -q -m "not slow and not viewer"

gate: $(STAMP)
	$(PDR) gate

bench: $(STAMP)
	$(PY) -m benchmarks.run_all

bench-discovery: $(STAMP)
	$(PY) -m benchmarks.discovery_matrix

clean:
	rm -rf processed
