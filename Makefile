# The README's commands. Each one sets up its own virtual environment on first use.
SHELL := /bin/bash
PYTHON ?= python3
VENV := .venv
VPY := $(VENV)/bin/python
STAMP := $(VENV)/.requirements-installed
DURATION ?= 20
DELAY_MS ?= 0
PASSIVITY ?= off

# Keep DDS discovery on this machine for everything started from here.
export ROS_AUTOMATIC_DISCOVERY_RANGE := LOCALHOST

.PHONY: demo test lint bench soak venv clean

venv: $(STAMP)

$(STAMP): requirements.txt
	$(PYTHON) -m venv $(VENV)
	$(VPY) -m pip install --upgrade --quiet pip
	$(VPY) -m pip install --quiet -r requirements.txt
	touch $@

demo: $(STAMP)
	$(VPY) -m kraft_master_driver.demo --duration $(DURATION) --delay-ms $(DELAY_MS) \
		--passivity $(PASSIVITY)

test: $(STAMP)
	$(VPY) -m pytest -q

lint: $(STAMP)
	$(VPY) -m pytest -q -m linter

# Figures, not tests: each prints a table (loop and link also write JSON).
bench: $(STAMP)
	$(VPY) benchmarks/kinematics.py
	$(VPY) benchmarks/link.py
	$(VPY) benchmarks/loop.py --repeat 3
	$(VPY) benchmarks/messages.py
	$(VPY) benchmarks/report.py

# A long run at 1 kHz with random faults, not part of `make test`: one hour unless
# `make soak DURATION=600` says otherwise.
soak: $(STAMP)
	$(VPY) benchmarks/soak.py --duration $(if $(filter command line,$(origin DURATION)),$(DURATION),3600)

clean:
	rm -rf $(VENV) build install log .pytest_cache .hypothesis
