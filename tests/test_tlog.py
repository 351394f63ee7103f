"""Run logs: the MAVLink telemetry log (gcs.report.tlog), read back by us and by pymavlink's
mavlogdump, and the JSON-lines events log (gcs.report.events)."""

from __future__ import annotations

import json
import math
import os
import shutil
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from gcs.report.events import EventLog, read_events
from gcs.report.metrics import tracking_from_positions
from gcs.report.tlog import TlogWriter, read_tlog

DT = 0.02
N_DRONES, N_SAMPLES = 3, 100
MAVLOGDUMP = Path(sys.executable).parent / "mavlogdump.py"
if not MAVLOGDUMP.exists():  # pymavlink's script beside another interpreter
    MAVLOGDUMP = Path(shutil.which("mavlogdump.py") or MAVLOGDUMP)


def truth(seed: int = 1) -> dict[str, np.ndarray]:
    """Known vehicle states (T, N, 3) with values that are not exact in float32."""
    rng = np.random.default_rng(seed)
    t = np.round(np.arange(N_SAMPLES) * DT, 9)
    shape = (N_SAMPLES, N_DRONES, 3)
    pos = np.cumsum(rng.normal(0.0, 0.1, shape), axis=0) + np.array([100.0 / 3.0, -7.1, -5.3])
    return {
        "t": t,
        "pos": pos,
        "vel": rng.normal(0.0, 1.0, shape),
        "euler": rng.uniform(-0.5, 0.5, shape),
        "rates": rng.normal(0.0, 0.3, shape),
    }


def write(path: Path, s: dict[str, np.ndarray], epoch_offset_s: float = 0.0) -> None:
    with TlogWriter(path, epoch_offset_s=epoch_offset_s) as w:
        for k, t in enumerate(s["t"]):
            for i in range(N_DRONES):
                w.write_vehicle_sample(
                    t, i + 1, s["pos"][k, i], s["vel"][k, i], s["euler"][k, i], s["rates"][k, i]
                )
            if k % 50 == 0:
                for i in range(N_DRONES):
                    w.write_heartbeat(t, i + 1, armed=k > 0, system_status=4)
        w.write_statustext(1.0, 2, 2, "drone 2 lost")
        w.write_statustext(1.5, 1, 6, "offboard setpoints resumed after a link cut; " * 3)


def f32(x: np.ndarray) -> np.ndarray:
    return x.astype(np.float32).astype(np.float64)


@pytest.fixture(scope="module")
def logged(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, np.ndarray]]:
    path = tmp_path_factory.mktemp("tlog") / "flight.tlog"
    s = truth()
    write(path, s, epoch_offset_s=1_700_000_000.0)
    return path, s


@pytest.fixture(scope="module")
def logged_at_epoch_zero(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    path = tmp_path_factory.mktemp("tlog0") / "flight.tlog"
    s = truth()
    write(path, s)  # the default epoch offset 0: records dated from 1970-01-01
    return path, s


def mavlogdump(*args: str) -> list[str]:
    env = {**os.environ, "MAVLINK20": "1"}
    out = subprocess.run(
        [sys.executable, str(MAVLOGDUMP), *args],
        env=env,
        capture_output=True,
        text=True,
        timeout=60,
        check=True,
    )
    return [line for line in out.stdout.splitlines() if line.strip()]


def test_round_trip_gives_every_state_to_float32_precision(logged):
    path, s = logged
    track = read_tlog(path)
    assert sorted(track.vehicles) == [1, 2, 3] and track.bad_records == 0
    for i in range(N_DRONES):
        v = track.vehicles[i + 1]
        np.testing.assert_allclose(v.t_s, s["t"], atol=1e-9)
        np.testing.assert_array_equal(v.position_ned_m, f32(s["pos"][:, i]))
        np.testing.assert_array_equal(v.velocity_ned_m_s, f32(s["vel"][:, i]))
        np.testing.assert_array_equal(v.euler_rad, f32(s["euler"][:, i]))
        np.testing.assert_array_equal(v.body_rates_rad_s, f32(s["rates"][:, i]))
        np.testing.assert_allclose(v.attitude_t_s, s["t"], atol=1e-9)


def test_status_texts_come_back_whole_with_their_time(logged):
    path, _ = logged
    texts = read_tlog(path, epoch_offset_s=1_700_000_000.0).statustexts
    assert [(x.sysid, x.severity, x.text) for x in texts] == [
        (2, 2, "drone 2 lost"),
        (1, 6, "offboard setpoints resumed after a link cut; " * 3),
    ]
    assert texts[0].t_s == pytest.approx(1.0, abs=1e-5)


def test_records_carry_epoch_offset_and_link_zero(logged):
    path, _ = logged
    data = path.read_bytes()
    (first,) = struct.unpack(">Q", data[:8])
    assert first & 0x3 == 0
    assert first == pytest.approx(1_700_000_000e6, abs=4)
    assert data[8] == 0xFD  # MAVLink 2


def test_resample_holds_samples_and_is_nan_before_data_and_after_silence(tmp_path):
    path = tmp_path / "gaps.tlog"
    with TlogWriter(path) as w:
        for k in range(10):  # sysid 1: 0.0 .. 0.9 s at 10 Hz
            w.write_vehicle_sample(0.1 * k, 1, [float(k), 0, 0], [0] * 3, [0] * 3, [0] * 3)
        w.write_vehicle_sample(0.5, 3, [7.0, 7.0, 7.0], [0] * 3, [0] * 3, [0] * 3)
    grid = np.round(np.arange(0, 2.0, 0.02), 9)
    pos = read_tlog(path).resample(grid)
    assert pos.shape == (grid.size, 3, 3)
    np.testing.assert_array_equal(pos[grid == 0.34, 0, 0], [3.0])  # held from t = 0.3
    np.testing.assert_array_equal(pos[grid == 0.4, 0, 0], [4.0])  # exactly on a sample
    assert np.all(np.isnan(pos[:, 1]))  # sysid 2 never sent
    assert np.all(np.isnan(pos[grid < 0.5, 2])) and np.all(pos[grid == 0.6, 2] == 7.0)
    assert np.all(np.isfinite(pos[grid <= 1.4, 0])) and np.all(np.isnan(pos[grid > 1.41, 0]))


def test_truncated_last_record_is_ignored(tmp_path, logged):
    path, _ = logged
    cut = tmp_path / "cut.tlog"
    cut.write_bytes(path.read_bytes()[:-5])
    track = read_tlog(cut)
    assert track.vehicles[1].t_s.size == N_SAMPLES
    assert track.statustexts[0].text == "drone 2 lost"  # the chunked last text is incomplete


def test_mavlogdump_reads_the_log(logged_at_epoch_zero):
    path, s = logged_at_epoch_zero
    lines = mavlogdump("--types", "LOCAL_POSITION_NED,ATTITUDE", str(path))
    assert sum("LOCAL_POSITION_NED {" in line for line in lines) == N_SAMPLES * N_DRONES
    assert sum("ATTITUDE {" in line for line in lines) == N_SAMPLES * N_DRONES
    first = next(line for line in lines if "LOCAL_POSITION_NED {" in line)
    x = float(first.split("x : ")[1].split(",")[0])
    assert x == pytest.approx(s["pos"][0, 0, 0], abs=1e-5)


def test_mavlogdump_json_gives_fields_and_record_times(logged):
    path, s = logged
    lines = mavlogdump("--format", "json", "--types", "LOCAL_POSITION_NED,HEARTBEAT", str(path))
    msgs = [json.loads(line) for line in lines]
    pos = [m for m in msgs if m["meta"]["type"] == "LOCAL_POSITION_NED"]
    beats = [m for m in msgs if m["meta"]["type"] == "HEARTBEAT"]
    assert len(pos) == N_SAMPLES * N_DRONES and len(beats) == 2 * N_DRONES
    last = pos[-1]
    assert last["data"]["time_boot_ms"] == round(s["t"][-1] * 1000)
    assert last["data"]["z"] == pytest.approx(s["pos"][-1, -1, 2], abs=1e-5)
    assert last["meta"]["timestamp"] == pytest.approx(1_700_000_000.0 + s["t"][-1], abs=1e-5)
    assert beats[0]["data"]["type"] == 2 and beats[0]["data"]["autopilot"] == 0  # quadrotor
    assert beats[-1]["data"]["base_mode"] & 128  # armed


def test_tracking_recomputed_from_the_tlog_matches_the_truth(tmp_path):
    s = truth(seed=2)
    path = tmp_path / "track.tlog"
    write(path, s)
    desired = np.zeros((N_SAMPLES, 9))
    desired[:, :3] = s["pos"].mean(axis=1) + np.array([0.0, 0.1, 0.0])
    member = np.ones((N_SAMPLES, N_DRONES), dtype=bool)
    expected = tracking_from_positions(s["t"], s["pos"], member, desired, settle_s=0.5)
    got = tracking_from_positions(s["t"], read_tlog(path).resample(s["t"]), member, desired, 0.5)
    assert got["n_samples"] == expected["n_samples"]
    assert got["centroid_m"]["rms"] == pytest.approx(expected["centroid_m"]["rms"], abs=1e-5)
    assert got["centroid_m"]["rms"] == pytest.approx(0.1, abs=1e-5)
    for name, stat in expected["descriptors"].items():
        if stat["rms"] is not None and not name.endswith("_rad"):
            assert got["descriptors"][name]["rms"] == pytest.approx(stat["rms"], abs=1e-4)


# --- events log -----------------------------------------------------------------------------


def test_events_are_appended_flushed_and_read_back(tmp_path):
    path = tmp_path / "run" / "events.jsonl"
    with EventLog(path) as log:
        log.record(0.0, "run_start", scenario="paper", n_drones=np.int64(9))
        log.record(30.0, "fault", what="kill", sysid=2, position=np.array([34.0, 0.0, -5.0]))
        # flushed at once: a reader sees it while the log is still open
        assert read_events(path)[-1]["kind"] == "fault"
        log.record(30.4, "dropout_detected", sysid=2, latency_s=float("nan"))
    with EventLog(path) as log:  # reopening appends
        log.record(200.0, "run_end")
    events = read_events(path)
    assert [e["kind"] for e in events] == ["run_start", "fault", "dropout_detected", "run_end"]
    assert events[0] == {"t_s": 0.0, "kind": "run_start", "scenario": "paper", "n_drones": 9}
    assert events[1]["position"] == [34.0, 0.0, -5.0]
    assert events[2]["latency_s"] is None  # strict JSON: no NaN
    assert all(math.isfinite(e["t_s"]) for e in events)


def test_read_events_skips_a_truncated_last_line_only(tmp_path):
    path = tmp_path / "events.jsonl"
    path.write_text('{"t_s": 1.0, "kind": "command"}\n\n{"t_s": 2.0, "kind": "fa')
    assert read_events(path) == [{"t_s": 1.0, "kind": "command"}]
    path.write_text('{"t_s": 1.0, "kind": "comm\n{"t_s": 2.0, "kind": "fault"}\n')
    with pytest.raises(ValueError, match=":1:"):
        read_events(path)


def test_event_log_refuses_what_json_cannot_hold(tmp_path):
    with EventLog(tmp_path / "e.jsonl") as log, pytest.raises(TypeError):
        log.record(1.0, "command", callback=object())


def test_agent_status_carries_the_integrated_neighbour_ids_and_reads_older_logs(tmp_path):
    """Layout 1 carries the ids (the lowest 46 of a larger set, the count whole); a layout-0
    record (what logs held before) reads back with its values and its ids unknown."""
    from protocols.mavlink.conventions import AGENT_NEIGHBOUR_SLOTS

    estimate = np.arange(9) * 1.5
    many = list(range(100, 150))  # more than the slots
    with TlogWriter(tmp_path / "s.tlog") as log:
        for t, ids in ((0.2, [7, 3, 5]), (0.4, []), (0.6, many)):
            values = np.array([*estimate, len(ids), 3, 1], dtype=float)
            log.write_agent_status(t, 2, values, ids)
        log.write_agent_status(0.8, 2, np.array([*estimate, 4, 3, 1], dtype=float))  # layout 0
    v = read_tlog(tmp_path / "s.tlog").vehicles[2]
    np.testing.assert_allclose(v.status_t_s, [0.2, 0.4, 0.6, 0.8])
    assert v.status_layout.tolist() == [1, 1, 1, 0]
    assert v.neighbour_ids(0) == (3, 5, 7) and v.neighbour_ids(1) == ()
    assert v.neighbour_ids(2) == tuple(many[:AGENT_NEIGHBOUR_SLOTS])
    assert v.neighbour_ids(3) is None  # unknown, not "no neighbours"
    assert v.status[:, 9].tolist() == [3, 0, 50, 4]  # the count stays whole
    np.testing.assert_allclose(v.status[:, :9], np.tile(estimate, (4, 1)))


def test_a_vehicle_sample_is_written_as_pymavlink_frames_it(tmp_path: Path) -> None:
    """write_vehicle_sample packs the two payloads itself: the bytes are pymavlink's frames of
    the same fields (float32 rounding, a payload's trailing zeros cut), from arrays or lists."""
    from pymavlink.dialects.v20 import common as mavlink

    from protocols.mavlink.fast import pack

    cases = [
        ([1.0, -2.5, 0.1234567891], [0.3, 0.0, 0.0], [0.01, -0.02, 3.1], [0.0, 0.0, 0.0]),
        ([1e-9, 123456.789, -3.0], [1.0, 2.0, 3.0], [0.0, 0.0, 0.0], [0.5, -0.5, 1e-3]),
    ]
    for k, (pos, vel, euler, rates) in enumerate(cases):
        for as_array in (False, True):
            path = tmp_path / f"s{k}{as_array}.tlog"
            conv = np.array if as_array else list
            with TlogWriter(path) as log:
                log.write_vehicle_sample(1.234, 3, conv(pos), conv(vel), conv(euler), conv(rates))
            mav = mavlink.MAVLink(None, srcSystem=3, srcComponent=1)
            want = pack(mav.local_position_ned_encode(1234, *pos, *vel), mav)
            want2 = pack(mav.attitude_encode(1234, *euler, *rates), mav)
            data = path.read_bytes()
            assert data[8 : 8 + len(want)] == want
            assert data[16 + len(want) :] == want2
            assert bytes(mav.local_position_ned_encode(1234, *pos, *vel).pack(mav)) == want


def test_an_agent_status_is_written_as_pymavlink_frames_it(tmp_path: Path) -> None:
    """write_agent_status packs DEBUG_FLOAT_ARRAY's payload itself: pymavlink's frame of the
    same fields (NaNs, layout 0 and 1 with neighbour ids)."""
    from pymavlink.dialects.v20 import common as mavlink

    from protocols.mavlink.conventions import AGENT_COMPID, AGENT_STATUS_LAYOUT, AGENT_STATUS_NAME
    from protocols.mavlink.fast import pack

    values = np.array([1.0, -2.0, 3.5, 0.1, np.nan, 0.2, 4.0, 1.5, 0.25, 6.0, np.nan, 1.0])
    for ids in (None, [7, 3, 12]):
        path = tmp_path / f"status{ids is None}.tlog"
        with TlogWriter(path) as log:
            log.write_agent_status(2.5, 4, values, ids)
        data = path.read_bytes()[8:]
        mav = mavlink.MAVLink(None, srcSystem=4, srcComponent=AGENT_COMPID)
        row = [float(v) for v in values]
        layout = 0 if ids is None else AGENT_STATUS_LAYOUT
        if ids is not None:
            row += [float(j) for j in sorted(ids)]
        row += [float("nan")] * (58 - len(row))
        msg = mav.debug_float_array_encode(2_500_000, AGENT_STATUS_NAME.encode(), layout, row)
        assert data == pack(msg, mav) == bytes(msg.pack(mav))


def test_the_frequent_records_read_without_message_objects_read_as_pymavlinks(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """TlogReader reads LOCAL_POSITION_NED, ATTITUDE, ACTUATOR_OUTPUT_STATUS and agent statuses
    from their unpacked payloads and skips the messages it never reads unbuilt: the track is the
    one pymavlink's message objects give, value for value, beside signed and MAVLink 1 records,
    a status from another component, truth, heartbeats, texts and a record with a bad checksum."""
    from pymavlink.dialects.v10 import common as v1
    from pymavlink.dialects.v20 import ardupilotmega
    from pymavlink.dialects.v20 import common as v2

    import gcs.report.tlog as tlog
    from protocols.mavlink.conventions import AGENT_COMPID

    s = truth(3)
    path = tmp_path / "mixed.tlog"
    rng = np.random.default_rng(4)
    with TlogWriter(path) as w:
        for k, t in enumerate(s["t"][:40]):
            for i in range(N_DRONES):
                w.write_vehicle_sample(
                    t, i + 1, s["pos"][k, i], s["vel"][k, i], s["euler"][k, i], s["rates"][k, i]
                )
                quat = [1.0, *(0.5 * s["euler"][k, i])]
                w.write_truth(t, i + 1, s["pos"][k, i], s["vel"][k, i], quat, s["rates"][k, i])
                forces = [float(f) for f in rng.uniform(0.0, 3.0, 4)] + [0.0] * 28
                w.write_message(t, i + 1, v2.MAVLink_actuator_output_status_message(
                    int(t * 1e6), 15, forces))  # fmt: skip
                values = np.array([*rng.normal(size=9), 2, 3, 1], dtype=float)
                w.write_agent_status(t, i + 1, values, [0, 2] if k % 2 else None)
                w.write_message(t, i + 1, v2.MAVLink_sys_status_message(*[0] * 13))
            w.write_heartbeat(t, 1, armed=True, system_status=4)
        other = v2.MAVLink(None, srcSystem=2, srcComponent=AGENT_COMPID + 1)  # not an agent's
        w.write_packet(0.5, other.debug_float_array_encode(1, b"AGENT", 1, [1.0] * 58).pack(other))
        signed = v2.MAVLink(None, srcSystem=3, srcComponent=1)
        signed.signing.secret_key = bytes(32)
        signed.signing.sign_outgoing = True
        w.write_packet(0.6, signed.local_position_ned_encode(600, 1, 2, 3, 4, 5, 6).pack(signed))
        old = v1.MAVLink(None, srcSystem=2, srcComponent=1)
        w.write_packet(0.7, old.attitude_encode(700, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6).pack(old))
        bad = bytearray(v2.MAVLink(None, 1, 1).attitude_encode(800, 1, 1, 1, 1, 1, 1).pack(
            v2.MAVLink(None, 1, 1)))  # fmt: skip
        bad[-1] ^= 0xFF
        w.write_packet(0.8, bytes(bad))
        w.write_statustext(0.9, 2, 2, "drone 2 lost")
    fast = read_tlog(path)
    monkeypatch.setattr(tlog, "_FAST_ROWS", {})
    every = frozenset(c.msgname for c in ardupilotmega.mavlink_map.values())
    monkeypatch.setattr(tlog, "_READ", every)
    built = read_tlog(path)
    assert fast.vehicles.keys() == built.vehicles.keys() == {1, 2, 3}
    for sysid, v in fast.vehicles.items():
        u = built.vehicles[sysid]
        for name in ("t_s", "position_ned_m", "status_t_s", "status", "status_layout"):
            np.testing.assert_array_equal(getattr(v, name), getattr(u, name), err_msg=name)
        assert v.neighbour_ids(1) == u.neighbour_ids(1)
    assert fast.vehicles[1].status.shape[0] == 40 and fast.bad_records == built.bad_records == 1
    assert [x.text for x in fast.statustexts] == [x.text for x in built.statustexts]


def test_a_log_read_piece_by_piece_tracks_as_it_reads_whole(logged, tmp_path: Path) -> None:
    """TlogReader.track() after each piece (a drills run asks every half second, converting
    only the rows read since) ends with the track read_tlog gives of the whole log."""
    from gcs.report.tlog import TlogReader

    path, _ = logged
    data = path.read_bytes()
    reader, used = TlogReader(epoch_offset_s=1_700_000_000.0), 0
    for cut in (0, 57, 2000, 2001, 9000, len(data) // 2, len(data)):
        used += reader.feed(data[used:cut])
        partial = reader.track()
        assert all(v.t_s.size <= N_SAMPLES for v in partial.vehicles.values())
    whole = read_tlog(path, epoch_offset_s=1_700_000_000.0)
    got = reader.track()
    assert got.vehicles.keys() == whole.vehicles.keys()
    for sysid, v in whole.vehicles.items():
        for name in ("t_s", "position_ned_m", "euler_rad", "heartbeat_t_s", "armed"):
            np.testing.assert_array_equal(getattr(got.vehicles[sysid], name), getattr(v, name))
