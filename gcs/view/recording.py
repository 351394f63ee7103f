"""``flight.rrd``: a report's Rerun recording, written next to the files it is made from.

Rerun is an optional extra (``pip install 'quadswarm[view]'``). This module never imports it at
load time: :func:`rerun_available` asks whether it is installed, :func:`require_rerun` says how to
install it, and :func:`write_recording` writes nothing (returns None) without it, so the rest of
the tool runs the same with or without the viewer.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from gcs.report.tlog import TlogTrack

RRD = "flight.rrd"
INSTALL_HINT = (
    "the Rerun viewer is not installed: pip install 'quadswarm[view]' "
    "(or: pip install 'rerun-sdk>=0.41,<0.42'); `make venv` installs it"
)


class RerunMissing(RuntimeError):
    """Rerun is not installed; the message says how to install it."""


def rerun_available() -> bool:
    """Whether ``rerun`` (rerun-sdk) can be imported."""
    return importlib.util.find_spec("rerun") is not None


def require_rerun() -> None:
    """Raise :class:`RerunMissing` unless ``rerun`` can be imported."""
    if not rerun_available():
        raise RerunMissing(INSTALL_HINT)


def write_recording(
    report_dir: Path, n_drones: int | None = None, track: TlogTrack | None = None
) -> Path | None:
    """Write ``report_dir/flight.rrd`` from the report's flight.tlog (``track``: already read),
    events.jsonl and trajectory.json; None (nothing written) without Rerun or without a flight
    in the tlog."""
    if not rerun_available():
        return None
    from gcs.view.rerun_log import write_rrd
    from gcs.view.scene import scene_from_report

    scene = scene_from_report(report_dir, n_drones, track)
    if scene is None:
        return None
    return write_rrd(scene, report_dir / RRD, recording_id=f"quadswarm-{report_dir.resolve().name}")


def report_recording(
    report_dir: Path, n_drones: int | None, wanted: bool, track: TlogTrack | None = None
) -> Path | None:
    """A report's ``flight.rrd``: written when ``wanted`` (:func:`write_recording`), otherwise an
    earlier flight's removed, so that none lies under this one's name (swarm replay makes it
    when it opens the report). Its path, None when there is none."""
    if not wanted:
        (report_dir / RRD).unlink(missing_ok=True)
        return None
    return write_recording(report_dir, n_drones, track)
