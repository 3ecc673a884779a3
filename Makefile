# agv-cosim: the two set-up commands are `make run` and `make test`.
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
# pytest-xdist workers for `make test` (tests/README.md: 2 measured best on 2 cores); files
# are kept whole on one worker (--dist loadfile) so a file's module fixtures run once.
JOBS   ?= 2

.PHONY: run test test-fast test-deps fmus venv clean

# Debian packages the interop tests build and run their hosts with (fmusim: libxml2,
# minizip, sundials; valgrind; ecospy's libtbb12) and the browser the report page is tested in (chromium,
# driven by Selenium through chromium-driver), installed with apt-get when missing (as
# root; otherwise the missing ones are named, and those tests skip on a developer machine).
TEST_DEBS := libxml2-dev libminizip-dev libsundials-dev valgrind chromium chromium-driver libtbb12

# The venv holds the versions of constraints.txt (the results depend on them).
$(STAMP): pyproject.toml setup.py constraints.txt
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -c constraints.txt -e ".[test]"
	# the bytecode pip compiles for an installed package (an editable install gets none;
	# with PYTHONDONTWRITEBYTECODE set, every command would compile the sources again)
	$(BIN)/python -m compileall -q orchestrator/agv_cosim
	touch $(STAMP)

venv: $(STAMP)

fmus: $(STAMP)
	$(BIN)/agv-cosim build --out fmus

run: fmus
	$(BIN)/agv-cosim run experiments/seed000_models_abc.toml --out results/seed000_models_abc
	@echo "plots: results/seed000_models_abc/*.png"

test-deps:
	@missing=$$(for p in $(TEST_DEBS); do dpkg -s $$p >/dev/null 2>&1 || echo $$p; done); \
	if [ -z "$$missing" ]; then exit 0; fi; \
	if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
		echo "installing" $$missing; \
		apt-get install -y -q -o DPkg::Lock::Timeout=300 --no-install-recommends $$missing \
		|| { apt-get update -q -o DPkg::Lock::Timeout=300 && \
		     apt-get install -y -q -o DPkg::Lock::Timeout=300 --no-install-recommends $$missing; }; \
	else echo "missing Debian packages (install as root):" $$missing; fi

test: fmus test-deps
	$(BIN)/python -m pytest -q -n $(JOBS) --dist loadfile --durations=30

# The fast tier: every test not marked slow (no seed reproductions, no interop checks).
test-fast: venv
	$(BIN)/python -m pytest -q -m "not slow"

clean:
	rm -rf fmus/*.fmu fmus/build-index.json results
