# Two commands do all set-up on a machine with only python3 and make:
#   make demo      creates .venv, installs kfusion and runs the main job on built-in data
#   make test      creates .venv with the dev extras and runs lint, type check and the whole suite
#   make test-all  the same on every supported Python found here, each in its own .venv-X.Y
# Every install uses constraints.txt: the tested versions of all dependencies.
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
DEMO_OUT ?= demo-output
CONSTRAINTS := constraints.txt
SUPPORTED_PYTHONS := 3.11 3.12 3.13

.PHONY: demo test test-all lint typecheck pytest bench clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)

$(VENV)/.core-installed: pyproject.toml $(CONSTRAINTS) | $(BIN)/python
	$(BIN)/python -m pip install --quiet -c $(CONSTRAINTS) -e .
	touch $@

$(VENV)/.dev-installed: pyproject.toml $(CONSTRAINTS) | $(BIN)/python
	$(BIN)/python -m pip install --quiet -c $(CONSTRAINTS) -e '.[dev]'
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

# One Python at a time (the suite already uses both cores). A Python is looked up as
# ~/.pyenv/versions/X.Y.*/bin/python, then pythonX.Y on PATH; one not found is reported and skipped.
test-all:
	@for version in $(SUPPORTED_PYTHONS); do \
	  python=$$(ls -d $$HOME/.pyenv/versions/$$version.*/bin/python 2>/dev/null | sort -V | tail -n 1); \
	  [ -n "$$python" ] || python=$$(command -v python$$version || true); \
	  if [ -z "$$python" ]; then echo "== Python $$version: not found, skipped"; continue; fi; \
	  echo "== Python $$version: $$python, venv .venv-$$version"; start=$$(date +%s); \
	  $(MAKE) --no-print-directory test PYTHON=$$python VENV=.venv-$$version || exit 1; \
	  echo "== Python $$version: lint, types and tests passed in $$(( $$(date +%s) - start )) s"; \
	done

bench: $(VENV)/.dev-installed
	$(BIN)/python benchmarks/accuracy.py
	$(BIN)/python benchmarks/latency.py

clean:
	rm -rf $(VENV) .venv-3.* $(DEMO_OUT) paper-output kfusion-output .pytest_cache .ruff_cache \
	  .mypy_cache
