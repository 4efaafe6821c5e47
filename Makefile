PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
# Reinstall only when the package metadata changes.
STAMP  := $(VENV)/.installed

.PHONY: venv test test-all docs demo bench bench-threads bench-stepping bench-split bench-promise cf-tools

venv: $(STAMP)

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/pip install -e '.[test]'
	# compile the demo's numba kernels into the cache now, so that its first run computes at once
	$(BIN)/capsim warm-up configs/sphere.yaml
	touch $@

# one test process per core, a test file's tests on one of them (module fixtures computed once):
# the suite is single-threaded work, ~14 min of CPU on this 2-core machine
test: venv cf-tools
	$(BIN)/python -m pytest -q -m "not slow" -n auto --dist loadfile

test-all: venv
	$(BIN)/python -m pytest -q

# cfchecker and the libudunits2 it loads, for tests/storage/test_results.py (it runs offline with the CF
# tables of tests/data/cf). Best effort: without network or root the CF tests skip with the reason.
CF_STAMP := $(VENV)/.cf-tools
cf-tools: $(CF_STAMP)

$(CF_STAMP): pyproject.toml | $(STAMP)
	-@ldconfig -p 2>/dev/null | grep -q libudunits2 || { [ "$$(id -u)" = 0 ] && \
		(apt-get install -y -q libudunits2-0 udunits-bin >/dev/null 2>&1 || \
		 (apt-get update -q >/dev/null 2>&1 && apt-get install -y -q libudunits2-0 udunits-bin >/dev/null 2>&1)) || \
		echo "cf-tools: no libudunits2 (needs root: apt-get install libudunits2-0 udunits-bin); CF tests will skip"; }
	-@$(BIN)/pip install -q -e '.[cf]' || echo "cf-tools: cfchecker not installed; CF tests will skip"
	@touch $@

# the documentation site into site/ (warnings are errors); the case-file and quantity references
# are generated from the code at every build (docs/gen_reference.py)
DOCS_STAMP := $(VENV)/.docs-tools
$(DOCS_STAMP): pyproject.toml | $(STAMP)
	$(BIN)/pip install -q -e '.[docs]'
	touch $@

# --clean empties site/ first: refused when site is a link or not a directory (it would empty
# whatever the link points at)
docs: $(DOCS_STAMP)
	@if [ -L site ] || { [ -e site ] && [ ! -d site ]; }; then \
		echo "error: site is a symbolic link or not a directory; make docs builds into site/ and empties it first: remove or rename it" >&2; \
		exit 2; fi
	$(BIN)/mkdocs build --strict --clean

demo: venv
	$(BIN)/capsim run configs/sphere.yaml --overwrite

bench: venv
	$(BIN)/python benchmarks/run_bench.py

# numba threading layers x OpenMP wait policies, 1 and 2 threads, quiet and with a busy competitor
# (several minutes): writes benchmarks/threads.md and benchmarks/threads.json
bench-threads: venv
	$(BIN)/python benchmarks/threads.py
	$(BIN)/python benchmarks/threads.py --level 4 --t-end 2 --repeat 3 --loads quiet \
		--settings capsim,omp-passive,default --out benchmarks/threads_level4

# time schemes at equal accuracy (about 1.5 h on 2 cores, 40 min of it case h5; CASES=a c to run some):
# writes benchmarks/time_schemes.md and benchmarks/time_schemes.json
bench-stepping: venv
	$(BIN)/python benchmarks/stepping.py $(CASES)

# the per-stage split of one evaluation (level 3, lambda = 1, quarter symmetry, one thread), this
# checkout against the baseline commit in alternating rounds (a few minutes):
# writes benchmarks/evaluation_split.md and benchmarks/evaluation_split.json
bench-split: venv
	$(BIN)/python benchmarks/evaluation_split.py

# the demo's command around its evaluations (issue 57): the whole command, validate, imports, the run's
# evaluations, rows and writes, this checkout against the baseline in alternating rounds (about 2 min):
# writes benchmarks/command_time.md and benchmarks/command_time.json
.PHONY: bench-command
bench-command: venv
	$(BIN)/python benchmarks/command_time.py

# the peer's three cases (issue 57, item 3): the whole command and its split at level 3, this checkout
# (about 2 min): writes benchmarks/peer_command_time.md and benchmarks/peer_command_time.json
.PHONY: bench-peer-command
bench-peer-command: venv
	$(BIN)/python benchmarks/peer_command_time.py

# a campaign of 16 short level-2 runs on one worker (issue 57): its time outside the evaluations, this
# checkout against the baseline in alternating rounds (about 2 min): writes benchmarks/campaign_overhead.{md,json}
.PHONY: bench-campaign
bench-campaign: venv
	$(BIN)/python benchmarks/campaign_overhead.py

# time.rtol's promise: every scheme x case x rtol 1e-2..1e-5, error / rtol against a reference at
# 1e-7 (about 25 min on 2 shared cores; CASES=a c to run some): writes benchmarks/rtol_promise.md and .json
bench-promise: venv
	$(BIN)/python benchmarks/stepping.py --promise $(CASES)

# auto's pick against every fixed scheme in wall time (issue 44: within 1.25x of the fastest), the
# stepping cases at levels 2 and 3 made cheaper, rtol 1e-4, median of 3 interleaved (about 10 min;
# CASES=g2 a3 to run some): writes benchmarks/auto_choice.md and benchmarks/auto_choice.json
.PHONY: bench-auto
bench-auto: venv
	$(BIN)/python benchmarks/auto_choice.py $(CASES)

# red cells against Tran-Son-Tay, Sutera & Rao 1984 (issue 40): the five shear rates with and
# without membrane viscosity, the sensitivity at 28.6 1/s and two other membrane laws, level 2, one run at a time (about
# 25 min on one core; runs already in benchmarks/tran_son_tay.json are kept): writes
# benchmarks/tran_son_tay.md and docs/figures/tran_son_tay.png
# the scene's cost (flows, the wall) at level 3 and the figures of planar extension's D(G) and the
# wall's lift(h) (a few minutes): writes benchmarks/scenes.md/.json and docs/figures/{planar_extension_D,wall_lift}.png
.PHONY: bench-scenes
bench-scenes: venv
	PYTHONPATH=. $(BIN)/python benchmarks/scenes.py

# the bending trade (issue 54): a sphere's steady D_xy and its compressed membrane against the
# bending modulus at small G, levels 2 and 3 (a few minutes): writes benchmarks/bending_trade.md/.json
.PHONY: bench-bending
bench-bending: venv
	PYTHONPATH=. $(BIN)/python benchmarks/bending_trade.py

# the red cell's tumbling-tank-treading transition against Fischer & Korzeniewski 2013's threshold stress
# (issue 55): rates around it at three viscosities, two stress-free shapes, level 1 (about 30 min on one
# core; runs in benchmarks/tumbling_transition.json are kept): writes benchmarks/tumbling_transition.md
.PHONY: bench-transition
bench-transition: venv
	$(BIN)/python benchmarks/tumbling_transition.py run

# capsim fit's intervals against the truth over repeated noise draws (issue 56): flow.G from D_xy, level 1,
# 20 draws (about 15 min on one core; FITS=G Gs-lambda DRAWS=20 8): writes benchmarks/fit_coverage.md/.json
.PHONY: bench-fit
bench-fit: venv
	PYTHONPATH=. $(BIN)/python benchmarks/fit_coverage.py $(if $(FITS),--fits $(FITS)) $(if $(DRAWS),--draws $(DRAWS))

# the red cell at 0.1-50 Pa in 30 mPa s (issue 55): the area modulus C = 10, 100, 1000 at level 2, C = 1000 at
# level 3, the configuration as it ships (skalak_c auto) at levels 2 and 3 and in 10 and 100 mPa s, settled (kt 100),
# with a viscous membrane, and what moves its elongation index (the stored rows took 3.1 h, partly two or three
# runs on two cores; about 4 h on one core with viscous_oblate3, not stored; rows in
# benchmarks/rbc_high_stress.json are kept, GROUPS=... runs those only): writes benchmarks/rbc_high_stress.md and
# docs/figures/rbc_ektacytometry.png
.PHONY: bench-rbc-stress
bench-rbc-stress: venv
	$(BIN)/python benchmarks/rbc_high_stress.py run $(GROUPS)

.PHONY: bench-pair
bench-pair: venv
	$(BIN)/capsim sweep campaigns/pair-collision.yaml --workers 2
	PYTHONPATH=. $(BIN)/python benchmarks/pair_collision.py

# the cost of one velocity evaluation against the number of capsules (issue 43): level 2 with 1-16
# capsules, level 3 one against the pair, 1 and 2 threads, and the dense Stokeslet sum against
# fmm3dpy's Stokes FMM, which runs in a throwaway venv outside the project when FMM_PYTHON names its
# python (python3 -m venv /tmp/fmmvenv && /tmp/fmmvenv/bin/pip install fmm3dpy numpy numba scipy;
# without it the FMM numbers of benchmarks/capsules.json are kept); a few minutes, most of it the FMM:
# writes benchmarks/capsules.md and benchmarks/capsules.json
.PHONY: bench-capsules
bench-capsules: venv
	PYTHONPATH=. $(BIN)/python benchmarks/capsules.py $(if $(FMM_PYTHON),--fmm-python $(FMM_PYTHON))

# the cost of a conduit's wall (issue 53): assembly, LU, memory, back-solve and the layer's sums
# against the wall's nodes (1k-8k), the GMRES alternative, and whole runs of configs/tube.yaml at
# levels 2 and 3 (about 8 min on 2 shared cores, level 3 1.5 min of it; SKIP_LEVEL3=1 leaves it out):
# writes benchmarks/conduits.md and benchmarks/conduits.json
.PHONY: bench-conduits
bench-conduits: venv
	PYTHONPATH=. $(BIN)/python benchmarks/conduits.py $(if $(SKIP_LEVEL3),--skip-level3)

.PHONY: bench-scheme-cost
bench-scheme-cost: venv
	PYTHONPATH=. $(BIN)/python benchmarks/scheme_cost.py

.PHONY: bench-error-model
# the error model of time.rtol auto and accuracy targets (issue 44): 157 training cases, two workers
# (about 15 min on 2 cores; rows already in capsim/solve/error_model.json are kept, --all measures again)
bench-error-model: venv
	$(BIN)/python benchmarks/error_model.py --workers=2

.PHONY: bench-accuracy-target
# the accuracy target on eight cases the model was not built from (about half an hour on 2 cores, most of it level-4 runs)
bench-accuracy-target: venv
	$(BIN)/python benchmarks/accuracy_target.py --workers=2

# does a short run tell the mesh error at t_end? (issue 44) levels 1-3 of the eleven training cases beside the
# error model's grid, D_xy and θ at kt 1, 2, 4 (about 5 min on 2 cores): writes benchmarks/early_error.md and .json
.PHONY: bench-early-error
bench-early-error: venv
	$(BIN)/python benchmarks/early_error.py --workers=2

# time.rtol auto against rtol 1e-4 (issue 44): evaluations saved and D_xy, θ moved against each case's
# own mesh error (one level coarser), the stepping cases at levels <= 3, one run each (about a minute;
# CASES=a e to run some): writes benchmarks/rtol_auto.md and benchmarks/rtol_auto.json
.PHONY: bench-rtol-auto
bench-rtol-auto: venv
	$(BIN)/python benchmarks/rtol_auto.py $(CASES)

.PHONY: bench-tts
bench-tts: venv
	$(BIN)/python benchmarks/tran_son_tay.py run main elastic sensitivity extra shape hardening soft stressfree fischer fischersoft twosided fischerfit
	$(BIN)/python benchmarks/tran_son_tay.py report
