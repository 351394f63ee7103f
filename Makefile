# quadswarm: `make demo` flies the paper's scenario and writes ./report; `make test` runs the suite.
# Each target creates or reuses .venv and installs what it needs first.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed-$(shell cat pyproject.toml | cksum | cut -d' ' -f1)
export MAVLINK20 := 1
export MPLBACKEND := Agg

.PHONY: demo test lint typecheck bench venv clean

venv: $(STAMP)

$(STAMP): pyproject.toml
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	@rm -f $(VENV)/.installed-*
	@touch $@

demo: $(STAMP)
	$(BIN)/swarm simulate scenarios/paper.toml --report report

lint: $(STAMP)
	$(BIN)/ruff check gcs drone_agent sitl_sim protocols tests bench scripts

typecheck: $(STAMP)
	$(BIN)/mypy

test: lint typecheck
	$(BIN)/python -m pytest -q

bench: $(STAMP)
	$(BIN)/python -m bench.run --out bench/results.json

clean:
	rm -rf $(VENV) report .pytest_cache .mypy_cache .ruff_cache
