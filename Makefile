# make demo   set up .venv and run the tool on the bundled samples
# make test   set up .venv and run the tests
# make lint   ruff
# make bench  run every bench/*.py
# make golden regenerate tests/golden/ on purpose (tests never do)
# make test-blender  set up .venv-blender (Python 3.11, bpy 5.0.1) and run the Blender round trip tests
# make test-gltf  install node (apt, as root, if missing) and the Khronos glTF-Validator (tools/gltf), run its tests
# make test-browser  install chromium (apt, as root, if missing), Playwright and tools/view; run the browser tests
# make view-bundle  rebuild staggered_cli/viewer/vendor/three.min.js from the pinned three and esbuild (tools/view)
# make screenshots  regenerate docs/pictures/view.png, the README's picture of `staggered view` (review it first)
# make batch  IN=dir OUT=dir [STEPS='cull --keep 30%|...']: staggered batch over a library

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
# tests run on this many processes (pytest-xdist), each module on one of them
# (its module fixtures are built once); TEST_WORKERS=0 runs them in this one
TEST_WORKERS ?= 2

.PHONY: all demo test test-blender test-gltf test-browser view-bundle screenshots chromium lint bench golden install clean batch samples pictures

all: test

$(BIN)/python:
	$(PYTHON) -m venv $(VENV) || { echo "could not create $(VENV): install Python's venv module (Debian: python3-venv)" >&2; exit 1; }

$(STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install -e '.[dev]'
	touch $@

# Bytecode for the package: an editable install writes none, and where
# PYTHONDONTWRITEBYTECODE is set (containers often set it) Python would
# compile every module at every start, about 35 ms a process.  Only the
# files changed since their bytecode are compiled again.
BYTECODE = $(BIN)/python -m compileall -q staggered_cli

install: $(STAMP)
	@$(BYTECODE)

test: $(STAMP)
	@$(BYTECODE)
	$(BIN)/python -m pytest -n $(TEST_WORKERS) --dist loadfile $(PYTEST_ARGS)

# Blender's bpy wheel (one PyPI wheel, about 374 MB) exists for Python 3.11
# only and pins numpy < 2: it gets its own venv with the project installed.
PYTHON311 ?= python3.11
BLENDER_VENV ?= .venv-blender
BLENDER_STAMP := $(BLENDER_VENV)/.staggered-installed

$(BLENDER_STAMP): pyproject.toml
	$(PYTHON311) -m venv $(BLENDER_VENV) || { echo "could not create $(BLENDER_VENV): bpy 5.0.1 needs Python 3.11 (set PYTHON311=...)" >&2; exit 1; }
	$(BLENDER_VENV)/bin/python -m pip install 'bpy==5.0.1' 'numpy<2' 'pytest>=7.4' 'pytest-timeout>=2.1' -e .
	touch $@

test-blender: $(BLENDER_STAMP)
	$(BLENDER_VENV)/bin/python -m pytest tests/blender $(PYTEST_ARGS)

# The Khronos glTF-Validator (npm package gltf-validator, pinned in
# tools/gltf/package-lock.json) checks every glTF the tests write.  node and
# npm come from apt where they are missing (as root; otherwise it says so).
GLTF_TOOLS := tools/gltf
GLTF_STAMP := $(GLTF_TOOLS)/node_modules/.staggered-installed

$(GLTF_STAMP): $(GLTF_TOOLS)/package.json $(GLTF_TOOLS)/package-lock.json
	@if ! command -v node >/dev/null || ! command -v npm >/dev/null; then \
	  if [ "$$(id -u)" = 0 ]; then apt-get update && apt-get install -y nodejs npm; \
	  else echo "node and npm are missing: install them (Debian: apt-get install -y nodejs npm, as root)" >&2; exit 1; fi; \
	fi
	cd $(GLTF_TOOLS) && npm ci --no-audit --no-fund
	touch $@

test-gltf: $(STAMP) $(GLTF_STAMP)
	@$(BYTECODE)
	GLTF_VALIDATOR_REQUIRED=1 $(BIN)/python -m pytest -n 0 -m gltf_validator tests/test_gltf.py $(PYTEST_ARGS)

# The page of `staggered view` carries three.js (npm package three, MIT) as
# one minified IIFE, built by tools/view/build.mjs with the esbuild pinned in
# tools/view/package-lock.json: the same bytes every time (the browser tests
# rebuild it and compare; tests/test_view.py checks its recorded sha256).
VIEW_TOOLS := tools/view
VIEW_STAMP := $(VIEW_TOOLS)/node_modules/.staggered-installed
NEED_NODE = @if ! command -v node >/dev/null || ! command -v npm >/dev/null; then \
	  if [ "$$(id -u)" = 0 ]; then apt-get update && apt-get install -y nodejs npm; \
	  else echo "node and npm are missing: install them (Debian: apt-get install -y nodejs npm, as root)" >&2; exit 1; fi; \
	fi

$(VIEW_STAMP): $(VIEW_TOOLS)/package.json $(VIEW_TOOLS)/package-lock.json
	$(NEED_NODE)
	cd $(VIEW_TOOLS) && npm ci --no-audit --no-fund
	touch $@

view-bundle: $(VIEW_STAMP)
	cd $(VIEW_TOOLS) && node build.mjs

# The browser tests: Debian's chromium (no browser download: Playwright
# launches the system one) and Playwright for Python in .venv.  With
# STAGGERED_BROWSER_REQUIRED=1 a missing browser fails them (under plain
# `make test` they skip, saying why).
BROWSER_STAMP := $(VENV)/.browser-installed

$(BROWSER_STAMP): $(STAMP)
	$(BIN)/python -m pip install -e '.[dev,browser]'
	touch $@

chromium:
	@if ! command -v chromium >/dev/null; then \
	  if [ "$$(id -u)" = 0 ]; then apt-get update && DEBIAN_FRONTEND=noninteractive apt-get install -y chromium; \
	  else echo "chromium is missing: install it (Debian: apt-get install -y chromium, as root)" >&2; exit 1; fi; \
	fi

test-browser: chromium $(BROWSER_STAMP) $(VIEW_STAMP)
	@$(BYTECODE)
	STAGGERED_BROWSER_REQUIRED=1 $(BIN)/python -m pytest -n 0 -m browser tests/browser tests/test_view.py $(PYTEST_ARGS)

screenshots: chromium $(BROWSER_STAMP)
	@$(BYTECODE)
	$(BIN)/python -m tests.browser.screenshot docs/pictures/view.png

lint: $(STAMP)
	$(BIN)/ruff check .

bench: $(STAMP)
	@$(BYTECODE)
	@if [ -z "$(BENCHES)" ]; then echo "no bench/*.py scripts yet"; fi
	@set -e; for script in $(BENCHES); do echo "== $$script"; $(BIN)/python $$script; done

golden: $(STAMP)
	$(BIN)/python tests/make_golden.py

# The main job on the bundled sample: extract staggered poses, look at them,
# cull, loosen the arm timing with succession, exaggerate a pose, bake.
S := $(BIN)/staggered
demo: $(STAMP)
	@$(BYTECODE)
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
	$(S) layer $(DEMO_OUT)/march.stag --add --keep 4 -o - \
	  | $(S) edit-pose - --layer 1 --pose 1 --rotate LeftArm=0,0,15 -o - \
	  | $(S) detail - --gain 0.5 -o - \
	  | $(S) bake - -o $(DEMO_OUT)/march_layered.bvh --force
	$(S) extract data/samples/march.c3d -o - | $(S) bake - -o $(DEMO_OUT)/march.c3d --force
	$(S) bake $(DEMO_OUT)/march.stag -o $(DEMO_OUT)/march_roundtrip.bvh --force
	@cmp -s data/samples/march.bvh $(DEMO_OUT)/march_roundtrip.bvh && echo "round trip: $(DEMO_OUT)/march_roundtrip.bvh is byte-identical to the sample"
	$(S) plot $(DEMO_OUT)/march_loose.stag --kind signals -o $(DEMO_OUT)/signals.png --force
	$(S) plot $(DEMO_OUT)/march_loose.stag --kind timing -o $(DEMO_OUT)/timing.png --force
	$(S) plot $(DEMO_OUT)/march_loose.stag --kind curves --joints RightArm,RightForeArm,RightHand -o $(DEMO_OUT)/curves.png --force
	$(S) preview $(DEMO_OUT)/march_loose.stag --compare data/samples/march.bvh -o $(DEMO_OUT)/preview.png --force
	@echo "wrote $(DEMO_OUT)/: march.stag, march_loose.bvh, march_exaggerated.bvh, march_layered.bvh, march.c3d and signals, timing, curves, preview .png"

# The README's pictures, regenerated on purpose (review them before committing).
pictures: demo
	mkdir -p docs/pictures
	cp $(DEMO_OUT)/signals.png $(DEMO_OUT)/timing.png $(DEMO_OUT)/curves.png $(DEMO_OUT)/preview.png docs/pictures/

samples: $(STAMP)
	$(BIN)/python data/samples/make_samples.py

# ---------------------------------------------------------------------------
# make [-j N] batch IN=dir OUT=dir [STEPS='cull --keep 30%|...'] [STEPS_BVH=...] [STEPS_C3D=...]
#                   [EXTRACT_OPTS='--min-spacing 0.15'] [BAKE_OPTS='--fps 30'] [JOBS=N] [FORCE=1]
#
# `staggered batch IN OUT --steps "$STEPS" -j N` (see `staggered batch --help`):
# extract | steps | bake for every .bvh / .c3d under IN into the same tree
# under OUT, outputs up to date skipped (after changing STEPS use FORCE=1).
# A thin rule over the command rather than a pattern rule per file, so that
# there is one implementation: the same steps grammar, checks before any
# file, up-to-date rule, per-kind steps, statuses (built / unchanged /
# skipped / failed) and crash isolation as the command, any file name (make
# cannot spell names with spaces, ':' or '%' as targets), and one Python
# process per worker instead of three per file.  JOBS defaults to make's -j.
STAGGERED ?= $(BIN)/staggered
JOBS ?= $(or $(patsubst -j%,%,$(filter -j%,$(MAKEFLAGS))),1)
# a make variable as one shell word, exactly as given (no $ expansion by make)
batch_q = '$(subst ','\'',$(value $1))'

batch: $(STAMP)
	@if [ -z $(call batch_q,IN) ] || [ -z $(call batch_q,OUT) ]; then \
	  echo "usage: make [-j N] batch IN=dir OUT=dir [STEPS='cull --keep 30%|...']" >&2; exit 2; fi
	@$(STAGGERED) batch $(call batch_q,IN) $(call batch_q,OUT) --steps $(call batch_q,STEPS) --jobs $(JOBS) \
	  $(if $(value STEPS_BVH),--steps-bvh $(call batch_q,STEPS_BVH)) \
	  $(if $(value STEPS_C3D),--steps-c3d $(call batch_q,STEPS_C3D)) \
	  $(if $(value EXTRACT_OPTS),--extract-opts $(call batch_q,EXTRACT_OPTS)) \
	  $(if $(value BAKE_OPTS),--bake-opts $(call batch_q,BAKE_OPTS)) \
	  $(if $(FORCE),--force)

clean:
	rm -rf out build *.egg-info .pytest_cache .ruff_cache
