"""Session fixtures shared by test modules."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from hypothesis import settings
from paper_flight import simulate_paper

# Property tests draw the same examples on every run (CI included): a failure is reproducible,
# and a green run stays green. Set HYPOTHESIS_PROFILE=explore to draw new examples.
settings.register_profile("repeatable", derandomize=True)
settings.register_profile("explore", derandomize=False)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "repeatable"))


@pytest.fixture(scope="session")
def simulated_paper_report(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The report of ``swarm simulate scenarios/paper.toml`` (about a minute), run once."""
    return simulate_paper(tmp_path_factory.mktemp("paper"))
