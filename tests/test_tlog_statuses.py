"""The ground station logs a batch of agent statuses (gcs/report/tlog.py
``write_agent_statuses``) as the same tlog records, byte for byte, as one status at a time, and
reads them back."""

from __future__ import annotations

import random
from pathlib import Path

import numpy as np
import pytest

from gcs.report.tlog import TlogWriter, read_tlog
from gcs.station.telemetry import TelemetryReceiver
from protocols.wire.status import AgentMode, AgentStatus, Health, StatusCounters


def _statuses(seed: int, n: int) -> list[AgentStatus]:
    rng = random.Random(seed)
    out = []
    for k in range(n):
        estimate = np.array([rng.gauss(0.0, 30.0) for _ in range(9)])
        if rng.random() < 0.1:
            estimate[rng.randrange(9)] = rng.choice((np.nan, -np.nan, np.inf, -np.inf))
        if rng.random() < 0.05:
            estimate[rng.randrange(9)] = 1e-46  # below float32's smallest: rounds to 0
        neighbours = tuple(sorted(rng.sample(range(250), rng.choice((0, 3, 16, 60)))))
        out.append(AgentStatus(
            rng.randrange(250), k, rng.choice((0.0, 0.02 * k, 1e-7 * k, 123.456789)),
            rng.choice(list(AgentMode)), rng.random() < 0.5, Health.NONE, estimate, neighbours,
            StatusCounters(),
        ))  # fmt: skip
    return out


def _logged(path: Path, statuses: list[AgentStatus], together: bool, offset_s: float) -> bytes:
    with TlogWriter(path, epoch_offset_s=offset_s) as tlog:
        receiver = TelemetryReceiver.__new__(TelemetryReceiver)
        receiver._tlog = tlog
        for batch in (statuses[:1], statuses[1:40], statuses[40:]):
            if together:
                receiver.log_agent_statuses(batch)
            else:
                for status in batch:  # one at a time: its values as the station logs them
                    values = [*status.estimate, len(status.neighbours), int(status.mode),
                              int(status.armed)]  # fmt: skip
                    row = np.array(values, dtype=float)
                    tlog.write_agent_status(status.t_s, status.drone + 1, row, status.neighbours)
        assert tlog.n_records == len(statuses)
    return path.read_bytes()


@pytest.mark.parametrize("seed", range(4))
def test_a_batch_of_statuses_is_logged_as_one_status_at_a_time(seed: int, tmp_path: Path) -> None:
    statuses = _statuses(seed, 120)
    for offset_s in (0.0, 1.7e9):
        alone = _logged(tmp_path / "alone.tlog", statuses, False, offset_s)
        together = _logged(tmp_path / "together.tlog", statuses, True, offset_s)
        assert together == alone
    track = read_tlog(tmp_path / "together.tlog")
    assert track is not None


def test_a_value_beyond_float32_is_logged_as_infinite_not_refused(tmp_path: Path) -> None:
    """A diverged estimate (finite, beyond float32's range) is written as +-inf, one status at a
    time and in a batch alike (struct refused it: the ground station stopped logging)."""
    statuses = _statuses(9, 50)
    big = np.array(statuses[3].estimate)
    big[2], big[5] = 1e39, -1e300
    statuses[3] = AgentStatus(3, 1, 0.5, AgentMode.FLYING, True, Health.NONE, big, (),
                              StatusCounters())  # fmt: skip
    logs = [_logged(tmp_path / f"{t}.tlog", statuses, t, 0.0) for t in (False, True)]
    assert logs[0] == logs[1]
    with TlogWriter(tmp_path / "one.tlog") as tlog:
        tlog.write_agent_status(0.5, 4, big, ())
    data = (tmp_path / "one.tlog").read_bytes()
    values = np.frombuffer(data[8 + 10 + 20 :][: 4 * 12], dtype="<f4")
    assert values[2] == np.inf and values[5] == -np.inf
