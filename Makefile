# make demo   set up .venv and run the tool on the bundled samples
# make test   set up .venv and run the tests
# make lint   ruff
# make bench  run every bench/*.py
# make golden regenerate tests/golden/ on purpose (tests never do)
# make test-blender  set up .venv-blender (Python 3.11, bpy 5.0.1) and run the Blender round trip tests
# make batch  IN=dir OUT=dir [STEPS='cull --keep 30%|...']: extract -> steps -> bake over a library

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

.PHONY: all demo test test-blender lint bench golden install clean batch _batch-files samples pictures

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
	$(S) plot $(DEMO_OUT)/march_loose.stag --kind signals --dpi 72 -o $(DEMO_OUT)/signals.png --force
	$(S) plot $(DEMO_OUT)/march_loose.stag --kind timing --dpi 72 -o $(DEMO_OUT)/timing.png --force
	$(S) plot $(DEMO_OUT)/march_loose.stag --kind curves --joints RightArm,RightForeArm,RightHand --dpi 72 -o $(DEMO_OUT)/curves.png --force
	$(S) preview $(DEMO_OUT)/march_loose.stag --compare data/samples/march.bvh --dpi 72 -o $(DEMO_OUT)/preview.png --force
	@echo "wrote $(DEMO_OUT)/: march.stag, march_loose.bvh, march_exaggerated.bvh, march_layered.bvh, march.c3d and signals, timing, curves, preview .png"

# The README's pictures, regenerated on purpose (review them before committing).
pictures: demo
	mkdir -p docs/pictures
	cp $(DEMO_OUT)/signals.png $(DEMO_OUT)/timing.png $(DEMO_OUT)/curves.png $(DEMO_OUT)/preview.png docs/pictures/

samples: $(STAMP)
	$(BIN)/python data/samples/make_samples.py

# ---------------------------------------------------------------------------
# make -j2 -k batch IN=dir OUT=dir [STEPS='cull --keep 30%|succession --joint LeftShoulder --offset 0.02 --power 2']
#
# For every .bvh / .c3d (any case) under IN, at any depth:
#   staggered extract IN/rel -o - | staggered STEP1 - -o - | ... | staggered bake - -o OUT/rel
# OUT mirrors IN's tree.  An output is rebuilt only when older than its input
# (make's rule: after changing STEPS, use -B).  STEPS has the syntax of
# `staggered batch --steps` and is checked once before any file.  A failing
# file leaves no output (bake writes atomically; a previous output of it is
# removed) and its stderr in OUT/rel.err; with -k the others go on.  The
# summary names every input without an up-to-date output, with its reason.
# Spaces in names under IN work; IN and OUT themselves may hold no whitespace
# and, like the names under IN, none of BATCH_BAD_CHARS (make or the shell
# would read them): such IN / OUT are refused (exit 2), such files skipped
# and reported as failed (`staggered batch` handles any name).
STAGGERED ?= $(BIN)/staggered
export STEPS
BATCH_IN = $(patsubst %/,%,$(IN))
BATCH_OUT = $(patsubst %/,%,$(OUT))
BATCH_MAKEFILE := $(lastword $(MAKEFILE_LIST))
# one name a line, sorted, without ./ (a newline in a name arrives as \036)
BATCH_FIND = find . -xtype f \( -iname '*.bvh' -o -iname '*.c3d' \) -print0 | tr '\n\0' '\036\n' | LC_ALL=C sort | sed 's|^\./||'
batch_empty :=
# the characters, and a bracket expression (grep -E, bash =~) of them and control characters
BATCH_BAD_CHARS := " \# $$ : ; = \ ` | % * ? [ ]
BATCH_BAD_NAME := [][:cntrl:]"\#$$:;=\`|%*?[]
BATCH_UNSUPPORTED := file name not supported by make batch; use staggered batch

ifneq ($(filter batch,$(MAKECMDGOALS)),)
# checked before anything runs: make splits IN and OUT on whitespace and reads the others
batch_bad_paths := $(strip $(foreach c,$(BATCH_BAD_CHARS),$(if $(findstring $c,$(value IN)$(value OUT)),$c)))
ifeq ($(strip $(value IN)),)
$(error usage: make [-j N] [-k] batch IN=dir OUT=dir [STEPS='cull --keep 30%|...'])
else ifeq ($(strip $(value OUT)),)
$(error usage: make [-j N] [-k] batch IN=dir OUT=dir [STEPS='cull --keep 30%|...'])
else ifneq ($(words x$(value IN)x x$(value OUT)x),2)
$(error make batch: IN and OUT must not contain whitespace (make splits them); rename, or use staggered batch)
else ifneq ($(batch_bad_paths),)
$(error make batch: IN and OUT must not contain any of $(BATCH_BAD_CHARS) (found $(batch_bad_paths)); rename, or use staggered batch)
endif
endif

batch: $(STAMP)
	@$(STAGGERED) -q batch "$(BATCH_IN)" "$(BATCH_OUT)" --steps "$$STEPS" --dry-run > /dev/null
	@status=0; $(MAKE) -f "$(BATCH_MAKEFILE)" --no-print-directory _batch-files || status=$$?; \
	export LC_ALL=C; bad='$(BATCH_BAD_NAME)'; total=0; failed=0; \
	while IFS= read -r rel; do \
	  total=$$((total + 1)); in="$(BATCH_IN)/$$rel"; out="$(BATCH_OUT)/$$rel"; reason=; \
	  if [[ $$rel =~ $$bad ]]; then \
	    reason="$(BATCH_UNSUPPORTED)"; \
	  elif [ -f "$$out.err" ]; then \
	    reason=$$(grep -v ': WARNING: ' -- "$$out.err" | grep -m 1 .); reason=$${reason:-exit status $$status}; \
	  elif [ ! -f "$$out" ] || [ "$$out" -ot "$$in" ]; then \
	    reason="not built"; \
	  fi; \
	  if [ -n "$$reason" ]; then failed=$$((failed + 1)); echo "  FAILED $$rel: $$reason"; fi; \
	done < <(cd -- "$(BATCH_IN)" && $(BATCH_FIND)); \
	echo "make batch: $$total files, $$failed failed (outputs in $(BATCH_OUT))"; \
	if [ $$failed -gt 0 ] && [ $$status -eq 0 ]; then status=1; fi; \
	exit $$status

ifneq ($(filter _batch-files,$(MAKECMDGOALS)),)
# make splits its word lists on spaces: a space in a path travels as \037
# and becomes an escaped space only in the rules; names make cannot handle
# get no rule (the summary reports them)
BATCH_US := $(shell printf '\037')
batch_esc = $(subst $(BATCH_US),\$(batch_empty) $(batch_empty),$1)
BATCH_RELS := $(shell cd -- "$(BATCH_IN)" && $(BATCH_FIND) | LC_ALL=C grep -v -E -e '$(BATCH_BAD_NAME)' | tr ' ' '\037')
BATCH_STEPS = $(if $(strip $(STEPS)),| $(STAGGERED) $(subst |, - -o - | $(STAGGERED) ,$(STEPS)) - -o - )
BATCH_PIPE = $(STAGGERED) extract "$<" -o - $(BATCH_STEPS)| $(STAGGERED) bake - -o "$@" --force
BATCH_RECIPE = set -o pipefail; out="$@"; err="$@.err"; mkdir -p -- "$$(dirname -- "$$out")"; \
  if { $(BATCH_PIPE); } 2> "$$err"; then \
    cat -- "$$err" >&2; rm -f -- "$$err"; echo "baked $$out"; \
  else rm -f -- "$$out"; echo "failed $<" >&2; exit 1; fi

_batch-files: $(foreach r,$(BATCH_RELS),$(call batch_esc,$(BATCH_OUT)/$r))

define batch_rule
$(call batch_esc,$(BATCH_OUT)/$1): $(call batch_esc,$(BATCH_IN)/$1)
	@$$(BATCH_RECIPE)
endef
$(foreach r,$(BATCH_RELS),$(eval $(call batch_rule,$r)))
endif

clean:
	rm -rf out build *.egg-info .pytest_cache .ruff_cache
