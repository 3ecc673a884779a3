# agv-cosim: the two set-up commands are `make run` and `make test`.
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
# pytest-xdist workers for `make test` (tests/README.md: 2 measured best on 2 cores); files
# are kept whole on one worker (--dist loadfile) so a file's module fixtures run once.
JOBS   ?= 2

.PHONY: run test test-fast fmus venv clean

$(STAMP): pyproject.toml setup.py
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e ".[test]"
	touch $(STAMP)

venv: $(STAMP)

fmus: $(STAMP)
	$(BIN)/agv-cosim build --out fmus

run: fmus
	$(BIN)/agv-cosim run experiments/seed000_models_abc.toml --out results/seed000_models_abc
	@echo "plots: results/seed000_models_abc/*.png"

test: fmus
	$(BIN)/python -m pytest -q -n $(JOBS) --dist loadfile

# The fast tier: every test not marked slow (no seed reproductions, no interop checks).
test-fast: venv
	$(BIN)/python -m pytest -q -m "not slow"

clean:
	rm -rf fmus/*.fmu fmus/build-index.json results
