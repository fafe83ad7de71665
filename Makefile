# Two entry points, both self-contained on a fresh machine (Python 3.11 + PyPI):
#   make demo   set up, then run the main job on the built-in `bench` scenario
#   make test   set up, then lint, type-check and run the whole test suite
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
DEMO   := runs/bench-demo

.PHONY: setup demo test lint clean

setup: $(VENV)/.installed

$(VENV)/.installed: pyproject.toml postproc/products/_orthokernels.c
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -e '.[test]'
	touch $@

demo: setup
	rm -rf $(DEMO)
	$(BIN)/sisa simulate --preset bench --out $(DEMO)
	$(BIN)/sisa process $(DEMO)

lint: setup
	$(BIN)/ruff check .
	$(BIN)/lint-imports --no-cache
	$(BIN)/mypy
	$(BIN)/mypy bench

test: lint
	$(BIN)/python -m pytest -n 2 -q

clean:
	rm -rf $(VENV) runs .pytest_cache .mypy_cache .ruff_cache
