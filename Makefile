# Two commands do everything on a fresh machine: `make demo` and `make test`.
# Both create .venv and install the package (editable, with test and dask extras) the first time, and compile the
# search kernels into numba's cache (minutes of CPU, once; else the first match does it); later runs skip the
# install unless setup.cfg or setup.py changed.
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
	$(BIN)/python -m sosmatch.tools.warm_kernels
	touch $(STAMP)

# the kernels again (a second when their cache is complete): a changed kernel source empties it
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
