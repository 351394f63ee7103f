"""``swarm view`` (a running swarm, live) and ``swarm replay`` (a report's flight.rrd) in Rerun.

Both serve Rerun's web viewer on this machine and print its URL (``--native`` opens the native
viewer instead, where a display exists), on the swarm layout of :mod:`gcs.view.layout`
(``--layout auto``: Rerun's automatic one). Rerun is optional (``pip install 'quadswarm[view]'``):
without it both commands say how to install it and exit with code 2; this module imports it only
when a command runs, so ``swarm --help`` and everything else work without it.

``swarm view REPORT_DIR`` follows the report folder a ground station is writing (its flight.tlog,
events.jsonl and trajectory.json: :mod:`gcs.view.live`), so it attaches to any running swarm whose
folder it can read, needs no Zenoh session and cannot disturb the flight.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, TextIO

from gcs.view.recording import RRD, RerunMissing, require_rerun, write_recording

if TYPE_CHECKING:
    import rerun as rr

Stop = Callable[[], bool]

DEFAULT_WEB_PORT = 9090
DEFAULT_GRPC_PORT = 9876
VIEW_COMMANDS = ("view", "replay")
#: ``--layout`` choices (gcs.view.layout.LAYOUTS, without importing Rerun).
LAYOUTS = ("swarm", "auto")


class ViewError(Exception):
    """A user mistake or a missing viewer: one line."""


def add_parsers(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add ``view`` and ``replay``."""
    view = sub.add_parser(
        "view",
        help="watch a running swarm live in Rerun (3-D view, events, descriptors)",
        description=(
            "Follow the report folder of a running ground station (flight.tlog, events.jsonl, "
            "trajectory.json) and show the swarm live in Rerun: drones coloured by mode with "
            "trails, the commanded and the true formation ellipsoids, the agents' centre "
            "estimates, events, and each descriptor against its command. Serves the web viewer "
            "locally and prints its URL. Needs the optional extra: pip install 'quadswarm[view]'."
        ),
    )
    view.add_argument(
        "report", type=Path, nargs="?", default=Path("report"),
        help="the ground station's report folder (default ./report)",
    )  # fmt: skip
    view.add_argument(
        "--scenario", type=Path, metavar="FILE",
        help="show this scenario's plan until the ground station writes its own",
    )  # fmt: skip
    view.add_argument("--poll-s", type=float, default=0.5, help="how often to read (default 0.5)")
    view.add_argument(
        "--duration-s", type=float, metavar="S", help="stop after S wall seconds (default: Ctrl-C)"
    )
    _serving(view)
    replay = sub.add_parser(
        "replay",
        help="open a report's flight recording (flight.rrd) in Rerun",
        description=(
            "Open REPORT_DIR/flight.rrd (written by swarm simulate and by the ground station's "
            "report; made here from flight.tlog and events.jsonl if missing) in Rerun's web "
            "viewer, served locally until Ctrl-C. Needs: pip install 'quadswarm[view]'."
        ),
    )
    replay.add_argument("report", type=Path, help="report folder holding flight.rrd")
    replay.add_argument(
        "--duration-s", type=float, metavar="S", help="serve for S seconds (default: Ctrl-C)"
    )
    _serving(replay)


def _serving(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--web-port", type=int, default=DEFAULT_WEB_PORT,
        help=f"port of the web viewer (default {DEFAULT_WEB_PORT})",
    )  # fmt: skip
    p.add_argument(
        "--grpc-port", type=int, default=DEFAULT_GRPC_PORT,
        help=f"port the viewer reads the data from (default {DEFAULT_GRPC_PORT})",
    )  # fmt: skip
    p.add_argument(
        "--native", action="store_true", help="open Rerun's native viewer (needs a display)"
    )
    p.add_argument(
        "--layout", choices=LAYOUTS, default=LAYOUTS[0],
        help="swarm (default): the 3-D swarm large, one plot per descriptor with its command, "
        "true value and the agents' estimates, the events log across the bottom; auto: Rerun's "
        "automatic layout",
    )  # fmt: skip


def run(args: argparse.Namespace, out: TextIO = sys.stdout) -> int:
    """Run ``swarm view`` or ``swarm replay``; ViewError on a mistake or a missing Rerun."""
    try:
        require_rerun()
    except RerunMissing as exc:
        raise ViewError(f"swarm {args.command}: {exc}") from None
    from gcs.cli.supervisor import interrupt_flag

    with interrupt_flag() as interrupted:
        deadline = None if args.duration_s is None else time.monotonic() + args.duration_s

        def stop() -> bool:
            return bool(interrupted()) or (deadline is not None and time.monotonic() >= deadline)

        if args.command == "replay":
            return _replay(args, stop, out)
        return _view(args, stop, out)


def _open(args: argparse.Namespace, recording_id: str, out: TextIO) -> rr.RecordingStream:
    """A recording sent to a viewer (web, served here; or native); prints where to look."""
    from gcs.view.layout import layout_blueprint
    from gcs.view.rerun_log import recording, serve

    rec = recording(recording_id)
    if args.native:
        rec.spawn(default_blueprint=layout_blueprint(args.layout))
        print(f"swarm {args.command}: opened Rerun's native viewer", file=out, flush=True)
    else:
        try:
            url = serve(rec, args.web_port, args.grpc_port, args.layout)
        except Exception as exc:  # Rerun raises its own errors for a taken port
            raise ViewError(f"swarm {args.command}: cannot serve the viewer: {exc}") from None
        print(f"swarm {args.command}: Rerun web viewer at {url}", file=out, flush=True)
    return rec


def _replay(args: argparse.Namespace, stop: Stop, out: TextIO) -> int:
    from rerun.chunk import RrdReader

    report: Path = args.report
    rrd = report / RRD
    if not rrd.exists():
        if not (report / "flight.tlog").exists():
            raise ViewError(f"swarm replay: no {rrd} and no flight.tlog to make it from")
        if write_recording(report) is None:
            raise ViewError(f"swarm replay: {report / 'flight.tlog'} holds no flight")
        print(f"swarm replay: wrote {rrd}", file=out)
    rec = _open(args, f"replay-{report.resolve().name}", out)
    rec.send_chunks(RrdReader(rrd).stream())
    rec.flush()
    _wait(stop)
    return 0


def _view(args: argparse.Namespace, stop: Stop, out: TextIO) -> int:
    from gcs.view.live import LiveView

    plan = None
    if args.scenario is not None:
        from protocols.scenario.scenario_file import ScenarioError, load_scenario

        try:
            plan = load_scenario(args.scenario).trajectory()
        except ScenarioError as exc:
            raise ViewError(str(exc)) from None
    if not args.poll_s > 0:
        raise ViewError("--poll-s must be > 0")
    rec = _open(args, f"live-{args.report.resolve().name}", out)
    waiting = "" if (args.report / "flight.tlog").exists() else ", waiting for it to appear"
    print(
        f"swarm view: following {args.report}/flight.tlog{waiting} (Ctrl-C ends)",
        file=out,
        flush=True,
    )
    LiveView(args.report, rec, plan).run(stop, args.poll_s)
    return 0


def _wait(stop: Stop) -> None:
    while not stop():
        time.sleep(0.2)
