# Two entry points for a fresh machine: `make run` (one NVF episode on the embedded scene) and
# `make test` (`make lint`, then the default test suite). Each installs what it needs first (scripts/setup.sh): `run` the
# main environment, `test` also Blender (its tests render with it); `make blender` installs Blender alone.
PY := .venv/bin/python
ARGS ?=

.PHONY: setup blender browser run lint test test-slow bench
setup:
	@bash scripts/setup.sh

blender:
	@bash scripts/setup.sh blender

browser:
	@bash scripts/setup.sh browser

run: setup
	$(PY) -m pipeline.run $(ARGS)

lint: setup  # import layers, lint and format of the code, tests, scripts and examples, and types of nvf/ and pipeline/ (pyproject.toml's [tool.importlinter], [tool.ruff], [tool.mypy])
	.venv/bin/lint-imports
	$(PY) -m ruff check nvf pipeline tests scripts examples
	$(PY) -m ruff format --check nvf pipeline tests scripts examples
	$(PY) -m mypy

test: setup blender lint
	$(PY) -m pytest -n 2 $(ARGS)

test-slow: setup blender browser
	$(PY) -m pytest -m slow $(ARGS)

bench: setup
	$(PY) -m pipeline.bench $(ARGS)
