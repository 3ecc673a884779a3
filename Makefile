# agv-cosim: the two set-up commands are `make run` and `make test`.
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: run test fmus venv clean

$(STAMP): pyproject.toml
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
	$(BIN)/python -m pytest -q

clean:
	rm -rf fmus/*.fmu fmus/build-index.json results
