# The README's two commands: `make up` (start the product) and `make test` (run every test).
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
TEST_STAMP := $(VENV)/.installed-test
# The browser the viewer's tests and benchmark drive (Debian's chromium; Playwright never downloads one).
CHROMIUM ?= /usr/bin/chromium
export SIMECS_CHROMIUM := $(CHROMIUM)
CODE := mesh models nodes viewer testing benchmarks tests docs/examples

.PHONY: up test lint format bench warm schema clean browser-deps

# uv installs into the venv what pip would (same resolver rules, same editable install), downloading
# and unpacking in parallel: 25 s instead of 50 s for the test extras on a fresh clone. Compiled to
# bytecode as pip does: without it every process imports from source (4.3 s instead of 1.5 s for a
# node's imports here), and the tests start hundreds of processes.
UV := $(BIN)/uv pip install --quiet --compile-bytecode --python $(BIN)/python

$(BIN)/python:
	$(PY) -m venv $(VENV)

$(BIN)/uv: | $(BIN)/python
	$(BIN)/pip install --quiet --disable-pip-version-check uv

$(STAMP): pyproject.toml | $(BIN)/uv
	$(UV) -e .
	touch $@

$(TEST_STAMP): pyproject.toml | $(BIN)/uv
	$(UV) -e '.[test]'
	touch $(STAMP) $@

# The browser tests need chromium, and Mesa for its WebGL (llvmpipe, testing/browser.py): installed from
# Debian's packages where we may (root with apt), otherwise `make test` stops here and says what is
# missing (it never skips those tests).
BROWSER_PACKAGES := chromium libegl1 libegl-mesa0 libgl1-mesa-dri
browser-deps: $(TEST_STAMP)
	@if $(BIN)/python -c "import sys; from simecs.testing.browser import browser_missing; sys.exit(bool(browser_missing()))"; then \
		:; \
	elif command -v apt-get >/dev/null 2>&1 && [ "$$(id -u)" = 0 ]; then \
		echo "installing Debian's chromium and Mesa for the browser tests"; \
		apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $(BROWSER_PACKAGES) >/dev/null; \
	else \
		echo "make test: the browser tests need chromium at $(CHROMIUM) and Mesa's EGL: install Debian's" \
			"packages $(BROWSER_PACKAGES) (as root) or pass CHROMIUM=/path/to/chromium" >&2; \
		exit 1; \
	fi

# Compile the drive kernels into numba's cache once, and fit the URDF models' collision spheres
# (measuring each model's cost builds it), so no node or test pays either on its first run.
warm: $(STAMP)
	$(BIN)/python -c "from simecs import models; print(f'drives compiled in {models.warmup(alongside=True):.1f} s'); models.costs()"

up: $(STAMP) warm
	$(BIN)/simecs up

# mypy sees the folders as the simecs.* packages they install as (see [tool.mypy] in pyproject.toml).
TYPES := .simecs/types/simecs
PACKAGES := mesh models nodes viewer testing benchmarks

lint: $(TEST_STAMP)
	$(BIN)/ruff check $(CODE)
	$(BIN)/ruff format --check $(CODE)
	@mkdir -p $(TYPES) && for p in $(PACKAGES); do ln -sfn ../../../$$p $(TYPES)/$$p; done
	$(BIN)/mypy
	PYTHONPATH=.simecs/types $(BIN)/lint-imports --no-cache
	$(BIN)/python -m simecs.mesh.protocol.protocol_doc --check

format: $(TEST_STAMP)
	$(BIN)/ruff check --fix $(CODE)
	$(BIN)/ruff format $(CODE)

# Rewrite docs/protocol.schema.json and the generated tables of docs/PROTOCOL.md from mesh/protocol/.
schema: $(STAMP)
	$(BIN)/python -m simecs.mesh.protocol.protocol_doc

# Lint and the drives' compile run side by side (one core each): on a fresh clone that saves half a minute.
test: $(TEST_STAMP) browser-deps
	$(MAKE) --no-print-directory -j2 --output-sync=target lint warm
	$(BIN)/python -m pytest -q -n 2 --dist loadfile --durations=20

# The benchmarks check against the test oracles (yourdfpy) and drive the browser (playwright): the test extras.
bench: $(TEST_STAMP) warm
	$(BIN)/simecs bench model
	$(BIN)/simecs bench commands
	$(BIN)/simecs bench control
	$(BIN)/simecs bench service
	$(BIN)/simecs bench recorder
	$(BIN)/simecs bench lan
	$(BIN)/simecs bench viewer
	$(BIN)/simecs bench hil
	$(BIN)/simecs bench scale

clean:
	rm -rf $(VENV) .simecs artifacts .pytest_cache .ruff_cache .mypy_cache
