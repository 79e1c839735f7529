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

.PHONY: all demo test lint bench golden install clean

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

# Round trip of one sample through the readers and writers (until extract/bake exist).
ROUNDTRIP = import sys; from staggered_cli.cli.options import load_input; from staggered_cli.io import files; \
  from staggered_cli.motion import BvhMotion; src, dst = sys.argv[1:]; m = load_input(src); \
  from staggered_cli.io.bvh import bvh_bytes; from staggered_cli.io.c3d import c3d_bytes; \
  files.write_atomic(dst, (bvh_bytes if isinstance(m, BvhMotion) else c3d_bytes)(m), force=True)

demo: $(STAMP)
	@if [ -z "$(SAMPLES)" ]; then echo "no samples in data/samples/" >&2; exit 1; fi
	@mkdir -p $(DEMO_OUT)
	@set -e; for f in $(SAMPLES); do \
	  out=$(DEMO_OUT)/$$(basename $$f); \
	  echo "== staggered info $$f"; \
	  $(BIN)/staggered info $$f; \
	  echo "== round trip $$f -> $$out"; \
	  $(BIN)/python -c '$(ROUNDTRIP)' $$f $$out; \
	  $(BIN)/staggered info --json $$f > $$out.info.json; \
	  $(BIN)/staggered info --json $$out > $$out.roundtrip.info.json; \
	  if cmp -s $$f $$out; then echo "   byte-identical"; \
	  elif diff -u $$out.info.json $$out.roundtrip.info.json; then echo "   same info (bytes differ)"; \
	  else echo "   round trip changed $$f" >&2; exit 1; fi; \
	done

clean:
	rm -rf out build *.egg-info .pytest_cache .ruff_cache
