# robot_calib: two commands set everything up on a fresh machine.
#   make demo   create .venv, install pinned dependencies, replay bags/ through every node
#   make test   create .venv if needed, then run the whole test suite
SHELL := /bin/bash
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
# ROS 2 discovery stays on this machine
export ROS_AUTOMATIC_DISCOVERY_RANGE ?= LOCALHOST

.PHONY: venv demo test bench lint config clean

venv: $(STAMP)

$(STAMP): requirements.txt requirements-bench.txt requirements-ray.txt requirements-build.txt \
		setup.py tools/build_tf2_msgs.sh
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -r requirements.txt -r requirements-bench.txt -r requirements-ray.txt
	$(PY) -m pip install --quiet --no-deps -e .
	# tf2_msgs (/tf, /tf_static) has no wheel: built from its message definition (where cmake
	# and a C/C++ compiler are missing, a one-line note and the rest is set up all the same)
	bash tools/build_tf2_msgs.sh $(VENV)
	touch $(STAMP)

demo: venv
	rm -rf demo_out && mkdir -p demo_out
	$(VENV)/bin/robot-calib replay bags/sim_drive --out demo_out/sim_drive
	$(VENV)/bin/robot-calib replay bags/husky_test1 --out demo_out/husky_test1
	@echo "reports: demo_out/sim_drive/report.md demo_out/husky_test1/report.md"

test: venv
	$(PY) -m pytest -q test

bench: venv
	for script in benchmarks/bench_*.py; do $(PY) $$script || exit 1; done
	$(PY) benchmarks/assemble_report.py

config: venv
	$(PY) -m robot_calib.config_gen > config/robot_calib.yaml

clean:
	rm -rf build install log demo_out
