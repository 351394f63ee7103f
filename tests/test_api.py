"""gcs.api end to end: swarms started by the ``swarm`` fixture (the package's pytest plugin) on
free ports in lockstep, commanded through the API, judged from what the vehicles did (the
report's flight.tlog and events.jsonl), the CLI's refusal against the API's, the asyncio form
with an exception inside the block; and the pure parts (requests, arrival) on their own."""

from __future__ import annotations

import asyncio
import itertools
import math
import subprocess
from pathlib import Path

import numpy as np
import pytest
from sitl_client import ENV, ROOT, swarm_command

from gcs.api import (
    AsyncSwarm,
    CommandRefused,
    Failsafe,
    NoGroundStation,
    Superseded,
    Swarm,
    UsageError,
    load_report,
)
from gcs.api.requests import command_request, fault_command
from gcs.api.state import Sent, Status, arrived, status_of
from gcs.report.events import read_events
from gcs.report.tlog import TlogTrack, read_tlog
from protocols.faults import LinkCut

N = 4


def _at(track: TlogTrack, t_s: float) -> np.ndarray:
    """Every vehicle's position (N, 3) at the last sample at or before ``t_s``."""
    out = []
    for sysid in range(1, N + 1):
        v = track.vehicles[sysid]
        k = int(np.searchsorted(v.t_s, t_s, side="right")) - 1
        assert k >= 0 and t_s - v.t_s[k] < 0.2, (sysid, t_s)
        out.append(v.position_ned_m[k])
    return np.array(out)


def _armed(track: TlogTrack, sysid: int, t_s: float) -> bool:
    v = track.vehicles[sysid]
    k = int(np.searchsorted(v.heartbeat_t_s, t_s, side="right")) - 1
    return bool(v.armed[k]) if k >= 0 else False


def test_a_session_flown_through_the_api(swarm) -> None:  # type: ignore[no-untyped-def]
    with swarm(drones=N) as s:
        ready = s.wait_ready()
        took = s.takeoff(altitude_m=3)
        assert took.reason.startswith("plan 1: centre arrives at t = ")
        up = took.wait()
        with pytest.raises(CommandRefused) as refused:
            s.scale(factor=0.1)
        typed = subprocess.run(
            swarm_command(
                "scale", "--factor", "0.1", "--zenoh-connect", s.link.endpoint, "--swarm-id",
                "swarm",
            ),
            capture_output=True, text=True, env=ENV, cwd=ROOT, timeout=60,
        )  # fmt: skip
        cut = s.drill("link-cut", i=0, j=1, for_s=3.0)
        start = s.descriptors()
        moved = s.move(north_m=2).wait()
        after = s.descriptors()
        down = s.land().wait()
    # the CLI says the same refusal, from the same code
    assert typed.returncode == 1, typed.stdout + typed.stderr
    first = typed.stdout.splitlines()[0]
    assert first.startswith("scale: refused (") and first.endswith(f": {refused.value.reason}")
    assert "cannot hold 4 drones" in refused.value.reason
    # the replies' view: at 3 m when the take-off arrived, 2 m north after the move, estimates
    assert ready.mode == ("READY",) * N and not ready.armed.any()
    assert up.alive.all() and np.allclose(-up.position_ned_m[:, 2], 3.0, atol=0.2)
    assert after.true[0] - start.true[0] == pytest.approx(2.0, abs=0.1)
    assert np.abs(after.estimated[:, :3] - after.true[:3]).max() < 0.1
    assert down.mode == ("LANDED",) * N and not down.armed.any()
    # what the vehicles did: flight.tlog and events.jsonl
    report_dir = s.report_dir or s.report.folder
    track = read_tlog(report_dir / "flight.tlog")
    events = read_events(report_dir / "events.jsonl")
    commands = {e["command"]: e["t_s"] for e in events if e["kind"] == "command" and e["accepted"]}
    assert set(commands) >= {"takeoff", "move", "land"}
    before = _at(track, commands["takeoff"] - 0.1)
    assert np.abs(before[:, 2]).max() < 0.05  # on the ground until the take-off
    assert not any(_armed(track, i, commands["takeoff"] - 0.1) for i in range(1, N + 1))
    at_3m = _at(track, up.t_s)
    assert np.allclose(-at_3m[:, 2], 3.0, atol=0.2)
    there = _at(track, moved.t_s)
    shift = there.mean(axis=0) - at_3m.mean(axis=0)
    assert shift[0] == pytest.approx(2.0, abs=0.1) and abs(shift[1]) < 0.1
    end = _at(track, down.t_s)
    assert np.abs(end[:, 2]).max() < 0.05
    assert not any(_armed(track, i, down.t_s) for i in range(1, N + 1))
    assert not [e for e in events if e["kind"] in ("crash", "failsafe", "dropout_detected")]
    # the drill reached the agents: the ground station logged it, and while it lasted neither
    # end of the cut link integrated the other (the agents' statuses in flight.tlog)
    assert cut.what == "sent link_cut 0<->1 for 3 s" and cut.fault is not None
    drills = [e for e in events if e["kind"] == "drill" and e.get("drill") == "link_cut"]
    assert len(drills) == 1 and drills[0]["link"] == [0, 1]
    t_cut = float(drills[0]["t_s"])
    for me, other in ((1, 2), (2, 1)):
        v = track.vehicles[me]
        during = [k for k, t in enumerate(v.status_t_s) if t_cut + 0.5 < t < t_cut + 2.5]
        heard = [v.neighbour_ids(k) for k in during]
        assert during and all(h is not None and other - 1 not in h for h in heard), heard
    # the report read back on leaving the block: arrays and the metrics of metrics.json
    report = s.report
    assert report is not None and s.end_reason == "shut down"
    t, n, three = report.positions_ned_m.shape
    assert (n, three) == (N, 3) and report.t_s.shape == (t,) and report.estimates.shape == (t, N, 9)
    k = int(np.searchsorted(report.t_s, moved.t_s))
    assert np.abs(report.positions_ned_m[k] - _at(track, report.t_s[k])).max() < 1e-6
    computed, written = report.metrics(), report.metrics_file
    for key in ("tracking", "consensus", "separation", "collisions", "reconvergence", "n_samples"):
        assert computed[key] == written[key], key
    frame = report.to_pandas()
    assert len(frame) == t * N
    assert frame.loc[(report.t_s[k], 2), "north_m"] == report.positions_ned_m[k, 2, 0]


def test_the_asyncio_form_lands_and_reports_when_the_block_raises(tmp_path: Path) -> None:
    folder = tmp_path / "report"
    seen = []

    async def fly() -> None:
        async with await AsyncSwarm.start(drones=N, report=folder) as s:
            await (await s.takeoff(altitude_m=2)).wait()
            async for status in s.subscribe(period_s=0.1, timeout_s=2.0):
                seen.append(status)
            raise RuntimeError("the user's code failed")

    with pytest.raises(RuntimeError, match="the user's code failed"):
        asyncio.run(fly())
    assert len(seen) >= 2 and all(b.t_s > a.t_s for a, b in itertools.pairwise(seen))
    assert all(np.isfinite(st.estimate).all() and st.estimate.shape == (N, 9) for st in seen)
    # leaving the block landed the swarm and wrote the report
    track = read_tlog(folder / "flight.tlog")
    events = read_events(folder / "events.jsonl")
    assert [e["reason"] for e in events if e["kind"] == "shutdown"] == ["interrupt"]
    last = max(float(track.vehicles[i].t_s[-1]) for i in range(1, N + 1))
    assert np.allclose(-seen[-1].position_ned_m[:, 2], 2.0, atol=0.3)  # it flew
    assert np.abs(_at(track, last)[:, 2]).max() < 0.05
    assert not any(_armed(track, i, last) for i in range(1, N + 1))
    assert load_report(folder).metrics()["tracking"] == load_report(folder).metrics_file["tracking"]


# -- the pure parts --------------------------------------------------------------------------
def test_requests_are_checked_with_the_flag_names() -> None:
    assert command_request("move", north_m=2, east_m=None).args == {"north_m": 2.0}
    assert command_request("formation", centre=(1, 2, 3)).args == {"centre_ned_m": [1.0, 2.0, -3.0]}
    with pytest.raises(UsageError, match=r"north_m \(--north-m\) must be a finite number"):
        command_request("move", north_m=math.nan)
    with pytest.raises(UsageError, match=r"takeoff: altitude_m \(--altitude-m\) is required"):
        command_request("takeoff")
    with pytest.raises(UsageError, match="move: unknown argument 'altitude_m'"):
        command_request("move", altitude_m=3)
    with pytest.raises(UsageError, match="centre"):
        command_request("formation", centre=(1, 2))
    assert fault_command("link-cut", i=0, j=1, for_s=5) == LinkCut(0, 1, False, 5.0)
    with pytest.raises(UsageError, match=r"gap_s \(--gap-s\) must be a positive"):
        fault_command("restart", drone=1, gap_s=0)


def test_the_cli_says_a_bad_value_in_one_line_as_the_api() -> None:
    out = subprocess.run(
        swarm_command("move", "--north-m", "nan", "--zenoh-connect", "tcp/127.0.0.1:1"),
        capture_output=True, text=True, env=ENV, cwd=ROOT, timeout=60,
    )  # fmt: skip
    assert out.returncode == 2 and out.stderr.count("\n") == 1, out.stderr
    with pytest.raises(UsageError) as api:
        command_request("move", north_m=math.nan)
    assert out.stderr == f"swarm: error: {api.value}\n"


def _status(t_s: float, seq: int, late: float | None, **row: object) -> Status:
    base = {"drone": 0, "alive": True, "mode": "FLYING", "armed": True, "failsafes": 0}
    return status_of(t_s, {"seq": seq, "command": "FLY", "late_s": late}, seq, [{**base, **row}])


def test_a_command_arrives_when_the_plan_says_as_late_as_it_is_flown() -> None:
    sent = Sent("move", 2, 10.0, {0: 0}, frozenset())
    assert not arrived(sent, _status(9.9, 2, 0.0))
    assert arrived(sent, _status(10.0, 2, 0.0))
    assert not arrived(sent, _status(11.0, 2, 1.5))  # the take-off came 1.5 s late
    assert not arrived(sent, _status(20.0, 2, None))  # still waiting on the ground
    with pytest.raises(Superseded, match="replaced by plan 3"):
        arrived(sent, _status(9.0, 3, 0.0))
    with pytest.raises(Failsafe, match="drone 0's vehicle failed safe"):
        arrived(sent, _status(9.0, 2, 0.0, failsafes=1))
    with pytest.raises(Failsafe, match="drone 0 lost"):
        arrived(sent, _status(9.0, 2, 0.0, lost={"t_s": 8.0, "reason": "vehicle crashed"}))
    landing = Sent("land", 3, 10.0, {0: 0}, frozenset())
    assert not arrived(landing, _status(30.0, 3, 0.0, mode="LANDING"))
    assert arrived(landing, _status(30.0, 3, 0.0, mode="LANDED", armed=False))


def test_mistakes_before_anything_flies(tmp_path: Path) -> None:
    with pytest.raises(UsageError, match="not both"):
        Swarm.start(ROOT / "scenarios" / "tilt9.toml", drones=4)
    with pytest.raises(UsageError, match=r"no flight\.tlog"):
        load_report(tmp_path)
    with pytest.raises(NoGroundStation, match="no ground station"):
        Swarm.connect("tcp/127.0.0.1:1")


def test_a_reply_carries_its_time_arrival_and_plan_and_older_replies_still_decode() -> None:
    import json

    from gcs.station.commands import Reply, decode_reply, encode_reply

    reply = Reply(True, "plan 2", 2, (), t_s=5.5, arrives_s=9.25,
                  plan={"seq": 2, "command": "FLY", "late_s": None})  # fmt: skip
    assert decode_reply(encode_reply(reply)) == reply
    old = {"version": 1, "accepted": False, "reason": "no", "seq": 1, "table": []}
    assert decode_reply(json.dumps(old).encode()) == Reply(False, "no", 1)


def test_start_says_swarm_up_s_words_and_refuses_what_it_would() -> None:
    from gcs.api.launch import up_words

    words, n = up_words(None, 4, "lockstep", seed=3, layout="line", duration_s=None)
    assert (words, n) == (["--drones", "4", "--seed", "3", "--layout", "line"], 4)
    tilt9 = ROOT / "scenarios" / "tilt9.toml"
    assert up_words(tilt9, None, "realtime", duration_s=5.0) == (
        [str(tilt9), "--duration-s", "5.0"],
        9,
    )
    with pytest.raises(UsageError, match="seed goes with drones=N"):
        up_words(tilt9, None, "lockstep", seed=1)
    with pytest.raises(UsageError, match="no fixed duration"):
        up_words(None, 4, "lockstep", duration_s=10.0)
    with pytest.raises(UsageError, match=r"clock \(--clock\)"):
        up_words(None, 4, "fast")
    with pytest.raises(UsageError, match=r"nowhere\.toml"):
        up_words(ROOT / "nowhere.toml", None, "lockstep")


def test_every_public_name_resolves() -> None:
    import gcs.api

    assert all(getattr(gcs.api, name) is not None for name in gcs.api.__all__)


def test_a_swarm_simulate_report_reads_back_with_its_losses(tmp_path: Path) -> None:
    """``swarm simulate`` logs no joins: load_report counts the drones as it does (members from
    the start until the scenario's drop-out and crash), so the figures agree with its
    metrics.json, computed in the process at the control rate, to the 25 Hz log's sampling."""
    scenario = tmp_path / "drop.toml"
    for words in (
        ("scenario", "new", "--drones", "5", "--template", "hover", "--faults", "dropout,crash",
         "--duration-s", "30", "-o", str(scenario)),
        ("simulate", str(scenario), "--report", str(tmp_path / "r"), "--no-plots",
         "--no-recording"),
    ):  # fmt: skip
        done = subprocess.run(swarm_command(*words), capture_output=True, text=True, env=ENV)
        assert done.returncode == 0, done.stdout + done.stderr
    report = load_report(tmp_path / "r", scenario=scenario)
    computed, written = report.metrics(), report.metrics_file
    assert computed["drones_lost"] == written["drones_lost"] and len(written["drones_lost"]) == 2
    assert report.member[-1].sum() == 3 and report.member[0].all()
    for part in ("tracking", "tracking_steady"):
        for key in ("centroid_m", "shape_m2"):
            assert computed[part][key]["rms"] == pytest.approx(written[part][key]["rms"], rel=0.02)
    assert computed["separation"]["min_m"] == pytest.approx(
        written["separation"]["min_m"], abs=1e-3
    )
