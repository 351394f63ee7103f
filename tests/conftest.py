"""Session fixtures shared by test modules."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from hypothesis import settings
from paper_flight import run_demo, simulate_paper

# Property tests draw the same examples on every run (CI included): a failure is reproducible,
# and a green run stays green. Set HYPOTHESIS_PROFILE=explore to draw new examples.
settings.register_profile("repeatable", derandomize=True)
settings.register_profile("explore", derandomize=False)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "repeatable"))


@pytest.fixture(scope="session")
def simulated_paper_report(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The report of ``swarm simulate scenarios/paper.toml`` (about a minute), run once."""
    return simulate_paper(tmp_path_factory.mktemp("paper"))


@pytest.fixture(scope="session")
def demo_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str]:
    """``swarm demo`` (what ``make demo`` runs: the paper's 200 s flight, lockstep, one agent
    process per drone; about 3 minutes), run once: its report folder and printed output. Read by
    tests/test_demo_paper.py and, for its first 20 s, by tests/test_lockstep_repeats.py."""
    return run_demo(tmp_path_factory.mktemp("demo"))


def pytest_sessionstart(session: pytest.Session) -> None:
    """Compile the simulator's and agents' compiled loops (numba), or load them from the cache,
    once before any test: the processes the tests start then load them instead of each compiling
    them at the same moment on a fresh checkout (seconds of CPU each, which timing-sensitive
    realtime flights would feel)."""
    from drone_agent.agent_core import warm_up
    from drone_agent.config import agent_config
    from protocols.scenario import load_scenario
    from sitl_sim import physics_jit

    physics_jit.ready()
    warm_up(agent_config(load_scenario(Path(__file__).parents[1] / "scenarios" / "paper.toml")))
