"""``swarm view``: a running swarm, live in Rerun, by following its report folder.

The ground station writes ``flight.tlog`` (every vehicle's telemetry and every agent's status, as
it receives them), ``events.jsonl`` and ``trajectory.json`` (the plan in force, rewritten at each
new plan) into its report folder while it flies. The live view tails those files: it needs no
Zenoh session, no port of the swarm's, and works the same for ``swarm up``, a ground station
started by hand, or a flight on another machine whose report folder is shared. It lags the swarm
by at most its poll period (default 0.5 s). Each poll reads the bytes added to the tlog since the
last one (:class:`gcs.report.tlog.TlogReader`), rebuilds the scene (:mod:`gcs.view.scene`)
and sends the samples and events not sent yet (:mod:`gcs.view.rerun_log`), so the live view shows
what the recording
``flight.rrd`` of the same flight will.

The commanded formation comes from the report's ``trajectory.json`` once the ground station has
written it during this view, before that from ``--scenario`` (its plan), else from an older
``trajectory.json``.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Any

import numpy as np
import rerun as rr

from gcs.report.events import read_events
from gcs.report.flight_record import FlightRecord
from gcs.report.log_record import build_record
from gcs.report.tlog import TlogReader
from gcs.view.rerun_log import log_scene, log_setup, trail_stride
from gcs.view.scene import (
    EVENTS,
    TLOG,
    TRAJECTORY,
    LinkLog,
    Scene,
    read_plan,
    scene_from_record,
    tlog_rate_hz,
)
from protocols.model.frames import FloatArray
from protocols.model.trajectory import DescriptorTrajectory


@dataclass
class LiveView:
    """Follows ``report_dir`` into ``rec``; ``plan`` is the plan to show until the ground station
    writes one; ``n_drones`` (default: the largest system id heard)."""

    report_dir: Path
    rec: rr.RecordingStream
    plan: DescriptorTrajectory | None = None
    n_drones: int | None = None

    def __post_init__(self) -> None:
        self._reader = TlogReader()
        self._offset = 0
        self._sent_t_s = -np.inf
        self._sent_events = 0
        self._setup_done = False
        self._started = time.time()
        if self.plan is None:
            self.plan = _try_plan(self.report_dir / TRAJECTORY)

    def poll(self) -> int:
        """Read what was added since the last poll and send it; the samples sent."""
        tlog = self.report_dir / TLOG
        if not tlog.exists():
            return 0
        if tlog.stat().st_size < self._offset:  # a new run truncated the log: start over
            self.__post_init__()
        with tlog.open("rb") as f:
            f.seek(self._offset)
            self._offset += self._reader.feed(f.read())
        self._refresh_plan()
        track = self._reader.track()
        n = self.n_drones or max(track.vehicles, default=0)
        rate = tlog_rate_hz(track)
        if self.plan is None or rate is None or n < 1:
            return 0
        events_path = self.report_dir / EVENTS
        record = build_record(tlog, events_path, self.plan, n, rate, np.inf, None, track)
        if record is None:
            return 0
        events = read_events(events_path) if events_path.exists() else []
        # only the samples not sent yet and the trail before them are worked out again
        offset = _window_start(record.t_s, self._sent_t_s)
        scene = scene_from_record(_tail(record, offset), events, LinkLog.from_track(track, n))
        if not self._setup_done:
            log_setup(self.rec, scene.n_drones)
            self._setup_done = True
        # the last sample may still change (a vehicle's message of that tick not read yet)
        ready = scene.t_s < scene.t_s[-1] - 1e-9
        start = int(np.searchsorted(scene.t_s, self._sent_t_s + 1e-6))
        stop = int(ready.sum())
        if stop <= start and len(scene.events) <= self._sent_events:
            return 0
        sent = max(0, stop - start)
        log_scene(self.rec, _head(scene, stop), start, self._sent_events)
        if stop > start:
            self._sent_t_s = float(scene.t_s[stop - 1])
        self._sent_events = len(scene.events)
        return sent

    def _refresh_plan(self) -> None:
        path = self.report_dir / TRAJECTORY
        if path.exists() and path.stat().st_mtime >= self._started:
            plan = _try_plan(path)
            if plan is not None:
                self.plan = plan

    def run(self, stop: Callable[[], bool], poll_s: float = 0.5) -> None:
        """Poll every ``poll_s`` s until ``stop()``."""
        while not stop():
            self.poll()
            time.sleep(poll_s)


def _window_start(t_s: FloatArray, sent_t_s: float) -> int:
    """The first sample the scene needs: the trail's history before the first sample not sent
    yet, starting on a trail row (as in the whole flight's recording, so the two agree)."""
    first_new = int(np.searchsorted(t_s, sent_t_s + 1e-6))
    stride, length = trail_stride(t_s)
    lo = max(0, first_new - stride * length)
    return lo - lo % stride


def _tail(record: FlightRecord, lo: int) -> FlightRecord:
    """``record`` from sample ``lo`` on."""
    if lo == 0:
        return record
    t = record.t_s.shape[0]
    cut: dict[str, Any] = {}
    for f in fields(record):
        value = getattr(record, f.name)
        if isinstance(value, np.ndarray) and value.ndim and value.shape[0] == t:
            cut[f.name] = value[lo:]
    return replace(record, **cut)


def _try_plan(path: Path) -> DescriptorTrajectory | None:
    """The plan in ``path``, None if absent or being written (half a file)."""
    try:
        return read_plan(path)
    except (ValueError, KeyError, OSError):
        return None


def _head(scene: Scene, stop: int) -> Scene:
    """``scene`` cut to its first ``stop`` samples (events and links, by time, kept)."""
    cut = {
        f.name: getattr(scene, f.name)[:stop]
        for f in fields(scene)
        if f.name not in ("events", "links")
    }
    return replace(scene, **cut)
