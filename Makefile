# The README's two commands: `make up` (start the product) and `make test` (run every test).
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
TEST_STAMP := $(VENV)/.installed-test

.PHONY: up test lint format bench clean

$(BIN)/python:
	$(PY) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip

$(STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/pip install --quiet -e .
	touch $@

$(TEST_STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/pip install --quiet -e '.[test]'
	touch $(STAMP) $@

up: $(STAMP)
	$(BIN)/simecs up

lint: $(TEST_STAMP)
	$(BIN)/ruff check mesh models nodes viewer tests docs/examples
	$(BIN)/ruff format --check mesh models nodes viewer tests docs/examples
	$(BIN)/mypy

format: $(TEST_STAMP)
	$(BIN)/ruff check --fix mesh models nodes viewer tests docs/examples
	$(BIN)/ruff format mesh models nodes viewer tests docs/examples

test: lint
	$(BIN)/python -m pytest -q -n 2 --dist loadfile

bench: $(STAMP)
	$(BIN)/simecs bench model
	$(BIN)/simecs bench service
	$(BIN)/simecs bench recorder
	$(BIN)/simecs bench viewer

clean:
	rm -rf $(VENV) .simecs artifacts .pytest_cache .ruff_cache .mypy_cache
