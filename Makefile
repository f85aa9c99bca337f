# Two commands do all set-up on a machine with only python3 and make:
#   make demo   creates .venv, installs kfusion and runs the main job on built-in data
#   make test   creates .venv with the dev extras and runs lint, type check and the whole suite
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
DEMO_OUT ?= demo-output

.PHONY: demo test lint typecheck pytest bench clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)

$(VENV)/.core-installed: pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e .
	touch $@

$(VENV)/.dev-installed: pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	touch $(VENV)/.core-installed $@

demo: $(VENV)/.core-installed
	$(BIN)/kfusion demo --out $(DEMO_OUT)

lint: $(VENV)/.dev-installed
	$(BIN)/ruff check kfusion tests benchmarks

typecheck: $(VENV)/.dev-installed
	$(BIN)/mypy kfusion

pytest: $(VENV)/.dev-installed
	$(BIN)/python -m pytest -n 2 --dist loadfile -q

test: lint typecheck pytest

bench: $(VENV)/.dev-installed
	$(BIN)/python benchmarks/accuracy.py
	$(BIN)/python benchmarks/latency.py

clean:
	rm -rf $(VENV) $(DEMO_OUT) .pytest_cache .ruff_cache .mypy_cache
