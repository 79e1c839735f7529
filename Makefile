# make demo   set up .venv and run the tool on the bundled samples
# make test   set up .venv and run the tests
# make lint   ruff
# make bench  run every bench/*.py
# make golden regenerate tests/golden/ on purpose (tests never do)

SHELL := /bin/bash
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
# the project is (re)installed into the venv only when pyproject.toml changes
STAMP := $(VENV)/.staggered-installed
SAMPLES = $(sort $(wildcard data/samples/*.bvh data/samples/*.c3d))
BENCHES = $(sort $(wildcard bench/*.py))
DEMO_OUT := out/demo
PYTEST_ARGS ?=

.PHONY: all demo test lint bench golden install clean samples

all: test

$(BIN)/python:
	$(PYTHON) -m venv $(VENV) || { echo "could not create $(VENV): install Python's venv module (Debian: python3-venv)" >&2; exit 1; }

$(STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install -e '.[dev]'
	touch $@

install: $(STAMP)

test: $(STAMP)
	$(BIN)/python -m pytest $(PYTEST_ARGS)

lint: $(STAMP)
	$(BIN)/ruff check .

bench: $(STAMP)
	@if [ -z "$(BENCHES)" ]; then echo "no bench/*.py scripts yet"; fi
	@set -e; for script in $(BENCHES); do echo "== $$script"; $(BIN)/python $$script; done

golden: $(STAMP)
	$(BIN)/python tests/make_golden.py

# The main job on the bundled sample: extract staggered poses, look at them,
# cull, loosen the arm timing with succession, exaggerate a pose, bake.
S := $(BIN)/staggered
demo: $(STAMP)
	@if [ -z "$(SAMPLES)" ]; then echo "no samples in data/samples/" >&2; exit 1; fi
	@mkdir -p $(DEMO_OUT)
	$(S) extract data/samples/march.bvh -o $(DEMO_OUT)/march.stag --force
	$(S) info $(DEMO_OUT)/march.stag
	$(S) cull $(DEMO_OUT)/march.stag --keep 50% -o - \
	  | $(S) succession - --joint LeftArm --offset 0.03 --power 1.5 --clamp -o - \
	  | $(S) succession - --joint RightArm --offset 0.03 --power 1.5 --clamp -o $(DEMO_OUT)/march_loose.stag --force
	$(S) bake $(DEMO_OUT)/march_loose.stag -o $(DEMO_OUT)/march_loose.bvh --force
	$(S) edit-pose $(DEMO_OUT)/march.stag --pose 3 --exaggerate 1.5 --relative-to average -o - \
	  | $(S) bake - -o $(DEMO_OUT)/march_exaggerated.bvh --force
	$(S) extract data/samples/march.c3d -o - | $(S) bake - -o $(DEMO_OUT)/march.c3d --force
	$(S) bake $(DEMO_OUT)/march.stag -o $(DEMO_OUT)/march_roundtrip.bvh --force
	@cmp -s data/samples/march.bvh $(DEMO_OUT)/march_roundtrip.bvh && echo "round trip: $(DEMO_OUT)/march_roundtrip.bvh is byte-identical to the sample"
	@echo "wrote $(DEMO_OUT)/: march.stag, march_loose.bvh, march_exaggerated.bvh, march.c3d"

samples: $(STAMP)
	$(BIN)/python data/samples/make_samples.py

clean:
	rm -rf out build *.egg-info .pytest_cache .ruff_cache
