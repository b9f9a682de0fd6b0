# Two commands do everything on a fresh machine: `make demo` and `make test`.
# Both create .venv and install the package (editable, with test and dask extras) the first time; later runs skip
# the install unless setup.cfg or setup.py changed. `make install` also compiles every search kernel into numba's
# cache (~100 s of CPU, once), so that a user's first match starts at once; the demo and the tests compile only
# the kernels they call, when they call them (a fresh `make demo` took 5 min 5 s with the whole warm-up first).
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.sosmatch-installed
DEMO_OUT ?= demo_out
PYTEST_WORKERS ?= 2

.PHONY: demo test lint bench install clean

$(STAMP): setup.cfg setup.py pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -e ".[test,dask]"
	touch $(STAMP)

# every kernel compiled (a second when their cache is complete): a changed kernel source empties it
install: $(STAMP)
	$(BIN)/python -m sosmatch.tools.warm_kernels

demo: $(STAMP)
	$(BIN)/sosmatch demo --out $(DEMO_OUT)

lint: $(STAMP)
	$(BIN)/ruff check .

test: $(STAMP) lint
	$(BIN)/python -m pytest -q -n $(PYTEST_WORKERS) --dist loadfile

bench: $(STAMP)
	$(BIN)/python -m sosmatch.tools.benchmarks.run_all

clean:
	rm -rf $(VENV) $(DEMO_OUT) build *.egg-info
