# Two commands for a newcomer: `make demo` (the main job) and `make test` (the test suite).
# Both create the virtual environment in .venv on first use.

PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
DEMO_DIR := out/demo-$(shell date +%Y%m%d-%H%M%S)

.PHONY: demo demo-offline test bench clean-venv

$(STAMP): pyproject.toml setup.py
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $(STAMP)

# The whole loop: the daemon on the simulated world, a calibration worker, a 20-pose capture
# scripted through the micam commands, live and final calibration, a report against the truth.
# It stays headless; it prints the `micam web` command that shows it live in a browser (the
# operator's page, docs/operator.md).
demo: $(STAMP)
	$(BIN)/python -m micam.demo_loop --out $(DEMO_DIR) --poses 20

# The same capture without the daemon, then `micam calibrate` in this process.
demo-offline: $(STAMP)
	$(BIN)/micam simulate --out $(DEMO_DIR)/session --poses 20
	$(BIN)/micam inspect $(DEMO_DIR)/session
	$(BIN)/micam calibrate $(DEMO_DIR)/session --out $(DEMO_DIR)/result.json \
		--acoular-xml $(DEMO_DIR)/microphones.xml

# On every core (pytest-xdist), each test module whole on one worker (tests/conftest.py).
test: $(STAMP)
	$(BIN)/python -m pytest -q -n auto

bench: $(STAMP)
	$(BIN)/python benchmarks/bench_simulation.py

clean-venv:
	rm -rf $(VENV)
