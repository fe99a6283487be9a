# The README's commands. Each one sets up its own virtual environment on first use.
SHELL := /bin/bash
PYTHON ?= python3
VENV := .venv
VPY := $(VENV)/bin/python
STAMP := $(VENV)/.requirements-installed
DURATION ?= 20

# Keep DDS discovery on this machine for everything started from here.
export ROS_AUTOMATIC_DISCOVERY_RANGE := LOCALHOST

.PHONY: demo test lint bench venv clean

venv: $(STAMP)

$(STAMP): requirements.txt
	$(PYTHON) -m venv $(VENV)
	$(VPY) -m pip install --upgrade --quiet pip
	$(VPY) -m pip install --quiet -r requirements.txt
	touch $@

demo: $(STAMP)
	$(VPY) -m kraft_master_driver.demo --duration $(DURATION)

test: $(STAMP)
	$(VPY) -m pytest -q

lint: $(STAMP)
	$(VPY) -m pytest -q -m linter

bench: $(STAMP)
	$(VPY) benchmarks/kinematics.py

clean:
	rm -rf $(VENV) build install log .pytest_cache .hypothesis
