# The two commands of the README:
#   make demo   -> the main job (bootstraps .venv on first use with what the demo
#                  needs only: ramps and its `demo` extra, OR-Tools and matplotlib)
#   make test   -> ruff, mypy and the whole test suite (bootstraps .venv on first
#                  use with everything: the demo's, test and check tools, and the
#                  ROS 2 extra with its action built, so the ROS face is tested too):
#                  the tests in parallel, then those marked serial alone; each pass
#                  ends with its slowest tests, to keep the suite in its 12 minutes
# and the fast loop while you work:
#   make check  -> ruff + mypy + the tests not marked slow (about a minute on 2 cores)
PYTHON ?= python3
# Python writes each module's bytecode on its first import (the install
# compiles none, see WHEELS below); with PYTHONDONTWRITEBYTECODE set, as some
# CI and container environments do, every node, worker and command the tests
# start would compile every module it imports again: a third more CPU
unexport PYTHONDONTWRITEBYTECODE
VENV   ?= .venv
BIN    := $(VENV)/bin
# everything (make test, check, lint, types)
STAMP  := $(VENV)/.installed
# what the demo and the benchmarks need (a subset: the full install makes it too)
DEMO_STAMP := $(VENV)/.installed-demo

.PHONY: demo test check lint types bench clean

# The full install takes its wheels from WHEELS, a folder kept between fresh clones (the
# index pages come through a proxy that sends no cache headers, so pip's own cache keeps
# none of them): offline when WHEELS has them all, else they are downloaded into it first.
# --no-compile: each module is compiled when first imported, not all 700 MB up front.
WHEELS ?= $(HOME)/.cache/ramps/wheels
ALL    := .[demo,test,check,ros]
OFFLINE := $(BIN)/python -m pip install -q --no-compile --no-index --find-links $(WHEELS)

$(STAMP): pyproject.toml
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	@$(OFFLINE) --upgrade pip 2>/dev/null || $(BIN)/python -m pip install -q --upgrade pip
	@$(OFFLINE) -e '$(ALL)' 2>/dev/null || { echo "downloading the wheels into $(WHEELS)"; \
	  $(BIN)/python -m pip download -q -d $(WHEELS) '$(ALL)' pip hatchling editables setuptools wheel && \
	  $(OFFLINE) -e '$(ALL)'; }
	-$(BIN)/ramps ros --build-interfaces  # the RunProgram action type: needs cmake and a C/C++ compiler; without them its test skips
	@touch $(STAMP) $(DEMO_STAMP)

$(DEMO_STAMP): pyproject.toml
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q -e '.[demo]'
	@touch $(DEMO_STAMP)

demo: $(DEMO_STAMP)
	$(BIN)/ramps demo

# the suite in two passes: first every test not marked serial, spread over
# TEST_WORKERS processes (pytest-xdist; most slow tests wait on robots, leases
# and timeouts rather than compute; each module stays on one worker, so a
# team its tests share starts once, see tests/conftest.py), then the serial
# ones alone (they measure CPU or time robots at a fraction of a core). Both
# passes run; either failing fails the target. TEST_WORKERS=0: one process.
TEST_WORKERS ?= 3

test: lint types $(STAMP)
	@rc=0; \
	$(BIN)/python -m pytest -q -n $(TEST_WORKERS) --dist loadfile -m "not serial" --durations=15 || rc=$$?; \
	echo "== the serial tests, alone"; \
	$(BIN)/python -m pytest -q -m serial --durations=15 || rc=$$?; \
	exit $$rc

# the fast tests on CHECK_WORKERS processes (each module on one; none is
# marked serial): 34 s on this project's 2-core VM against 56 s in one
CHECK_WORKERS ?= 2

check: lint types $(STAMP)
	$(BIN)/python -m pytest -q -m "not slow" -n $(CHECK_WORKERS) --dist loadfile

lint: $(STAMP)
	$(BIN)/ruff check src tests examples

types: $(STAMP)
	$(BIN)/mypy

bench: $(DEMO_STAMP)
	$(BIN)/ramps bench sim
	$(BIN)/ramps bench dispatch
	$(BIN)/ramps bench first-calls --rounds 3

clean:
	rm -rf $(VENV) build dist .pytest_cache .hypothesis .mypy_cache .ruff_cache
