# dlmpc_ros: every target installs what it needs into .venv on first use.
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
OUT    ?= out
# Isolate ROS traffic of tests and demos from anything else on the machine.
export ROS_AUTOMATIC_DISCOVERY_RANGE ?= LOCALHOST
export ROS_LOG_DIR ?= $(abspath $(OUT))/ros-log

.PHONY: venv test demo evaluate evaluate-plants evaluate-heldout ablation bench fuzz ros2cli \
	lint data models clean

venv: $(STAMP)

$(STAMP): requirements.txt setup.py
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --disable-pip-version-check -r requirements.txt
	# --use-pep517: once `make ros2cli` has installed wheel, pip would otherwise reinstall
	# by the legacy `setup.py develop`, which puts the console scripts in .venv/lib/dlmpc_ros
	# (setup.cfg) instead of .venv/bin
	$(PY) -m pip install --quiet --disable-pip-version-check --no-deps --no-build-isolation \
	    --use-pep517 -e .
	$(PY) -c "from dlmpc_ros.core.cavity import compile_kernels; compile_kernels()"
	$(PY) -m compileall -q dlmpc_ros
	touch $(STAMP)

# The suite on TEST_WORKERS processes (pytest-xdist), each test file on one of them (its
# module fixtures made once); every worker's ROS tests use their own domains (test/domains.py).
TEST_WORKERS ?= 2
test: $(STAMP)
	$(PY) -m pytest -q -n $(TEST_WORKERS) --dist loadfile --durations=15 test

demo: $(STAMP)
	$(VENV)/bin/bringup --controller dlmpc --lockstep --scenario sinusoidal \
	    --scenario-param amplitude=0.25 --scenario-param period=4000 \
	    --round-trips 8000 --csv $(OUT)/demo/run.csv --plot $(OUT)/demo/run.png \
	    --log-dir $(OUT)/demo/logs

# The closing table of the closed-loop issue: every controller on every scenario, in one
# process (about 10 minutes on 2 cores); drop --fast to run each through the node graph.
SEEDS ?= 1 2 3
CONTROLLERS ?= dlmpc esc ga passive fixed_best oracle
evaluate: $(STAMP)
	$(VENV)/bin/dlmpc-evaluate --fast --round-trips 20000 \
	    $(foreach s,sinusoidal chirp random_walk steps,--scenario $(s)) \
	    $(foreach c,$(CONTROLLERS),--controller $(c)) \
	    $(foreach s,$(SEEDS),--seed $(s)) --out $(OUT)/evaluate

# Controllers on lasers that are not the model (docs/results/plants): the nominal cavity
# and plants 1-8 of the family, on two drifts, and the auto-mode-locking benchmark (100
# cold starts per plant). Dask runs it on every core (WORKERS=1: serially); the drift
# runs are saved as they finish, and a rerun keeps them (--resume).
PLANTS ?= 1 2 3 4 5 6 7 8
WORKERS ?= $(shell nproc)
evaluate-plants: $(STAMP)
	$(VENV)/bin/dlmpc-evaluate --fast --round-trips 20000 --nominal \
	    $(foreach p,$(PLANTS),--plant-family $(p)) \
	    --scenario sinusoidal --scenario random_walk $(foreach s,$(SEEDS),--seed $(s)) \
	    $(foreach c,$(CONTROLLERS),--controller $(c)) --workers $(WORKERS) \
	    --resume --out $(OUT)/plants/drift
	$(VENV)/bin/dlmpc-evaluate --benchmark lock --starts 100 --nominal \
	    $(foreach p,$(PLANTS),--plant-family $(p)) \
	    $(foreach c,$(CONTROLLERS),--controller $(c)) --workers $(WORKERS) \
	    --out $(OUT)/plants/lock

# Issue 15's held-out benchmark (docs/controller.md): family plants 101-108, used for no
# choice, two drifts, seeds 1-3, every controller; the lock benchmark on them and the
# nominal cavity. About an hour on 2 cores; --resume keeps the runs already made.
HELDOUT ?= 101 102 103 104 105 106 107 108
evaluate-heldout: $(STAMP)
	$(VENV)/bin/dlmpc-evaluate --fast --round-trips 20000 \
	    $(foreach p,$(HELDOUT),--plant-family $(p)) \
	    --scenario sinusoidal --scenario random_walk $(foreach s,$(SEEDS),--seed $(s)) \
	    $(foreach c,$(CONTROLLERS),--controller $(c)) --workers $(WORKERS) \
	    --resume --out $(OUT)/heldout/drift
	$(VENV)/bin/dlmpc-evaluate --benchmark lock --starts 100 --nominal \
	    $(foreach p,$(HELDOUT),--plant-family $(p)) \
	    $(foreach c,$(CONTROLLERS),--controller $(c)) --workers $(WORKERS) \
	    --out $(OUT)/heldout/lock

# The ablation of docs/controller.md: the DL-MPC without each of its parts, on the nominal
# cavity and the held-out plants (bench/ablation_variants.json; nominal-only pretraining
# first makes its own predictor with bench/nominal_pretraining.py).
ablation: $(STAMP)
	$(PY) bench/nominal_pretraining.py --out $(OUT)/nominal-only
	OUT=$(abspath $(OUT)) $(PY) bench/dlmpc_variants.py --variants bench/ablation_variants.json --nominal \
	    $(foreach p,$(HELDOUT),--plant-family $(p)) --scenario sinusoidal \
	    --scenario random_walk --seeds $(SEEDS) --workers $(WORKERS) \
	    --out $(OUT)/ablation/ablation.json

bench: $(STAMP)
	$(PY) bench/bench_cavity.py --out $(OUT)/bench

# The real ros2 command line and colcon in .venv, for test/nodes/test_ros2_cli.py (from
# ../shared/tools/install-ros2cli where it exists; without them those tests are skipped).
ROS2CLI ?= ../shared/tools/install-ros2cli
ros2cli: $(STAMP)
	@if [ -x $(ROS2CLI) ]; then $(ROS2CLI) $(VENV) && $(PY) -m pip install --quiet \
	    --disable-pip-version-check colcon-common-extensions==0.3.0 colcon-core==0.21.3 \
	    colcon-ros==0.5.0; else echo "no $(ROS2CLI): the ros2 CLI tests will be skipped"; fi

# Longer property-based fuzzing than make test runs (hypothesis profile 'long').
fuzz: $(STAMP)
	DLMPC_FUZZ_PROFILE=long $(PY) -m pytest -q test/core/test_fuzz_core.py \
	    test/control/test_fuzz_controllers.py test/nodes/test_fuzz_properties.py

# Regenerate the training data (data/, not committed) and the shipped models (models/);
# then the deep-RL baseline (no data needed; about 20 minutes on one core, docs/gym.md).
data: $(STAMP)
	$(VENV)/bin/dlmpc-data all --data-dir data

models: data
	$(VENV)/bin/dlmpc-train all --data-dir data --models-dir models
	$(VENV)/bin/dlmpc-train drl --data-dir data --models-dir models

# ruff, then the import contracts of .importlinter (the layers of docs/architecture.md).
lint: $(STAMP)
	$(VENV)/bin/ruff check dlmpc_ros test bench
	$(VENV)/bin/lint-imports

clean:
	rm -rf $(VENV) $(OUT) build *.egg-info
