PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
# Reinstall only when the package metadata changes.
STAMP  := $(VENV)/.installed

.PHONY: venv test test-all demo bench

venv: $(STAMP)

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/pip install -e '.[test]'
	touch $@

test: venv
	$(BIN)/python -m pytest -q -m "not slow"

test-all: venv
	$(BIN)/python -m pytest -q

demo: venv
	$(BIN)/capsim run configs/sphere.yaml

bench: venv
	$(BIN)/python benchmarks/run_bench.py
