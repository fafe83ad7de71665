# Two entry points, both self-contained on a fresh machine with Python 3.11 and make: what
# else they need comes from tools/deps.sh (Debian packages, installed when run as root or with
# password-less sudo; else it says which and how) and from PyPI into .venv/
#   make demo   set up, then run the main job on the built-in `bench` scenario
#   make test   set up, then lint, type-check and run the whole test suite
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
DEMO   := runs/bench-demo

.PHONY: setup test-deps demo test lint clean

setup: $(VENV)/.installed

$(VENV)/.installed: pyproject.toml postproc/products/_orthokernels.c \
		postproc/georef/raycast/_castkernel.c
	PYTHON=$(PYTHON) bash tools/deps.sh demo
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

test-deps: setup
	PYTHON=$(PYTHON) bash tools/deps.sh test

test: test-deps lint
	$(BIN)/python -m pytest -n 2 -q

clean:
	rm -rf $(VENV) runs .pytest_cache .mypy_cache .ruff_cache
