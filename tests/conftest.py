"""Session fixtures shared by test modules."""

from __future__ import annotations

import os
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

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
    """``swarm demo`` (what ``make demo`` runs: the paper's 200 s flight, lockstep, the nine
    agents hosted in one process; under a minute), run once: its report folder and printed
    output. Read by tests/test_demo_paper.py and by tests/test_lockstep_repeats.py (against
    ``swarm simulate``'s flight)."""
    return run_demo(tmp_path_factory.mktemp("demo"))


#: when the session started (monotonic s): the part's wall time in test-times/
_session_start = [0.0]


def pytest_sessionstart(session: pytest.Session) -> None:
    """Compile the simulator's and agents' compiled loops (numba), or load them from the cache,
    once before any test: the processes the tests start then load them instead of each compiling
    them at the same moment on a fresh checkout (seconds of CPU each, which timing-sensitive
    realtime flights would feel)."""
    _session_start[0] = time.monotonic()
    from drone_agent.core import flight_phase
    from drone_agent.core.agent_core import warm_up
    from drone_agent.core.config import agent_config
    from protocols.scenario.scenario_file import load_scenario
    from sitl_sim.physics import jit as physics_jit

    physics_jit.ready()
    config = agent_config(load_scenario(Path(__file__).parents[1] / "scenarios" / "paper.toml"))
    warm_up(config)
    flight_phase.warm_up(config.limits)


# -- make test's two parts -------------------------------------------------------------------
# ``make test`` runs the suite in two parts (Makefile): first every test not marked ``serial`` on
# two pytest-xdist workers at once (lockstep and in-process flights give the same result however
# loaded the machine is, and unit tests do not care), then the ``serial`` tests one at a time.
# Serial: flights paced by the wall clock (a second flight beside them on two cores makes them
# miss ticks: their verdicts depend on the machine's load), except, in a realtime module, the
# lockstep case of a test parametrised by its ``clock`` and a test marked ``lockstep``. Flights
# on the default ports
# (14540.., 14550, Zenoh 7447: only one run on the machine can have them) fly in the first part,
# all in one xdist group, so one after the other on one worker (the other tests take ports the
# system hands out, above 32767, never these); those of them on the realtime clock are serial.
#: test modules whose flights run on the realtime clock
REALTIME_MODULES = frozenset(
    {
        "test_agent_flight",
        "test_agent_ground",
        "test_agent_vehicle_silence",
        "test_agent_without_scenario",
        "test_ardupilot_sitl",  # real ArduCopter SITL steps in real time (skipped without it)
        "test_drills",
        "test_gcs_flight",
        "test_host_batching",  # a tick's datagrams 0.4 ms apart against a 2 ms wait
        "test_lockstep_stall",  # a process frozen 4 s against a 5 s lease: wall-clock margins
        "test_lockstep_zenoh",  # Zenoh's send queue under a load the test makes itself
        "test_overload_flight",
        "test_rejoin_flight",
        "test_sim_shards",
        "test_sitl_actuator_stream",
        "test_sitl_agent_gone",
        "test_sitl_cli",
        "test_sitl_crash",
        "test_sitl_lockstep",
        "test_sitl_map",
        "test_sitl_mavproxy",
        "test_sitl_offboard",
        "test_sitl_overload",
        "test_sitl_robustness",
        "test_sitl_signing",
        "test_sitl_telemetry",
        "test_swarm_secrets",
    }
)
#: test modules that fly on the default ports, as a newcomer types the commands
DEFAULT_PORT_MODULES = frozenset(
    {
        "test_ardupilot_dialect_flight",
        "test_ardupilot_sitl",  # real ArduCopter SITL on the default ports (skipped without it)
        "test_drill_flight",
        "test_drills_run",
        "test_late_takeoff",
        "test_operator_flight",
        "test_operator_session",
        "test_ports",
        "test_scenario_faults",
    }
)
#: test modules that share a session fixture: on one worker, so that its flight runs once
_SHARED_GROUPS = {
    "test_demo_paper": "paper flights",  # demo_run, simulated_paper_report
    "test_lockstep_repeats": "paper flights",  # demo_run
    "test_simulate_paper": "paper flights",  # simulated_paper_report
    "test_multihost": "paper flights",  # simulated_paper_report
}


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line(
        "markers",
        "lockstep: flies on the lockstep clock only, its verdict the same however loaded the "
        "machine is: in a realtime module, it runs in make test's parallel part",
    )
    config.addinivalue_line(
        "markers",
        "no_ports: takes no port (swarm simulate, one process): in a default-port module, it "
        "runs in its module's xdist group, not in the one chain of default-port flights",
    )


@pytest.hookimpl(wrapper=True)  # before -m selects and xdist reads the groups
def pytest_collection_modifyitems(
    config: pytest.Config, items: list[pytest.Item]
) -> Iterator[None]:
    """Mark the realtime modules' tests, and the default-port modules' tests on the realtime
    clock, ``serial``; on xdist workers, group the tests by module (a module's fixtures fly
    once), the modules that share a session fixture together, and every default-port module in
    one group (one flight on the default ports at a time)."""
    worker = hasattr(config, "workerinput")
    for item in items:
        module = item.module.__name__.rsplit(".", 1)[-1] if item.module is not None else ""
        default_ports = module in DEFAULT_PORT_MODULES and not item.get_closest_marker("no_ports")
        lockstep = _on_the_clock(item, "lockstep") or item.get_closest_marker("lockstep")
        if (module in REALTIME_MODULES and not lockstep) or (
            default_ports and _on_the_clock(item, "realtime")
        ):
            item.add_marker(pytest.mark.serial)
        if worker:
            group = DEFAULT_PORTS_GROUP if default_ports else _SHARED_GROUPS.get(module, module)
            item.add_marker(pytest.mark.xdist_group(group))
    yield


#: the xdist group of every test on the default ports
DEFAULT_PORTS_GROUP = "default ports"


def _on_the_clock(item: pytest.Item, clock: str) -> bool:
    """Whether ``item`` is a case of a ``clock`` parametrisation on ``clock``."""
    callspec = getattr(item, "callspec", None)
    return callspec is not None and callspec.params.get("clock") == clock


# -- the suite's times ------------------------------------------------------------------------
#: Where ``make test`` leaves each part's wall time and slowest tests (README: "The two
#: commands"); one file per part, rewritten by each run of it.
TIMES_DIR = Path(__file__).parents[1] / "test-times"


def pytest_terminal_summary(terminalreporter: Any, exitstatus: int, config: pytest.Config) -> None:
    """The part's wall time and its 15 slowest test phases, in test-times/PART.txt (the part is
    named by ``-m``: "serial" or "not serial"; a run without ``-m`` writes nothing)."""
    if hasattr(config, "workerinput"):
        return
    part = {"serial": "serial", "not serial": "parallel"}.get(config.getoption("markexpr") or "")
    if part is None:
        return
    reports = [
        r
        # "": the passing setup and teardown phases (a module's flight is often its fixture's)
        for kind in ("passed", "failed", "error", "skipped", "")
        for r in terminalreporter.stats.get(kind, [])
        if hasattr(r, "duration") and getattr(r, "when", None) in ("setup", "call", "teardown")
    ]
    slowest = sorted(reports, key=lambda r: r.duration, reverse=True)[:15]
    wall = time.monotonic() - _session_start[0]
    counts = {k: len(terminalreporter.stats.get(k, [])) for k in ("passed", "failed", "skipped")}
    lines = [
        f"make test, {part} part: {wall:.0f} s wall, exit status {int(exitstatus)}, "
        f"{counts['passed']} passed, {counts['failed']} failed, {counts['skipped']} skipped",
        f"at {time.strftime('%Y-%m-%d %H:%M:%S')}; load average "
        + " ".join(f"{x:.2f}" for x in os.getloadavg()),
        "slowest 15:",
        *(f"  {r.duration:7.2f} s  {r.when:<8} {r.nodeid}" for r in slowest),
    ]
    TIMES_DIR.mkdir(exist_ok=True)
    (TIMES_DIR / f"{part}.txt").write_text("\n".join(lines) + "\n")
