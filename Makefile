# nue: two commands on a fresh machine — `make demo` and `make test`.
PY ?= python3.11
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

export LP_NUM_THREADS ?= 1
export PYTHONHASHSEED ?= 0

.PHONY: setup demo test lint bench clean

setup: $(STAMP)

$(STAMP): pyproject.toml
	@test -x $(BIN)/python || $(PY) -m venv $(VENV) || python3 -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet torch==2.13.0
	$(BIN)/python -m pip install --quiet -e '.[test]'
	@touch $(STAMP)

demo: setup
	$(BIN)/nue demo --out outputs/demo

test: setup lint
	$(BIN)/python -m pytest -q --durations=15

# ruff and mypy, both configured in pyproject.toml.
lint: setup
	$(BIN)/ruff check nue tests benchmarks scripts
	$(BIN)/mypy nue

bench: setup
	$(BIN)/python benchmarks/_run_all.py

clean:
	rm -rf outputs .pytest_cache .mypy_cache .ruff_cache
