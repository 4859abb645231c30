# nudge — the one entry point for set-up, tests, lint, benches and the demo.
# README and CI (.ci/run) call these targets; every target does its own set-up on a fresh machine.

SHELL := /bin/bash
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
PIP := $(VENV)/bin/pip
STAMP := $(VENV)/.nudge-stamp
TRAIN := $(VENV)/bin/nudge-train
# The demo's light environment: numpy + matplotlib + the extension (no torch, no ray).
DEMO_VENV ?= .venv-demo
DEMO_STAMP := $(DEMO_VENV)/.nudge-stamp
DEMO_EXT := $(DEMO_VENV)/.nudge-ext-stamp
DATA ?= ../shared/data/ngsim
CARGO ?= cargo

.PHONY: help venv venv-demo develop build wheel wheel-smoke wheel-smoke-versions test test-rust test-commonroad test-fuzz commonroad test-examples test-python lint fmt reference-docs fuzz fuzz-rust fuzz-python bench bench-planner bench-latency bench-table bench-python-predictor demo data teacher distill student distill-react student-react reaction paper paper-quick interaction interaction-merge goldens ci clean

help:
	@echo "make demo     set up and run the main job on the shipped defaults"
	@echo "make test     set up and run every test (Rust + Python + golden drift check + wheel smoke test)"
	@echo "make wheel    build the nudge wheel (models and scenes inside) into $(WHEEL_DIR)"
	@echo "make lint     rustfmt, clippy -D warnings, rustdoc -D warnings"
	@echo "make fuzz     mutation-fuzz weights, scenarios, settings, planning problems (FUZZ_SECONDS per target), then the Python entry points (FUZZ_EXAMPLES)"
	@echo "make bench    criterion benches (one thread) + the PyTorch-vs-Rust table"
	@echo "make data     build the processed NGSIM dataset from DATA=$(DATA)"
	@echo "make teacher  train the paper's teacher configurations, write docs/results/teacher.md"
	@echo "make student  generate the distillation set with the planner + teacher, distil the student"
	@echo "make paper    the paper's Tables I-II and Figures 7-10 into docs/paper (resumable, hours: Table II)"
	@echo "make reaction the teacher's and the students' reaction to the ego vs real cut-ins (docs/results/reaction.md)"
	@echo "make interaction  each planner vs its reaction ablated on dense scenes (docs/results/interaction.md)"

# ---- set-up ---------------------------------------------------------------------------------
# pip with retries: the registry sometimes drops a long download (torch's CUDA wheels are
# 0.5 GB each) at the same byte on every resume, so after pip's own resumes a failed install is
# started again, up to PIP_TRIES times, PIP_RETRY_SLEEP seconds apart.
PIP_TRIES ?= 3
PIP_RETRY_SLEEP ?= 20
# The first install upgrades pip itself (Python's bundled pip lacks --resume-retries).
PIP_BASE := --disable-pip-version-check -q --timeout 60
PIP_FLAGS := $(PIP_BASE) --resume-retries 10
RETRY := bash -c 'for i in $$(seq 1 $(PIP_TRIES)); do "$$@" && exit 0; echo "pip install failed (try $$i of $(PIP_TRIES))" >&2; [ $$i -lt $(PIP_TRIES) ] && sleep $(PIP_RETRY_SLEEP); done; exit 1' --
$(STAMP): python/train/pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(RETRY) $(PIP) install $(PIP_BASE) --upgrade pip
	$(RETRY) $(PIP) install $(PIP_FLAGS) -e "python/train[dev]"
	touch $(STAMP)

# The extras of pyproject.toml that the tests use, read from there: `env` (gymnasium, for
# nudge.env) and `highway` (highway-env, for nudge.adapters.highway).
DEV_EXTRAS := env highway
ENV_STAMP := $(VENV)/.nudge-env-stamp
$(ENV_STAMP): $(STAMP) pyproject.toml
	$(RETRY) $(PIP) install $(PIP_FLAGS) $$($(PY) -c 'import sys, tomllib; x = tomllib.load(open("pyproject.toml", "rb"))["project"]["optional-dependencies"]; print(" ".join(r for e in sys.argv[1:] for r in x[e]))' $(DEV_EXTRAS))
	touch $(ENV_STAMP)

venv: $(STAMP) $(ENV_STAMP)

$(DEMO_STAMP): python/train/pyproject.toml
	test -x $(DEMO_VENV)/bin/python || $(PYTHON) -m venv $(DEMO_VENV)
	$(RETRY) $(DEMO_VENV)/bin/pip install $(PIP_BASE) --upgrade pip
	$(RETRY) $(DEMO_VENV)/bin/pip install $(PIP_FLAGS) -e "python/train[demo]"
	touch $(DEMO_STAMP)

# The light environment with the extension nudge._native built into it (rebuilt when the Rust
# sources change).
$(DEMO_EXT): $(DEMO_STAMP) Cargo.lock $(shell find crates src -name '*.rs' -o -name Cargo.toml)
	$(DEMO_VENV)/bin/pip uninstall -y -q nudge 2>/dev/null || true
	rm -f python/nudge/_native.cpython-*.so
	VIRTUAL_ENV=$(abspath $(DEMO_VENV)) $(DEMO_VENV)/bin/maturin develop --release -q
	touch $(DEMO_EXT)

venv-demo: $(DEMO_EXT)

# Builds the Rust extension nudge._native into the venv (editable install of python/nudge).
# The distribution was called `nudge` before `nudge-planner`: an old install of that name is
# removed first (it would shadow the same `nudge` package and command).
# An extension built for one CPython before the abi3 build (`_native.cpython-3XX-*.so`) would
# shadow the abi3 one (`_native.abi3.so`) on import: it is removed.
develop: $(STAMP) $(ENV_STAMP)
	$(PIP) uninstall -y -q nudge 2>/dev/null || true
	rm -f python/nudge/_native.cpython-*.so
	VIRTUAL_ENV=$(abspath $(VENV)) $(VENV)/bin/maturin develop --release -q

build:
	$(CARGO) build --release --workspace

# The wheel users install (`pip install target/wheels/nudge_planner-*.whl`, or `pip install .`): the
# extension, the shipped models and scenes as package data, and the `nudge` command.
WHEEL_DIR ?= target/wheels
wheel: $(STAMP)
	rm -f $(WHEEL_DIR)/nudge-*.whl $(WHEEL_DIR)/nudge_planner-*.whl
	$(VENV)/bin/maturin build --release -q -i $(PY) -o $(WHEEL_DIR)
	@ls -l $(WHEEL_DIR)/nudge_planner-*.whl

# Installs the wheel into a fresh venv outside the checkout (numpy its only dependency, no
# torch) and runs tests/wheel/smoke.py there, from outside the checkout: predict, plan,
# simulate and the `nudge` command on the package's own assets.
wheel-smoke: wheel
	@set -e; tmp=$$(mktemp -d); trap 'rm -rf "$$tmp"' EXIT; \
	whl=$$(ls $(abspath $(WHEEL_DIR))/nudge_planner-*.whl); \
	scenes=$$(ls assets/scenes/*.safetensors | wc -l); \
	cp tests/wheel/smoke.py "$$tmp/"; \
	$(PYTHON) -m venv "$$tmp/venv"; \
	echo "wheel $$(basename $$whl): $$(du -k $$whl | cut -f1) KiB"; \
	t0=$$($(PYTHON) -c 'import time; print(time.time())'); \
	TIMEFORMAT="pip install into a fresh venv: %R s"; \
	time $(RETRY) "$$tmp/venv/bin/pip" install $(PIP_BASE) "$$whl"; \
	cd "$$tmp" && env -u NUDGE_ASSETS -u NUDGE_REPO NUDGE_SMOKE_T0=$$t0 "$$tmp/venv/bin/python" smoke.py --scenes $$scenes

# The same smoke test in fresh venvs of other CPythons (the wheel is abi3: one for CPython
# >= 3.10), e.g. `make wheel-smoke-versions PYTHONS="python3.10 python3.12"`; an interpreter
# that is not found fails the target.
PYTHONS ?= python3.10 python3.12
wheel-smoke-versions:
	@set -e; for py in $(PYTHONS); do \
	  exe=$$(command -v $$py) || { echo "wheel-smoke-versions: $$py not found" >&2; exit 1; }; \
	  echo "== $$exe"; $(MAKE) --no-print-directory wheel-smoke PYTHON=$$exe; \
	done

# ---- tests ----------------------------------------------------------------------------------
test: venv test-rust test-examples test-python test-commonroad wheel-smoke test-fuzz

# A few minutes of the mutation fuzzer in CI: every target for CI_FUZZ_SECONDS from the
# checked-in seeds (the shipped weights, scenes, world and CommonRoad files), seed fixed (the
# tries run in the same order on every machine; how many fit depends on its speed).
CI_FUZZ_SECONDS ?= 20
test-fuzz:
	$(CARGO) run --release --quiet -p nudge-fuzz -- --seconds $(CI_FUZZ_SECONDS) --seed 7

test-rust:
	$(CARGO) test --workspace --release

# The examples/ of the facade crate and examples/python/*.py, run as users would (from the
# repository root; tests/python/test_examples.py also checks the quick start's output), and the
# command-line tools of the unpublished crates fuzz/ (nudge-fuzz) and research/ (avoidability).
test-examples: develop
	$(CARGO) run --release --quiet --example plan_one_step
	$(CARGO) run --release --quiet --example custom_predictor
	$(CARGO) run --release --quiet -p nudge-fuzz -- --tries 50 > /dev/null
	$(CARGO) run --release --quiet -p nudge-research --bin avoidability -- assets/scenes/us101-11_1-t02.1-ego132.safetensors:0 > /dev/null
	set -e; for f in examples/python/*.py; do echo "== $$f"; $(PY) "$$f"; done
	$(PY) examples/python_predictor.py

# The front-end parity test runs the CLI binary built by `build`.
test-python: develop build
	NUDGE_CLI=target/release/nudge $(PY) -m pytest -q

# The official CommonRoad drivability checker on nudge's solutions, in its own environment
# $(CR_VENV) (the commonroad extra; its protobuf pin conflicts with ray's).
CR_VENV ?= .venv-commonroad
$(CR_VENV)/.nudge-stamp: python/train/pyproject.toml
	test -x $(CR_VENV)/bin/python || $(PYTHON) -m venv $(CR_VENV)
	$(RETRY) $(CR_VENV)/bin/pip install $(PIP_BASE) --upgrade pip
	$(RETRY) $(CR_VENV)/bin/pip install $(PIP_FLAGS) -e "python/train[commonroad]" pytest
	touch $@

test-commonroad: $(CR_VENV)/.nudge-stamp build
	NUDGE_CLI=target/release/nudge $(CR_VENV)/bin/python -m pytest -q python/train/tests/test_commonroad_check.py

# Every shipped scene planned in its CommonRoad source file, the solutions checked
# (docs/results/commonroad.md).
commonroad: $(CR_VENV)/.nudge-stamp build
	$(CR_VENV)/bin/nudge-train commonroad --nudge target/release/nudge --markdown docs/results/commonroad.md

# ---- fuzzing --------------------------------------------------------------------------------
# Structure-aware mutation of weights, scenario and settings files and of planning problems
# (the unpublished crate fuzz/, nudge-fuzz), then hypothesis property tests of the Python entry
# points (tests/python/test_fuzz_py.py); every try must end in a typed error or a valid result.
# FUZZ_SECONDS is the budget per Rust target; add e.g. FUZZ_ARGS="--seed 7 --tries 100000
# --target plan". FUZZ_EXAMPLES is the number of examples per Python property. The short modes
# run in `make test` (fuzz/tests/short_mode.rs, test_fuzz_py.py with its default examples).
FUZZ_SECONDS ?= 300
FUZZ_ARGS ?=
FUZZ_EXAMPLES ?= 5000
fuzz: fuzz-rust fuzz-python

fuzz-rust:
	$(CARGO) run --release -p nudge-fuzz -- --seconds $(FUZZ_SECONDS) $(FUZZ_ARGS)

fuzz-python: develop
	NUDGE_FUZZ_EXAMPLES=$(FUZZ_EXAMPLES) $(PY) -m pytest -q -s tests/python/test_fuzz_py.py

# ---- quality --------------------------------------------------------------------------------
fmt:
	$(CARGO) fmt --all

lint:
	$(CARGO) fmt --all -- --check
	$(CARGO) clippy --workspace --all-targets -- -D warnings
	RUSTDOCFLAGS="-D warnings" $(CARGO) doc --workspace --no-deps

# The generated reference pages (tests/reference.rs fails when they are out of date).
reference-docs:
	$(CARGO) run --release --quiet --bin nudge -- settings --format markdown > docs/reference/settings.md

# ---- benches (one thread, as in the paper) ---------------------------------------------------
bench: venv
	RAYON_NUM_THREADS=1 $(CARGO) bench -p nudge-predictor --bench predictor -- --warm-up-time 1 --measurement-time 3
	$(MAKE) bench-table bench-planner

bench-planner: venv
	RAYON_NUM_THREADS=1 $(CARGO) bench -p nudge --bench planner -- --warm-up-time 1 --measurement-time 4
	RAYON_NUM_THREADS=1 $(CARGO) bench -p nudge --bench animate -- --warm-up-time 1 --measurement-time 3
	$(TRAIN) bench planner

bench-table: venv
	$(TRAIN) bench inference --markdown docs/results/inference.md

# A predictor written in Python (numpy, PyTorch) vs the built-in ones per predictor call, one
# thread (docs/python_predictor.md); needs the extension.
bench-python-predictor: develop
	$(TRAIN) bench python-predictor --markdown docs/results/python_predictor.md

# The tail of the planning step over closed-loop runs on 120 test scenes, one thread
# (docs/results/latency.md); needs the extension (make develop) and the processed scenes.
bench-latency: venv
	$(TRAIN) bench latency --split test --n 120 --out docs/results/latency.md
	$(TRAIN) bench latency --split test --n 120 --predictors student teacher --budget-ms 20 --out docs/results/latency.md

# ---- data, models, demo ---------------------------------------------------------------------
goldens: venv
	$(TRAIN) goldens

data: venv
	$(TRAIN) data build --data-root $(DATA)

# Teacher experiments (Table I): trains every python/train/configs/teacher_*.toml (resumable),
# evaluates on the test split, writes docs/results/teacher.md. EXPORT=1 also exports the chosen
# teacher to assets/models/teacher.safetensors (which invalidates the distillation set).
teacher: venv
	test -f data/processed/manifest.json || $(MAKE) data
	$(TRAIN) teacher --report docs/results/teacher.md $(if $(EXPORT),,--no-export)

# Distillation set (the planner run with the shipped teacher; resumable) and the student.
DISTILL_SIZE ?= train=48,val=8,test=8
distill: develop
	test -f data/processed/manifest.json || $(MAKE) data
	$(TRAIN) distill --size $(DISTILL_SIZE)

student: distill
	$(TRAIN) student --report docs/results/student.md

# Reaction (docs/results/reaction.md): a distillation set with more scenes in $(REACT_DISTILL), a
# student distilled with a loss on its reaction to the ego in two runs (~30 + 15 min on 1 thread;
# exported to its run folder, never over the shipped student), and the reaction table of the
# teacher, the shipped student and that one against real cut-ins and held-out planner candidates.
REACT_DISTILL ?= runs/distill
REACT_STUDENT ?= runs/student_react_cont/student.safetensors
distill-react: develop
	test -f data/processed/manifest.json || $(MAKE) data
	$(TRAIN) distill --size train=160,val=32,test=32 --threads 2 --out $(REACT_DISTILL)

student-react: distill-react
	$(TRAIN) student-react --config python/train/configs/student_react.toml
	$(TRAIN) student-react --config python/train/configs/student_react_cont.toml

reaction: distill-react
	$(TRAIN) reaction --distill $(REACT_DISTILL) --report docs/results/reaction.md $(if $(wildcard $(REACT_STUDENT)),--candidate student_react=$(REACT_STUDENT),)

# The paper's evidence in one command (docs/paper/README.md): Table I from docs/results/teacher.md,
# Figures 7-10 by vehicle count (7 x 100 closed-loop runs per predictor, one thread) and Table II
# (a fresh paper-size distillation set and five students: about 1.6 h on one thread, the figures
# 12 min more). Resumable; caches in runs/paper.
# paper-quick: the same pipeline end to end on tiny sizes into runs/paper_quick (tests run it too).
paper: develop
	test -f data/processed/manifest.json || $(MAKE) data
	$(TRAIN) paper

paper-quick: develop
	$(TRAIN) paper --quick --no-progress

# Each planner against the same model with its predicted reaction ablated (planner setting
# ablate_reaction), on dense scenes of the validation and test splits, in the idm, teacher and
# log_replay worlds: docs/results/interaction.md (~35 min on 2 threads of a loaded 2-core machine;
# resumable, runs cached under runs/interaction). The reaction-distilled student joins as a
# candidate when make student-react has made it.
interaction: develop
	nice -n 5 $(TRAIN) interaction --threads 2 --out docs/results/interaction.md $(if $(wildcard $(REACT_STUDENT)),--candidate $(REACT_STUDENT),)

# The same experiment on every real merge (ego lane ends) of the train and test splits; the
# validation split has none. Intervals over ego vehicles.
interaction-merge: develop
	nice -n 5 $(TRAIN) interaction --scenes merge --splits train test --n 105 7 --teacher-n 30 7 --threads 2 \
		--out docs/results/interaction_merge.md --json runs/interaction/interaction_merge.json \
		$(if $(wildcard $(REACT_STUDENT)),--candidate $(REACT_STUDENT),)

# The main job: closed-loop lane changes on the shipped real NGSIM scenes (one run each),
# planned with the shipped distilled student (PREDICTOR=teacher|constant_velocity for the
# others), the trained teacher moving the other vehicles; per-step table of one run, summary
# over all, records (CSV/JSON), an animation of every run (out/demo/animations/<scene>-seed<seed>.gif;
# the README's picture is one of them) and a picture in out/demo/, drawn in the light environment
# $(DEMO_VENV).
PREDICTOR ?= student
demo: venv-demo build
	$(CARGO) run --release --bin nudge -- simulate --scenes assets/scenes --predictor $(PREDICTOR) \
		--world teacher --seed 0 --runs 1 --threads 2 --out out/demo --verbose-run \
		--animate
	$(DEMO_VENV)/bin/nudge-train figures runs out/demo --scenes assets/scenes --png out/demo/runs.png
	@echo "== the shipped real merges (assets/scenes/merge: the ego's lane ends) =="
	$(CARGO) run --release --bin nudge -- simulate --scenes assets/scenes/merge --predictor $(PREDICTOR) \
		--world teacher --seed 0 --runs 1 --threads 2 --out out/demo/merge
	$(DEMO_VENV)/bin/nudge-train figures runs out/demo/merge --scenes assets/scenes/merge \
		--png out/demo/merge/runs.png

ci: lint test

clean:
	$(CARGO) clean
	rm -rf $(VENV) $(DEMO_VENV)
