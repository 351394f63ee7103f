"""Session fixtures shared by test modules."""

from __future__ import annotations

from pathlib import Path

import pytest
from paper_flight import simulate_paper


@pytest.fixture(scope="session")
def simulated_paper_report(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The report of ``swarm simulate scenarios/paper.toml`` (about a minute), run once."""
    return simulate_paper(tmp_path_factory.mktemp("paper"))
