# Two entry points for a fresh machine: `make run` (one NVF episode on the embedded scene) and
# `make test` (the default test suite). Both install everything first (scripts/setup.sh).
PY := .venv/bin/python
ARGS ?=

.PHONY: setup run test test-slow smoke bench
setup:
	@bash scripts/setup.sh

run: setup
	$(PY) -m pipeline.run $(ARGS)

test: setup
	$(PY) -m pytest -n 2 $(ARGS)

test-slow: setup
	$(PY) -m pytest -m slow $(ARGS)

bench: setup
	$(PY) -m pipeline.bench $(ARGS)
