# quadswarm: `make demo` flies the paper's scenario and writes ./report; `make test` runs the suite.
# Each target creates or reuses .venv and installs what it needs first.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed-$(shell cat pyproject.toml | cksum | cut -d' ' -f1)
export MAVLINK20 := 1
export MPLBACKEND := Agg

.PHONY: demo test lint typecheck bytecode browser bench scenarios venv clean

venv: $(STAMP)

$(STAMP): pyproject.toml
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	# [view]: Rerun (swarm view / replay, flight.rrd), so that its tests run too
	$(BIN)/python -m pip install --quiet -e '.[dev,view]'
	# MAVProxy is a real ground-station peer for the SITL tests; --no-deps keeps it headless
	# (its GUI dependencies weigh ~1.4 GB and are not needed).
	$(BIN)/python -m pip install --quiet --no-deps 'MAVProxy>=1.8,<2' 'pyserial>=3.5'
	@rm -f $(VENV)/.installed-*
	@touch $@

demo: $(STAMP) bytecode
	$(BIN)/swarm demo

lint: $(STAMP)
	$(BIN)/ruff check gcs drone_agent sitl_sim protocols tests bench scripts

typecheck: $(STAMP)
	$(BIN)/mypy

# Two parts (tests/conftest.py): the tests that do not depend on the machine's load on two
# workers at once (a module's tests stay together), then the serial ones (realtime clock, default
# ports) one at a time. Both parts run; the target fails if either failed.
test: lint typecheck bytecode browser
	@status=0; \
	$(BIN)/python -m pytest -q -n 2 --dist loadgroup -m "not serial" --durations=15 || status=$$?; \
	$(BIN)/python -m pytest -q -m serial --durations=10 || status=$$?; \
	exit $$status

# Headless Chromium for the viewer's screenshot tests (tests/test_view.py): Debian's package,
# installed with apt-get where it is missing and this runs as root (as CI does); elsewhere it
# prints why not, and those tests are skipped saying so.
browser: $(STAMP)
	@$(BIN)/python tests/headless_chromium.py

# The project's modules compiled once: the suite and a flight start hundreds of processes, each
# of which would otherwise compile them from source again where PYTHONDONTWRITEBYTECODE is set
# (~0.3 s of CPU per agent process).
bytecode: $(STAMP)
	@$(BIN)/python -m compileall -q gcs drone_agent sitl_sim protocols tests bench > /dev/null

# regenerate scenarios/ (the library of `swarm scenario new` files; paper.toml has its own script)
scenarios: $(STAMP)
	PYTHONPATH=. $(BIN)/python scripts/make_scenarios.py
	PYTHONPATH=. $(BIN)/python scripts/make_paper_scenario.py scenarios/paper.toml

bench: $(STAMP)
	# RotorPy is the reference the simulator's physics step is compared with (bench only)
	$(BIN)/python -m pip install --quiet rotorpy
	$(BIN)/python -m bench.run --out bench/results.json
	# the issue targets, each as the plain command flies it: bench/results_targets.json, targets.md, .png
	$(BIN)/python -m bench.targets

clean:
	rm -rf $(VENV) report .pytest_cache .mypy_cache .ruff_cache
