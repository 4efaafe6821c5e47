PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
# Reinstall only when the package metadata changes.
STAMP  := $(VENV)/.installed

.PHONY: venv test test-all demo bench bench-threads bench-stepping

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
	$(BIN)/capsim run configs/sphere.yaml --overwrite

bench: venv
	$(BIN)/python benchmarks/run_bench.py

# numba threading layers x OpenMP wait policies, 1 and 2 threads, quiet and with a busy competitor
# (several minutes): writes benchmarks/threads.md and benchmarks/threads.json
bench-threads: venv
	$(BIN)/python benchmarks/threads.py

# time schemes at equal accuracy (about an hour on 2 cores; CASES=a c to run some):
# writes benchmarks/time_schemes.md and benchmarks/time_schemes.json
bench-stepping: venv
	$(BIN)/python benchmarks/stepping.py $(CASES)
