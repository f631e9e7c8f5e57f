# The two commands of the README:
#   make demo   -> the main job (bootstraps .venv on first use)
#   make test   -> the whole test suite (bootstraps .venv on first use, with the
#                  ROS 2 extra so the ROS face is tested too)
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: demo test bench clean

$(STAMP): pyproject.toml
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -e '.[test,ros]'
	-$(BIN)/ramps ros --build-interfaces  # the RunProgram action type: needs cmake and a C/C++ compiler (~30 s); without them its test skips
	@touch $(STAMP)

demo: $(STAMP)
	$(BIN)/ramps demo

test: $(STAMP)
	$(BIN)/python -m pytest -q

bench: $(STAMP)
	$(BIN)/ramps bench sim
	$(BIN)/ramps bench dispatch

clean:
	rm -rf $(VENV) build dist .pytest_cache .hypothesis
