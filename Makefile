# Two commands: `make demo` and `make test`. Both create .venv when missing and install the package
# (ROS 2 from PyPI wheels) into it; nothing is installed by hand.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
export ROS_AUTOMATIC_DISCOVERY_RANGE := LOCALHOST
export RMW_IMPLEMENTATION := rmw_fastrtps_cpp
export MPLBACKEND := Agg

.PHONY: demo test install bench paper clean

$(PY):
	$(PYTHON) -m venv $(VENV)

$(STAMP): $(PY) setup.py
	$(PY) -m pip install --quiet --upgrade pip setuptools wheel
	$(PY) -m pip install --quiet -e '.[ros,test,peers]'
	touch $(STAMP)

install: $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/tensegrity demo

# the suite on every core (pytest-xdist, a test to each idle worker); the kernels are compiled
# first, once, by test/conftest.py
test: $(STAMP)
	$(PY) -m pytest -q -n auto --dist worksteal test

bench: $(STAMP)
	$(VENV)/bin/tensegrity bench

paper: $(STAMP)
	$(VENV)/bin/tensegrity paper

clean:
	rm -rf $(VENV) build *.egg-info runs
