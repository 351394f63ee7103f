"""``swarm up`` for :meth:`gcs.api.Swarm.start`: the same command (its supervisor, children and
report) run as a child process on ports of its own, meeting at a Zenoh session of this process.

Ports: the vehicles and the ground station's telemetry on a block of free UDP ports, Zenoh on a
free TCP port, so that any number of swarms (and a ``swarm up`` on the default ports) run side by
side. The run ends as ``swarm up``'s does on Ctrl-C: :func:`stop` sends SIGINT (an operator
session lands first, then the report is written), a second SIGINT if it takes too long.
"""

from __future__ import annotations

import contextlib
import json
import signal
import socket
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from gcs.api.errors import StartError, UsageError

#: The run file ``swarm up`` writes once its children started (gcs.station.drills.RUN_FILE).
RUN_FILE = "run.json"
#: Where ``swarm up``'s own output goes, in the report's logs folder.
UP_LOG = "up.log"


@dataclass
class Launched:
    """A ``swarm up`` child process: its process, log, report folder and size."""

    proc: subprocess.Popen[bytes]
    log: Path
    report_dir: Path
    n_drones: int

    def last_line(self) -> str:
        """The last line ``swarm up`` wrote ("" before its first)."""
        try:
            text = self.log.read_text(errors="replace")
        except OSError:
            return ""
        lines = [ln.strip() for ln in text.replace("\r", "\n").splitlines() if ln.strip()]
        return lines[-1] if lines else ""

    def end_reason(self) -> str:
        """Why the run ended, as ``swarm up`` said it (its ``swarm up: REASON`` line)."""
        try:
            text = self.log.read_text(errors="replace")
        except OSError:
            return ""
        said = [ln for ln in text.splitlines() if ln.startswith("swarm up: ")]
        return said[-1].removeprefix("swarm up: ") if said else self.last_line()


def free_udp_block(n: int, host: str = "127.0.0.1", attempts: int = 50) -> int:
    """First of ``n`` consecutive UDP ports of ``host`` that are all free right now."""
    for _ in range(attempts):
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.bind((host, 0))
            base = int(s.getsockname()[1])
        if base + n > 65000:
            continue
        socks: list[socket.socket] = []
        try:
            for port in range(base, base + n):
                s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
                socks.append(s)
                s.bind((host, port))
            return base
        except OSError:
            continue
        finally:
            for s in socks:
                s.close()
    raise StartError(f"no block of {n} free UDP ports on {host}")


def n_drones_of(scenario: Path) -> int:
    """The number of drones of a scenario file; UsageError with the file's problem."""
    from protocols.scenario.scenario_file import load_scenario
    from protocols.scenario.schema import ScenarioError

    try:
        return load_scenario(scenario).n_drones
    except (ScenarioError, OSError) as exc:
        raise UsageError(str(exc)) from None


def up_words(
    scenario: str | Path | None,
    drones: int | None,
    clock: str,
    **flags: object,
) -> tuple[list[str], int]:
    """The words of ``swarm up`` that say what to fly (a scenario file, or ``--drones N`` with
    a session's ``seed``, ``layout``, ``spacing_m``, ``range_m``), plus ``duration_s`` and
    ``agents_per_process``, and the number of drones. UsageError, naming the argument as the API
    and the flag do, for what ``swarm up`` would refuse."""
    if (scenario is None) == (drones is None):
        raise UsageError("give a scenario file or drones=N (an operator session), not both")
    if clock not in ("lockstep", "realtime"):
        raise UsageError(f"clock (--clock) must be lockstep or realtime, got {clock!r}")
    given = {k: v for k, v in flags.items() if v is not None}
    session = [k for k in ("seed", "layout", "spacing_m", "range_m") if k in given]
    if scenario is not None:
        if session:
            raise UsageError(f"{session[0]} goes with drones=N; a scenario file has its own")
        path = Path(scenario)
        what, n = [str(path.resolve())], n_drones_of(path)
    else:
        if isinstance(drones, bool) or not isinstance(drones, int):
            raise UsageError(f"drones (--drones) must be a number of drones, got {drones!r}")
        if "duration_s" in given:
            raise UsageError("duration_s (--duration-s): an operator session has no fixed duration")
        what, n = ["--drones", str(drones)], drones
    for key, value in given.items():
        what += [f"--{key.replace('_', '-')}", str(value)]
    return what, n


def launch(
    what: list[str], n: int, report_dir: Path, endpoint: str, swarm_id: str, clock: str
) -> Launched:
    """Start ``swarm up WHAT`` (a scenario file, or ``--drones N`` and a session's flags) with
    its report in ``report_dir``, on free ports, its Zenoh meeting at ``endpoint``."""
    logs = report_dir / "logs"
    try:
        logs.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UsageError(f"cannot write the report folder {report_dir}: {exc.strerror}") from None
    with contextlib.suppress(FileNotFoundError):
        (logs / RUN_FILE).unlink()
    base = free_udp_block(n + 1)  # the vehicles, then the ground station's telemetry
    argv = [
        sys.executable, "-m", "gcs.cli", "up", *what, "--report", str(report_dir),
        "--clock", clock, "--base-port", str(base), "--gcs-port", str(base + n),
        "--swarm-id", swarm_id, "--zenoh-connect", endpoint,
    ]  # fmt: skip
    log = logs / UP_LOG
    with log.open("wb") as out:
        proc = subprocess.Popen(argv, stdout=out, stderr=subprocess.STDOUT)
    return Launched(proc, log, report_dir, n)


def wait_started(run: Launched, timeout_s: float) -> dict[str, object]:
    """Wait until ``swarm up`` has started its children (its run file); StartError with its
    last line if it ends or does not get there within ``timeout_s`` (wall s)."""
    run_file = run.report_dir / "logs" / RUN_FILE
    deadline = time.monotonic() + timeout_s
    while not run_file.exists():
        if run.proc.poll() is not None:
            raise StartError(f"swarm up ended: {run.last_line() or 'no output'} (log: {run.log})")
        if time.monotonic() > deadline:
            raise StartError(f"swarm up did not start within {timeout_s:g} s (log: {run.log})")
        time.sleep(0.1)
    about: dict[str, object] = json.loads(run_file.read_text())
    return about


def stop(run: Launched, land_timeout_s: float, stop_timeout_s: float = 60.0) -> int:
    """End the run as a Ctrl-C to ``swarm up`` does: SIGINT, then a second SIGINT (stop at once)
    after ``land_timeout_s``, SIGKILL after another ``stop_timeout_s``; the exit code."""
    proc = run.proc
    for sig, wait_s in ((signal.SIGINT, land_timeout_s), (signal.SIGINT, stop_timeout_s)):
        if proc.poll() is not None:
            break
        proc.send_signal(sig)
        with contextlib.suppress(subprocess.TimeoutExpired):
            proc.wait(wait_s)
    if proc.poll() is None:
        proc.kill()
        proc.wait(10)
    return int(proc.returncode)
