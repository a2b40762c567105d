# dlmpc_ros: every target installs what it needs into .venv on first use.
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
OUT    ?= out
# Isolate ROS traffic of tests and demos from anything else on the machine.
export ROS_AUTOMATIC_DISCOVERY_RANGE ?= LOCALHOST
export ROS_LOG_DIR ?= $(CURDIR)/$(OUT)/ros-log

.PHONY: venv test demo bench lint data models clean

venv: $(STAMP)

$(STAMP): requirements.txt setup.py
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --disable-pip-version-check -r requirements.txt
	$(PY) -m pip install --quiet --disable-pip-version-check --no-deps --no-build-isolation -e .
	touch $(STAMP)

test: $(STAMP)
	$(PY) -m pytest -q test

demo: $(STAMP)
	$(VENV)/bin/bringup --scenario sinusoidal --scenario-param period=2000 \
	    --round-trips 6000 --csv $(OUT)/demo/run.csv --plot $(OUT)/demo/run.png \
	    --log-dir $(OUT)/demo/logs

bench: $(STAMP)
	$(PY) bench/bench_cavity.py --out $(OUT)/bench

# Regenerate the training data (data/, not committed) and the shipped models (models/).
data: $(STAMP)
	$(VENV)/bin/dlmpc-data all --data-dir data

models: data
	$(VENV)/bin/dlmpc-train all --data-dir data --models-dir models

lint: $(STAMP)
	$(VENV)/bin/ruff check dlmpc_ros test bench

clean:
	rm -rf $(VENV) $(OUT) build *.egg-info
