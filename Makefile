# All targets create .venv on a fresh machine and install what they need.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

# Every process started here stays on this machine's loopback (DDS discovery) with its own domain.
export ROS_AUTOMATIC_DISCOVERY_RANGE := LOCALHOST
export ROS_DOMAIN_ID ?= 42

.PHONY: run demo-track test test-fast lint venv clean

venv: $(STAMP)

$(STAMP): pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[test,bench,ros,view,batch]'
	touch $(STAMP)

run: $(STAMP)
	$(VENV)/bin/mps demo press-cycle

# the node following an emulated press (docs/ros.md, Following a press): 2 s of press-cycle's
# truth, recorded under recordings/; the node stopped 2 s after the emulator has finished (time
# to take the measurements still queued)
demo-track: $(STAMP)
	$(VENV)/bin/mps node press-cycle --ros-args -p track:=/press/joint_states \
		-p track_mode:=/press/mode & node=$$!; \
	$(VENV)/bin/mps emulator press-cycle --t-end 2.0 --slider --glitch 1.0:jump; status=$$?; \
	sleep 2; kill -INT $$node; wait $$node; exit $$status

# two pytest workers (pytest-xdist), a test file to each at a time: the ROS tests mostly wait on
# their nodes, so two at once halve the suite's time on two cores. A worker that crashes ends the
# run (failed, with the test it crashed in): xdist 3.8 replacing it under loadfile hangs at the end
PYTEST := $(PY) -m pytest -q -n 2 --dist loadfile --max-worker-restart 0

test: lint
	$(PYTEST)

# the house's habits: lint and layout (ruff, its rules in pyproject.toml) and types (mypy on
# mps_core and mps_ros); `ruff format .` lays a file out as the check wants it
lint: $(STAMP)
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .
	$(VENV)/bin/mypy

test-fast: $(STAMP)
	$(PYTEST) -m 'not slow'

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache
