# gyro_ekf: `make demo` runs the main job on the bundled bag, `make test` runs the tests.
# Both create .venv by themselves (Python 3.10-3.13 and PyPI are all they need).

PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed-stamp

# DDS discovery stays on this machine and in the project's own domain, whoever runs make.
export ROS_AUTOMATIC_DISCOVERY_RANGE := LOCALHOST
GYRO_EKF_DOMAIN_ID ?= 42
export ROS_DOMAIN_ID := $(GYRO_EKF_DOMAIN_ID)
export ROS_LOG_DIR := $(CURDIR)/.ros/log
export MPLBACKEND := Agg

DEMO_BAG := bags/sim_static_start

.PHONY: venv demo test bags bench stress fuzz lint docs clean

venv: $(STAMP)

$(STAMP): setup.py package.xml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install -qq --upgrade pip setuptools wheel
	$(BIN)/pip install -qq -e '.[ros,test,bench]'
	touch $@

# --force: a second `make demo` replaces the first one's products (only those: demo refuses
# a folder holding anything else).
demo: $(STAMP)
	$(BIN)/gyro-ekf demo $(DEMO_BAG) -o results/demo --force

test: $(STAMP)
	$(BIN)/python -m pytest -q test

bags: $(STAMP)
	$(BIN)/gyro-ekf make-bags bags --force

bench: $(STAMP)
	$(BIN)/python -m benchmarks -o results/bench.json

# Seeded simulated trips per perturbation class (docs/stress.md) through the offline run;
# prints per class the share within the bounds and the silent failures, writes
# results/stress.json (--force: a second `make stress` replaces the first one's). A benchmark,
# never a test: it reports, it does not fail.
stress: $(STAMP)
	$(BIN)/gyro-ekf stress -o results/stress.json --force $(STRESS_ARGS)

# Mutated bags, chunks, CDR payloads, course logs and params files through the readers;
# bounded (FUZZ_ARGS, e.g. --budget-s 60 --seed 3), writes results/fuzz.json.
fuzz: $(STAMP)
	$(BIN)/python -m fuzz $(FUZZ_ARGS)

# docs/parameters.md and config/gyro_ekf.yaml from the nodes' declarations (tests compare them).
docs: $(STAMP)
	$(BIN)/python tools/parameters_doc.py docs/parameters.md

lint: $(STAMP)
	$(BIN)/python -m pytest -q -m linter test

clean:
	rm -rf build install log results .ros .pytest_cache
