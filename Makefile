# m4k -- one entry point. Every target sets the workspace up first (idempotent, seconds when done).
# How long each takes, as measured: the README ("Two commands" and "Results"), stated once there.
#   make run [CONFIG=my_robot.yaml] [FOXGLOVE=1]   the robot stack on simulated hardware (Ctrl-C
#                                     stops it); FOXGLOVE=1 adds the live view on localhost:8765
#   make lint                         tools/lint.sh: ruff, then mypy (mypy.ini)
#   make test                         lint + colcon test of every package + workspace tests, in
#                                     four streams side by side (M4K_TEST_SERIAL_ALONE=1: the
#                                     serial one alone, after the others; docs/testing.md)
#   make check                        lint + the unit tiers: make test without the tests marked
#                                     e2e (they start the stack, processes or ROS nodes); lint,
#                                     colcon test and the workspace tier side by side
#   make bench [QUICK=1] [ROUNDS=5]   the evidence in rounds (Table 1, utilization, Fig. 10, scaling)
#                                     and the guard's reaction
#   make bench RUNS=2                 two full runs, one after the other -> docs/results/bench-1, -2
#                                     and their combined table docs/results/bench-combined.md
#   make demo                         the 3 m drive past the obstacle (Fig. 9)
#   make scenarios [ONLY='a b'] [SHORT=1]  config/scenarios/*.yaml, then the envelope grid
#                                     (config/envelope.yaml), on the whole stack, judged on
#                                     ground truth -> docs/results/scenarios/ (with ONLY or
#                                     SHORT: log/scenarios/, the published table kept)
#   make soak [DURATION=600]          the stack driving in a loop under stress-ng: crashes, leaks
#   make fuzz [COUNT=100000] [SEED=n] [SECONDS_PER_PORT=18]  random and mutated datagrams at every
#                                     XDDP port of a real rt_core, then every
#                                     property test with the same seed and 20x the examples
SHELL := /bin/bash
.SHELLFLAGS := -eu -o pipefail -c
ENV := source tools/env.sh
SOURCES := $(shell find src config compat -type f -not -path '*/__pycache__/*' -not -name '*.pyc' 2>/dev/null)
BUILD_STAMP := install/.m4k-build-stamp
COLCON_FLAGS := --event-handlers console_cohesion- status- --metas colcon.meta

.PHONY: setup build test check lint run bench demo scenarios soak fuzz clean

setup:
	@tools/setup.sh

$(BUILD_STAMP): $(SOURCES) tools/setup.sh tools/compat-paths.sh requirements.txt colcon.meta
	@tools/setup.sh
	@echo 'm4k: colcon build' >&2
	@mkdir -p build; $(ENV); flock build/.m4k-build.lock colcon --log-base log build $(COLCON_FLAGS) \
	  --base-paths src $$(tools/compat-paths.sh) \
	  --cmake-args -DPython3_EXECUTABLE=$$VIRTUAL_ENV/bin/python3 >&2 \
	  || { echo 'm4k: colcon build failed (see log/latest_build)' >&2; exit 1; }
	@touch $(BUILD_STAMP)

build: setup $(BUILD_STAMP)

lint: setup
	@$(ENV); tools/lint.sh

test: build
	@tools/run-tests.sh

check: build
	@tools/run-tests.sh --check

run: build
	@$(ENV); bringup $(if $(CONFIG),--config $(CONFIG),) $(if $(FOXGLOVE),--foxglove,)

BENCH_ARGS = $(if $(QUICK),--quick,) $(if $(DURATION),--duration $(DURATION),) $(if $(ROUNDS),--rounds $(ROUNDS),)
bench: build
	@$(ENV); if [ -z '$(RUNS)' ]; then bench $(BENCH_ARGS); else dirs=; \
	  for i in $$(seq 1 $(RUNS)); do bench $(BENCH_ARGS) --publish docs/results/bench-$$i; \
	  dirs="$$dirs docs/results/bench-$$i"; done; \
	  bench_combine $$dirs --out docs/results/bench-combined.md; cat docs/results/bench-combined.md; fi

demo: build
	@$(ENV); demo

scenarios: build
	@$(ENV); M4K_CONFIG_DIR=$(CURDIR)/config scenarios config/scenarios config/envelope.yaml $(if $(ONLY),--only $(ONLY),) \
	  $(if $(SHORT),--short,)

soak: build
	@$(ENV); soak $(if $(DURATION),--duration $(DURATION),)

fuzz: build
	@$(ENV); seed='$(SEED)'; seed=$${seed:-$$(od -An -N4 -tu4 /dev/urandom | tr -d ' ')}; rc=0; \
	  fuzz --count $(or $(COUNT),100000) --seed $$seed \
	    $(if $(SECONDS_PER_PORT),--seconds-per-port $(SECONDS_PER_PORT),) || rc=1; \
	  tools/fuzz-properties.sh $$seed || rc=1; exit $$rc

clean:
	rm -rf build install log
