"""``swarm up --drones N``: an operator session, without a scenario file.

The scenario of a session is made by the scenario generator (:mod:`protocols.scenario.generator`,
the one implementation of layouts, radio graphs and consensus settings behind ``swarm scenario
new``) with its ``ground`` plan: N drones in a layout on the ground, resting there. ``swarm up``
writes it into the report's ``logs/session.toml`` (the simulator, the agents and the ground
station read it from there; ``swarm scenario check`` sums it up) and starts the ground station in
session mode: its first plan says GROUND, so the vehicles power up and wait, disarmed, until the
operator's ``swarm takeoff``; the run has no end time and ends with ``swarm shutdown`` or Ctrl-C,
which land the swarm first.

:func:`session_request` checks the flags of ``swarm up`` (a scenario file or ``--drones``, never
both) and raises :class:`~gcs.cli.supervisor.SupervisorError` with one line naming the flag.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from gcs.cli.supervisor import SupervisorError
from protocols.scenario.generator import (
    MAX_DRONES,
    MIN_DRONES,
    Generated,
    GeneratorError,
    GeneratorOptions,
)
from protocols.scenario.generator import generate as generate_scenario
from protocols.scenario.templates import SESSION_TEMPLATE

#: The session's scenario, in the report's logs folder.
SESSION_FILE = "session.toml"
#: Flags that shape a session's swarm (only with ``--drones``) and their defaults.
SESSION_DEFAULTS: dict[str, Any] = {"layout": "grid", "spacing_m": 2.5, "range_m": 6.0, "seed": 0}
#: How long (wall s) the ground station waits for a landing at shutdown before it stops anyway.
DEFAULT_SHUTDOWN_TIMEOUT_S = 120.0


@dataclass(frozen=True)
class SessionRequest:
    """The swarm of a session: N drones in ``layout``, ``spacing_m`` apart, radio ``range_m``;
    ``seed``: the random layout's and the run's draws; ``shutdown_timeout_s``: how long (wall s)
    a shutdown waits for the swarm to land."""

    drones: int
    layout: str = "grid"
    spacing_m: float = 2.5
    range_m: float = 6.0
    seed: int = 0
    shutdown_timeout_s: float = DEFAULT_SHUTDOWN_TIMEOUT_S

    def command_line(self) -> str:
        """The ``swarm up`` command of this session (recorded in its scenario file)."""
        return (
            f"swarm up --drones {self.drones} --layout {self.layout} "
            f"--spacing-m {self.spacing_m:g} --range-m {self.range_m:g} --seed {self.seed}"
        )

    def options(self) -> GeneratorOptions:
        """The generator's options for this session's scenario."""
        return GeneratorOptions(
            drones=self.drones,
            layout=self.layout,
            spacing_m=self.spacing_m,
            range_m=self.range_m,
            template=SESSION_TEMPLATE,
            seed=self.seed,
            name=f"session-{self.layout}{self.drones}",
        )


#: ``swarm up`` flags of a swarm spread over hosts (gcs/cli/up_hosts.py): not for a session.
MULTIHOST_FLAGS = (
    "router", "only", "sim_drones", "start_at", "sim_host", "gcs_host", "shard_sync",
    "shard_peers", "secrets",
)  # fmt: skip


def session_request(args: argparse.Namespace) -> SessionRequest | None:
    """The session ``args`` ask for (``swarm up --drones N``, no scenario file), None for a
    scenario run; SupervisorError with one line for a bad combination or value. With a scenario
    file, ``--drones LO-HI`` is the multi-host range of this host's agents (gcs/cli/up_hosts.py)."""
    if getattr(args, "command", "up") != "up":
        return None  # swarm demo flies the paper's scenario
    drones_text: str | None = getattr(args, "drones", None)
    scenario = getattr(args, "scenario", None)
    given = [k for k in SESSION_DEFAULTS if getattr(args, k, None) is not None]
    timeout = getattr(args, "shutdown_timeout_s", None)
    if scenario is not None or drones_text is None:
        if given or timeout is not None:
            flag = _flag(given[0] if given else "shutdown_timeout_s")
            raise SupervisorError(
                f"{flag} goes with --drones N (an operator session); a scenario file has its own"
            )
        if scenario is None:
            raise SupervisorError(
                "give a scenario file (swarm up SCENARIO) or --drones N for an operator session"
            )
        spread = any(getattr(args, k, None) for k in MULTIHOST_FLAGS)
        if drones_text is not None and not spread:
            raise SupervisorError(
                "--drones is for a swarm spread over hosts: give --router ENDPOINT (with a "
                f"scenario file, here {scenario}, --drones LO-HI picks this host's agents); for "
                "an operator session give --drones N without a scenario file"
            )
        return None
    multihost = [k for k in MULTIHOST_FLAGS if getattr(args, k, None)]
    if multihost:
        raise SupervisorError(
            f"{_flag(multihost[0])}: an operator session (--drones N) runs on this machine; "
            "a swarm spread over hosts flies a scenario file"
        )
    if not drones_text.strip().isdigit():
        raise SupervisorError(
            f"--drones: an operator session needs a number of drones, {MIN_DRONES}..{MAX_DRONES}, "
            f"got {drones_text!r} (a range LO-HI goes with a scenario file and --router)"
        )
    drones = int(drones_text)
    if not MIN_DRONES <= drones <= MAX_DRONES:
        raise SupervisorError(f"--drones: need {MIN_DRONES}..{MAX_DRONES}, got {drones}")
    if getattr(args, "duration_s", None) is not None:
        raise SupervisorError(
            "--duration-s: an operator session has no fixed duration; "
            "it ends with swarm shutdown or Ctrl-C"
        )
    if timeout is not None and not timeout > 0:
        raise SupervisorError(f"--shutdown-timeout-s: must be positive, got {timeout:g}")
    values = {k: getattr(args, k) if k in given else v for k, v in SESSION_DEFAULTS.items()}
    return SessionRequest(
        drones,
        str(values["layout"]),
        float(values["spacing_m"]),
        float(values["range_m"]),
        int(values["seed"]),
        DEFAULT_SHUTDOWN_TIMEOUT_S if timeout is None else float(timeout),
    )


def session_scenario(request: SessionRequest, path: Path) -> Generated:
    """The session's scenario, to be written to ``path`` (its header names the ``swarm up``
    command); SupervisorError naming the flag if the generator cannot meet it, e.g. a radio range
    too short for the layout."""
    try:
        return generate_scenario(request.options(), str(path), request.command_line())
    except GeneratorError as exc:
        name, sep, rest = str(exc).partition(": ")
        raise SupervisorError(f"{_flag(name)}: {rest}" if sep else str(exc)) from None


def write_text(path: Path, text: str) -> None:
    """Write ``text`` to ``path``; SupervisorError if it cannot be written."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text, encoding="utf-8")
    except OSError as exc:
        raise SupervisorError(f"cannot write {path}: {exc.strerror or exc}") from None


def _flag(name: str) -> str:
    return f"--{name.replace('_', '-')}" if name.isidentifier() else name
