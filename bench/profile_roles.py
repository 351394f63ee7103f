"""Where the CPU of a whole ``swarm up --clock lockstep`` goes: every process sampled at once.

``python -m bench.profile_roles [--drones 100] [--agents-per-process 50] [--warmup-s 25]
[--seconds 20] [--out DIR]``: flies the 100-drone hover grid (bench/end_to_end.py's scenario) on
free ports, waits ``--warmup-s`` wall seconds (take-off done), then records every process of the
flight (simulator, ground station, each agent process) with py-spy for ``--seconds``, and prints
and writes (DIR/summary.txt) each process's top functions: inclusive and self share of its
samples. The raw py-spy files are kept in DIR. Not in ``make bench``: a profiling aid; needs
py-spy (``.venv/bin/pip install py-spy``) and the right to attach to processes (root, or
ptrace_scope 0). py-spy itself takes CPU: the flight runs slower while recorded (the shares are
what to read, not the speed).
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

from bench.end_to_end import scenario_text
from bench.sitl import _free_block
from bench.up_lockstep import _role

ROOT = Path(__file__).resolve().parents[1]
_FRAME = re.compile(r"(.*) \((.*):\d+\)")


def summarise(raw: Path, top: int = 25) -> str:
    """The top ``top`` functions of a py-spy raw file, inclusive and self, as % of its samples."""
    incl: Counter[str] = Counter()
    own: Counter[str] = Counter()
    total = 0
    for line in raw.read_text(errors="replace").splitlines():
        stack, _, count = line.rpartition(" ")
        if not stack or not count.isdigit():
            continue
        n = int(count)
        total += n
        names = []
        for frame in stack.split(";"):
            m = _FRAME.match(frame)
            names.append(f"{m.group(1)} ({Path(m.group(2)).name})" if m else frame)
        for name in set(names):
            incl[name] += n
        own[names[-1]] += n
    if not total:
        return "  (no samples)\n"
    rows = [f"  {total} samples", "  inclusive:"]
    rows += [f"    {100 * v / total:5.1f} %  {k}" for k, v in incl.most_common(top)]
    rows += ["  self:"]
    rows += [f"    {100 * v / total:5.1f} %  {k}" for k, v in own.most_common(top)]
    return "\n".join(rows) + "\n"


def _roles(pid: int) -> list[tuple[str, int]]:
    """The flight's processes under ``pid``: (role, pid), an agent process named by its drones."""
    import psutil

    out = []
    for child in psutil.Process(pid).children(recursive=True):
        try:
            words = child.cmdline()
        except psutil.Error:
            continue
        role = _role(words)  # bench/up_lockstep.py's reading of a command line
        if role is None:
            continue
        if role == "agent" and "--drone-id" in words:
            role = f"agent{words[words.index('--drone-id') + 1]}"
        out.append((role, child.pid))
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--drones", type=int, default=100, help="drones on the hover grid")
    ap.add_argument("--agents-per-process", type=int, default=50, help="swarm up's hosting")
    ap.add_argument("--warmup-s", type=float, default=25.0, help="wall s before recording")
    ap.add_argument("--seconds", type=int, default=20, help="wall s recorded")
    ap.add_argument("--rate", type=int, default=100, help="py-spy samples per second")
    ap.add_argument("--out", type=Path, default=Path("profile_roles"), help="raw files and summary")
    args = ap.parse_args(argv)
    if min(args.drones, args.agents_per_process, args.seconds, args.rate) < 1 or args.warmup_s < 0:
        ap.error("--drones, --agents-per-process, --seconds and --rate must be >= 1")
    spy = shutil.which("py-spy") or str(Path(sys.executable).with_name("py-spy"))
    if not Path(spy).exists():
        print("py-spy is not installed: .venv/bin/pip install py-spy", file=sys.stderr)
        return 2
    args.out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        scenario = Path(tmp) / "hover.toml"
        flight_s = 3 * (args.warmup_s + args.seconds)  # outlasts the recording even at 0.3x
        scenario.write_text(scenario_text(args.drones, flight_s), encoding="utf-8")
        cmd = [sys.executable, "-m", "gcs.cli", "up", str(scenario), "--report",
               str(Path(tmp) / "report"), "--clock", "lockstep", "--agents-per-process",
               str(args.agents_per_process), "--duration-s", str(flight_s), "--base-port",
               str(_free_block(args.drones)), "--gcs-port", str(_free_block(1)),
               "--swarm-id", f"profile{os.getpid()}"]  # fmt: skip
        env = {**os.environ, "MAVLINK20": "1", "PYTHONPATH": str(ROOT)}
        flight = subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=subprocess.DEVNULL,
                                  stderr=subprocess.DEVNULL, start_new_session=True)  # fmt: skip
        try:
            time.sleep(args.warmup_s)
            roles = _roles(flight.pid) if flight.poll() is None else []
            if not roles:
                code = flight.poll()
                why = (
                    f"swarm up exited with {code}"
                    if code is not None
                    else f"no process of the flight yet after {args.warmup_s:g} s"
                )
                print(f"nothing to record: {why} (a longer --warmup-s?)",
                      file=sys.stderr)  # fmt: skip
                return 1
            print(f"recording {', '.join(r for r, _ in roles)} for {args.seconds} s", flush=True)
            spies = []
            for role, pid in roles:
                record = [spy, "record", "--pid", str(pid), "--duration", str(args.seconds),
                          "--rate", str(args.rate), "--format", "raw", "--nonblocking",
                          "-o", str(args.out / f"{role}.txt")]  # fmt: skip
                quiet = subprocess.DEVNULL
                spies.append(subprocess.Popen(record, stdout=quiet, stderr=quiet))
            for s in spies:
                s.wait()
        finally:
            flight.terminate()
            try:
                flight.wait(60)
            except subprocess.TimeoutExpired:  # a large, slow swarm still writing its report
                os.killpg(flight.pid, signal.SIGKILL)
                flight.wait(10)
    text = "".join(
        f"{role}:\n{summarise(args.out / f'{role}.txt')}"
        for role, _ in roles
        if (args.out / f"{role}.txt").exists()
    )
    (args.out / "summary.txt").write_text(text, encoding="utf-8")
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
