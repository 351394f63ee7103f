"""Rerun views: ``swarm simulate`` writes flight.rrd and Rerun's own reader finds in it the
entities, time range and values of flight.tlog and events.jsonl, and the radio links the tlog's
agent statuses name (a cut pair not drawn during its cut); the live view of a tlog being
written sends the same samples and links; ``swarm replay`` serves the web viewer (HTTP 200);
without Rerun the view commands say how to install it, and the rest of the tool never imports
it."""

from __future__ import annotations

import importlib.util
import json
import socket
import subprocess
import sys
import time
import urllib.request
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pytest
from agent_harness import write_scenario
from sitl_client import ENV, ROOT, swarm_command

from gcs.cli.main import main
from gcs.reference.simulate import simulate
from gcs.report.events import read_events
from gcs.report.tlog import read_tlog
from gcs.view import recording as recording_module
from protocols.scenario.scenario_file import load_scenario

pytestmark = pytest.mark.timeout(120)
SQUARE = [(0.0, 0.0, 0.0), (0.0, 3.0, 0.0), (4.0, 0.0, 0.0), (4.0, 3.0, 0.0)]
#: The radio link between drones 0 and 1 is cut over these simulated seconds.
CUT_S = (2.0, 4.0)
LINK_CUT = f"""
[[faults]]
t_s = {CUT_S[0]}
kind = "link_cut"
drones = [0, 1]
duration_s = {CUT_S[1] - CUT_S[0]}
"""
ENTITIES = {
    "/swarm/drones", "/swarm/trails", "/swarm/estimates", "/swarm/formation/commanded",
    "/swarm/formation/actual", "/events", "/descriptors/centre_n/commanded",
    "/descriptors/yaw/actual", "/separation/min_m", "/consensus/error_m", "/links/neighbours_mean",
    "/swarm/links", "/links/pairs",
}  # fmt: skip


@pytest.fixture(scope="module")
def report(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 6-s flight of four drones, flown by ``swarm simulate``'s code in this process, the
    link between drones 0 and 1 cut over :data:`CUT_S`: the warm-up, then a brisk climb to 2 m
    (its plan climbs in 1 s from the ground: the agents' estimates lag the truth enough to be
    seen beside it on the plots), a hover."""
    tmp = tmp_path_factory.mktemp("view")
    path = write_scenario(
        tmp / "hover.toml", SQUARE, centre=(2.0, 1.5, -2.0), spread=(2.0, 1.5, 0.0), duration_s=6.0,
        extra=LINK_CUT,
    )  # fmt: skip
    climb = "[[trajectory.waypoints]]\nt_s = 0.0\ncentre_ned_m = [2.0, 1.5, 0.0]\n"
    written = path.read_text()
    first = "[[trajectory.waypoints]]\nt_s = 0.0\n"
    assert first in written
    text = written.replace(
        first, climb + "spread_m = [2.0, 1.5, 0.0]\n\n[[trajectory.waypoints]]\nt_s = 1.0\n", 1
    )
    path.write_text(text)
    out = tmp / "report"
    result = simulate(load_scenario(path), out, plots=False)
    assert out / "flight.rrd" in result.files
    return out


def _rows(rrd: Path) -> dict[str, list[dict[str, Any]]]:
    """Every row of every temporal chunk of ``rrd`` by entity path, read with Rerun's reader;
    ``sim_time`` in seconds."""
    from rerun.chunk import RrdReader

    out: dict[str, list[dict[str, Any]]] = {}
    for chunk in RrdReader(rrd).stream():
        if chunk.is_static:
            continue
        batch = chunk.to_record_batch()
        times = batch.column("sim_time").cast(pa.int64()).to_numpy() / 1e9
        cols = {name: batch.column(name).to_pylist() for name in batch.schema.names
                if ":" in name}  # fmt: skip
        for k, t in enumerate(times):
            out.setdefault(chunk.entity_path, []).append(
                {"t_s": float(t), **{c: v[k] for c, v in cols.items()}}
            )
    for rows in out.values():
        rows.sort(key=lambda r: r["t_s"])
    return out


def _drone_positions(rows: list[dict[str, Any]]) -> tuple[np.ndarray, np.ndarray]:
    """Times (T,) and positions (T, N, 3) of ``/swarm/drones`` (all drones heard in each row)."""
    t = np.array([r["t_s"] for r in rows])
    pos = np.array([r["Points3D:positions"] for r in rows], dtype=float)
    return t, pos


def test_recording_matches_the_tlog_and_events(report: Path) -> None:
    rrd = report / "flight.rrd"
    assert rrd.read_bytes()[:4] == b"RRF2"
    rows = _rows(rrd)
    assert set(rows) >= ENTITIES
    track = read_tlog(report / "flight.tlog")
    t_log = track.vehicles[1].t_s
    t, pos = _drone_positions(rows["/swarm/drones"])
    np.testing.assert_allclose(t, t_log, atol=1e-6)  # the tlog's samples, first to last
    for sysid, v in track.vehicles.items():
        np.testing.assert_allclose(pos[:, sysid - 1], v.position_ned_m, atol=1e-5)  # float32
    labels = rows["/swarm/drones"][-1]["Points3D:labels"]
    assert labels == ["1", "2", "3", "4"]
    events = read_events(report / "events.jsonl")
    texts = [r["TextLog:text"][0] for r in rows["/events"]]
    assert len(texts) == len(events) and any(t.startswith("drone 2 armed") for t in texts)
    # the commanded ellipsoid is the plan's centre and spreads; the true one nearby once flying
    plan = json.loads((report / "trajectory.json").read_text())
    assert plan["seq"] == 0
    last = rows["/swarm/formation/commanded"][-1]
    np.testing.assert_allclose(last["Ellipsoids3D:centers"], [[2.0, 1.5, -2.0]], atol=1e-5)
    np.testing.assert_allclose(last["Ellipsoids3D:half_sizes"], [[2.0, 1.5, 0.0]], atol=1e-5)
    actual = rows["/swarm/formation/actual"][-1]["Ellipsoids3D:centers"][0]
    assert np.linalg.norm(np.subtract(actual, [2.0, 1.5, -2.0])) < 1.0
    separation = [r["Scalars:scalars"][0] for r in rows["/separation/min_m"]]
    assert min(separation) > 1.0
    estimates = rows["/swarm/estimates"]
    assert len(estimates[-1]["Points3D:positions"]) == 4  # every agent's centre estimate


def _links_drawn(rows: dict[str, list[dict[str, Any]]]) -> dict[float, set[frozenset[int]]]:
    """Time -> the pairs of drone indices that ``/swarm/links`` joins at that time, each segment's
    ends matched to the drones' positions in ``/swarm/drones`` at the same time."""
    drones = {r["t_s"]: r for r in rows["/swarm/drones"]}
    out: dict[float, set[frozenset[int]]] = {}
    for row in rows["/swarm/links"]:
        at = drones[row["t_s"]]
        pos = np.array(at["Points3D:positions"], dtype=float)
        ids = [int(label) - 1 for label in at["Points3D:labels"]]
        pairs = set()
        for strip in row["LineStrips3D:strips"] or []:
            assert len(strip) == 2
            ends = [int(np.argmin(np.linalg.norm(pos - np.array(p), axis=1))) for p in strip]
            for p, e in zip(strip, ends, strict=True):
                np.testing.assert_allclose(p, pos[e], atol=1e-5)  # a segment joins two drones
            pairs.add(frozenset(ids[e] for e in ends))
        out[row["t_s"]] = pairs
    return out


def test_recording_draws_the_links_the_tlog_names_and_not_the_cut_one(report: Path) -> None:
    rows = _rows(report / "flight.rrd")
    drawn = _links_drawn(rows)
    track = read_tlog(report / "flight.tlog")
    statuses = 0
    for v in track.vehicles.values():  # the tlog's record carries the ids, their count whole
        assert (v.status_layout == 1).all()
        for k in range(v.status_t_s.size):
            assert len(v.neighbour_ids(k) or ()) == v.status[k, 9]
            statuses += 1
    assert statuses > 4 * 25  # every agent at 5 Hz over 6 s
    expected_rows = 0
    for t, pairs in drawn.items():
        # from the tlog alone: each agent's latest status at most 1 s old names its neighbours
        expected = set()
        for sysid, v in track.vehicles.items():
            k = int(np.searchsorted(v.status_t_s, t + 5e-4, side="right")) - 1
            if k >= 0 and t - v.status_t_s[k] <= 1.0 + 5e-4:
                expected |= {frozenset((sysid - 1, j)) for j in v.neighbour_ids(k) or ()}
        assert pairs == expected, t
        expected_rows += bool(expected)
    assert expected_rows > 40  # links drawn at 10 Hz through the flight
    cut = {0, 1}
    during = [t for t in drawn if CUT_S[0] + 0.25 <= t < CUT_S[1]]
    before = [t for t in drawn if 1.0 <= t < CUT_S[0]]
    after = [t for t in drawn if CUT_S[1] + 0.5 <= t]
    assert during and before and after
    assert all(cut not in drawn[t] for t in during)  # the cut pair is not drawn
    assert all(cut in drawn[t] for t in before + after)  # but is outside the cut
    assert all(len(drawn[t]) == 5 for t in during) and all(len(drawn[t]) == 6 for t in after)
    totals = {r["t_s"]: r["Scalars:scalars"][0] for r in rows["/links/pairs"]}
    assert all(totals[t] == len(pairs) for t, pairs in drawn.items())


def _blueprint(rrd: Path) -> dict[str, dict[str, Any]]:
    """The default blueprint stored in ``rrd``: entity path -> its components' values."""
    from rerun.chunk import RrdReader

    reader = RrdReader(rrd)
    (store,) = reader.blueprints()
    out: dict[str, dict[str, Any]] = {}
    for chunk in reader.stream(store=store):
        batch = chunk.to_record_batch()
        values = {n.split(":")[1]: batch.column(n).to_pylist()[-1] for n in batch.schema.names
                  if ":" in n}  # fmt: skip
        out.setdefault(chunk.entity_path, {}).update(values)
    return out


def test_recording_carries_the_swarm_layout(report: Path) -> None:
    """flight.rrd's default blueprint: one 3-D view of ``swarm``, a plot per descriptor with
    its command, true value and agents' estimates, the events log, the time panel on
    ``sim_time``; every entity a plot names is in the recording (no empty plot)."""
    from gcs.view.rerun_series import DESCRIPTOR_PLOTS

    parts = _blueprint(report / "flight.rrd")
    views = {path: v for path, v in parts.items() if "class_identifier" in v}
    kinds = [v["class_identifier"][0] for v in views.values()]
    assert kinds.count("3D") == 1 and kinds.count("TextLog") == 1
    (swarm,) = [v for v in views.values() if v["class_identifier"][0] == "3D"]
    assert swarm["space_origin"][0].strip("/") == "swarm"
    queries = {
        v["display_name"][0]: parts[f"{path}/ViewContents"]["query"]
        for path, v in views.items()
        if v["class_identifier"][0] == "TimeSeries"
    }
    for _, name, title in DESCRIPTOR_PLOTS:
        assert sorted(queries[title]) == [
            f"/descriptors/{name}/{series}" for series in ("actual", "commanded", "estimates")
        ]
    assert queries["Δ heading [°]"] == ["/descriptors/yaw/error"]
    recorded = set(_rows(report / "flight.rrd"))
    assert {q for query in queries.values() for q in query} <= recorded
    assert parts["/time_panel"]["timeline"] == ["sim_time"]
    (events,) = [p for p, v in views.items() if v["class_identifier"][0] == "TextLog"]
    assert views[events]["space_origin"][0].strip("/") == "events"


def test_recording_plots_each_descriptor_as_descriptors_png(report: Path) -> None:
    """Each descriptor's plot carries what the report's figure plots of the flight's logs: the
    command and the true value at every sample, every agent's estimate on the trail rows (about
    10 a second), altitude up, angles in degrees within half a turn of the command, and the
    angle's error."""
    from gcs.view.rerun_log import trail_stride
    from gcs.view.rerun_series import DESCRIPTOR_PLOTS
    from gcs.view.scene import scene_from_report

    scene = scene_from_report(report)
    assert scene is not None
    stride, _ = trail_stride(scene.t_s)
    assert stride == 2  # 12.5 rows a second at the tlog's 25 Hz
    assert scene.heading_ok[-25:].all()  # length and width spreads apart: a heading
    rows = _rows(report / "flight.rrd")
    for k, name, _ in DESCRIPTOR_PLOTS:
        sign = -1.0 if name == "altitude" else 1.0
        scale = np.degrees(1.0) if name in ("roll", "pitch", "yaw") else 1.0
        estimates = rows[f"/descriptors/{name}/estimates"]
        t = np.array([r["t_s"] for r in estimates])
        np.testing.assert_allclose(t, scene.t_s[::stride], atol=1e-6)
        got = np.array([r["Scalars:scalars"] for r in estimates], dtype=float)
        want = sign * scale * scene.estimate[::stride, :, k]
        if scale != 1.0:  # the angle within half a turn of the command; none without a heading
            ref = scale * scene.desired[::stride, k : k + 1]
            want = ref + (want - ref + 180.0) % 360.0 - 180.0
            want[~scene.heading_ok[::stride]] = np.nan
        assert got.shape == (t.size, 4) and np.isfinite(got[-10:]).all()
        np.testing.assert_allclose(got, want, atol=1e-9)
        for series, values in (("commanded", scene.desired), ("actual", scene.actual)):
            got_rows = rows[f"/descriptors/{name}/{series}"]
            at = np.searchsorted(scene.t_s, np.array([r["t_s"] for r in got_rows]) - 1e-6)
            assert at.size >= 0.8 * scene.t_s.size  # (where known)
            value = np.array([r["Scalars:scalars"][0] for r in got_rows])
            np.testing.assert_allclose(value, sign * scale * values[at, k], atol=1e-9)
    error = rows["/descriptors/yaw/error"]
    at = np.searchsorted(scene.t_s, np.array([r["t_s"] for r in error]) - 1e-6)
    value = np.array([r["Scalars:scalars"][0] for r in error])
    wrapped = (np.degrees(scene.actual[at, 5] - scene.desired[at, 5]) + 180.0) % 360.0 - 180.0
    np.testing.assert_allclose(value, wrapped, atol=1e-9)
    assert np.abs(value[-25:]).max() < 10.0  # hovering: the heading held


def test_recording_draws_the_commanded_frame(report: Path) -> None:
    """``swarm/formation/commanded_axes``: three arrows from the commanded centre along the
    commanded ellipsoid's axes, as long as its half-axes (at least 0.5 m)."""
    from gcs.view.rerun_log import AXIS_MIN_M

    rows = _rows(report / "flight.rrd")
    last = rows["/swarm/formation/commanded_axes"][-1]
    ellipsoid = rows["/swarm/formation/commanded"][-1]
    origins = np.array(last["Arrows3D:origins"])
    vectors = np.array(last["Arrows3D:vectors"])
    np.testing.assert_allclose(origins, np.repeat(ellipsoid["Ellipsoids3D:centers"], 3, axis=0))
    x, y, z, w = ellipsoid["Ellipsoids3D:quaternions"][0]
    rot = np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])  # fmt: skip
    half = np.maximum(ellipsoid["Ellipsoids3D:half_sizes"][0], AXIS_MIN_M)
    np.testing.assert_allclose(vectors, (rot * half).T, atol=1e-5)
    np.testing.assert_allclose(np.linalg.norm(vectors, axis=1), [2.0, 1.5, 0.5], atol=1e-5)


def test_angles_are_shown_within_half_a_turn_of_the_command() -> None:
    from gcs.view.rerun_series import shown

    desired = np.radians([170.0, -170.0, 10.0, np.nan, 0.0])
    values = np.radians([-175.0, 175.0, 20.0, 30.0, 5.0])
    ok = np.array([True, True, True, True, False])  # no heading in the last sample
    np.testing.assert_allclose(
        shown(values, desired, 5, ok), [185.0, -185.0, 20.0, 30.0, np.nan], atol=1e-9
    )
    np.testing.assert_allclose(shown(values, desired, 2, ok), -values)  # altitude is -D
    assert shown(values, desired, 6, ok) is values  # variances as they are


def test_formation_axes_of_a_turned_formation() -> None:
    from gcs.view.rerun_log import formation_axes

    # heading 90 deg: length along east, width along south (-north), height down
    d = np.array([[1.0, 2.0, -3.0, 0.0, 0.0, np.pi / 2, 4.0, 1.0, 0.0]])
    np.testing.assert_allclose(
        formation_axes(d)[0], [[0.0, 2.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 0.5]], atol=1e-12
    )


def test_links_of_a_large_swarm_are_thinned_to_the_cap() -> None:
    from gcs.view.rerun_log import MAX_LINKS, thin
    from gcs.view.scene import link_pairs

    n, k = 250, 20  # each agent integrates its 20 successors (mod n), some only one way
    ids = np.array([[(i + d) % n for d in range(1, k + 1)] for i in range(n)], dtype=float)
    ids[::2, 0] = np.nan  # even agents do not integrate their next neighbour
    pos = np.random.default_rng(0).normal(size=(n, 3))
    pos[7] = np.nan  # drone 7 not heard yet: none of its links drawn
    pairs, both = link_pairs(ids, pos)
    assert pairs.shape == (n * k - 2 * k - n // 2 + 1, 2)  # 7's links and the even ones gone
    assert (pairs[:, 0] < pairs[:, 1]).all() and not (pairs == 7).any()
    assert not both.any()  # i integrates i+d, never the other way round (d < n / 2)
    keep = thin(pairs.shape[0])
    assert keep.size == MAX_LINKS and np.unique(keep).size == MAX_LINKS
    assert keep[0] == 0 and keep[-1] > 0.99 * pairs.shape[0] - 1  # spread over all of them
    assert thin(10).tolist() == list(range(10))


def test_live_view_of_a_growing_tlog_sends_the_same_samples(report: Path, tmp_path: Path) -> None:
    from gcs.view.live import LiveView
    from gcs.view.rerun_log import recording

    live = tmp_path / "live"
    live.mkdir()
    for name in ("events.jsonl", "trajectory.json"):
        (live / name).write_bytes((report / name).read_bytes())
    data = (report / "flight.tlog").read_bytes()
    rec = recording("live-test")
    rec.save(str(tmp_path / "live.rrd"))
    view = LiveView(live, rec)
    with (live / "flight.tlog").open("wb") as tlog:
        for cut in (len(data) // 3 + 7, 2 * len(data) // 3 + 1, len(data)):  # cuts mid-record
            tlog.write(data[tlog.tell() : cut])
            tlog.flush()
            view.poll()
    rec.flush()
    rec.disconnect()
    rows_live, rows_file = _rows(tmp_path / "live.rrd"), _rows(report / "flight.rrd")
    t_live, pos_live = _drone_positions(rows_live["/swarm/drones"])
    t_file, pos_file = _drone_positions(rows_file["/swarm/drones"])
    assert t_live.size == t_file.size - 1  # the last sample waits for the next one
    np.testing.assert_allclose(t_live, t_file[:-1])
    np.testing.assert_allclose(pos_live, pos_file[:-1])
    links_live, links_file = _links_drawn(rows_live), _links_drawn(rows_file)
    assert len(links_live) >= len(links_file) - 1
    assert all(links_live[t] == links_file[t] for t in links_live)  # the same links


def _free_tcp_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _serve(command: str, report: Path, log: Path, *flags: str) -> subprocess.Popen[bytes]:
    """``swarm replay`` or ``swarm view`` of ``report`` on free ports (its output in ``log``)."""
    web, grpc = _free_tcp_port(), _free_tcp_port()
    with log.open("wb") as f:
        return subprocess.Popen(
            swarm_command(command, str(report), "--web-port", str(web), "--grpc-port", str(grpc),
                          "--duration-s", "300", *flags),
            stdout=f, stderr=subprocess.STDOUT, env=ENV, cwd=ROOT,
        )  # fmt: skip


def _viewer_url(proc: subprocess.Popen[bytes], log: Path) -> str:
    """The web viewer's URL ``swarm replay`` or ``swarm view`` printed into ``log``."""
    deadline = time.monotonic() + 30
    while "web viewer at" not in log.read_text() and time.monotonic() < deadline:
        assert proc.poll() is None, log.read_text()
        time.sleep(0.1)
    url = log.read_text().split("web viewer at ", 1)[1].split()[0]
    assert url.startswith("http://127.0.0.1:") and "/?url=rerun+http://127.0.0.1:" in url
    return url


@pytest.fixture(scope="module")
def replay_url(report: Path, tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """``swarm replay`` of the report on free ports (the swarm layout, the default), running
    while the module's tests use it; the web viewer's URL it printed."""
    log = tmp_path_factory.mktemp("replay") / "replay.out"
    proc = _serve("replay", report, log)
    try:
        yield _viewer_url(proc, log)
    finally:
        proc.terminate()
        proc.wait(15)


def test_replay_serves_the_web_viewer(replay_url: str) -> None:
    with urllib.request.urlopen(replay_url, timeout=10) as page:
        assert page.status == 200 and b"<html" in page.read().lower()


def _near(pixels: np.ndarray, rgb: tuple[int, int, int], tol: int) -> np.ndarray:
    return np.asarray(np.abs(pixels - np.array(rgb)).max(axis=2) <= tol)


@dataclass
class ViewerShot:
    """What a screenshot of the viewer shows: the pixels, the share of the window of the view
    that holds the drones and of the largest view, and how many plots (other views) show both
    the true value and the agents' estimates."""

    pixels: np.ndarray
    drones: int = 0
    links: int = 0
    swarm_share: float = 0.0
    largest_share: float = 0.0
    plots_with_estimates: int = 0
    full_width_below: bool = False

    @staticmethod
    def of(pixels: np.ndarray) -> ViewerShot:
        from headless_chromium import panes

        from gcs.view.rerun_log import LINK_BOTH_RGB, MODE_RGB
        from gcs.view.rerun_series import ACTUAL_RGB, ESTIMATE_RGB
        from gcs.view.scene import Mode

        shot = ViewerShot(pixels)
        green = _near(pixels, MODE_RGB[Mode.FLYING], 12)
        shot.drones = int(green.sum())
        shot.links = int(_near(pixels, LINK_BOTH_RGB, 20).sum())
        if not shot.drones:
            return shot
        labels = panes(pixels)
        areas = np.bincount(labels.ravel())
        areas[0] = 0
        window = labels.size
        swarm = int(np.bincount(labels[green], minlength=areas.size)[1:].argmax()) + 1
        shot.swarm_share = areas[swarm] / window
        shot.largest_share = areas.max() / window
        true = np.bincount(labels[_near(pixels, ACTUAL_RGB, 12)], minlength=areas.size)
        agents = np.bincount(labels[_near(pixels, ESTIMATE_RGB, 25)], minlength=areas.size)
        plots = (true >= 10) & (agents >= 10)
        plots[[0, swarm]] = False
        shot.plots_with_estimates = int(plots.sum())
        bottom = int(np.nonzero(labels == swarm)[0].max())
        below = np.unique(labels[min(bottom + 4, labels.shape[0] - 1), :])
        shot.full_width_below = any(
            np.ptp(np.nonzero(labels == k)[1]) >= 0.95 * labels.shape[1] for k in below if k
        )
        return shot

    def layout_ok(self) -> bool:
        return (
            self.drones >= 20 and self.links >= 100 and self.swarm_share >= self.largest_share
            and self.swarm_share > 0.3 and self.plots_with_estimates >= 3 and self.full_width_below
        )  # fmt: skip


#: How long a screenshot test waits for the viewer to draw (s): it draws in ~10 s on 2 idle
#: cores, SwiftShader being much slower when other tests load the machine.
SHOT_WAIT_S = 120.0


def _screenshot(url: str, profile: Path, until: Callable[[ViewerShot], bool]) -> ViewerShot:
    """The viewer at ``url`` in headless Chromium (1280 x 800), once ``until`` holds of its
    screenshot or after :data:`SHOT_WAIT_S`; saved as ``profile``.png to look at."""
    from headless_chromium import HeadlessChromium, chromium, why_not
    from PIL import Image

    executable = chromium()
    if executable is None:
        pytest.skip(f"the viewer's screenshot is not checked here: {why_not()}")
    with HeadlessChromium(executable, url, profile) as browser:
        deadline = time.monotonic() + SHOT_WAIT_S
        while True:
            shot = ViewerShot.of(browser.screenshot())
            if until(shot) or time.monotonic() > deadline:
                break
            time.sleep(1.0)
    Image.fromarray(shot.pixels.astype(np.uint8)).save(profile.with_suffix(".png"))
    return shot


@pytest.mark.timeout(240)
def test_headless_chromium_shows_the_swarm_layout(replay_url: str, tmp_path: Path) -> None:
    """The served web viewer, loaded by headless Chromium (software WebGL), draws the flight on
    the swarm layout: within SHOT_WAIT_S its screenshot holds the flying drones' colour and the
    links' colour, which only the recording brings (the viewer's own UI is grey and blue); the
    view that holds the drones is the largest (the views cut apart at their borders) and over
    30 % of the window, at least three plots beside it show the true value and the agents'
    estimates together, and a view as wide as the window lies under it (the events). Skipped,
    saying why, where no Chromium is installed (``make test`` installs Debian's package as
    root: tests/headless_chromium.py)."""
    shot = _screenshot(replay_url, tmp_path / "swarm", ViewerShot.layout_ok)
    where = tmp_path / "swarm.png"
    assert shot.pixels.shape[1] == 1280
    assert np.unique(shot.pixels.reshape(-1, 3), axis=0).shape[0] > 500  # a UI, not a blank page
    assert shot.drones >= 20, f"no drones drawn after {SHOT_WAIT_S:.0f} s: {where}"
    assert shot.links >= 100, f"no links drawn after {SHOT_WAIT_S:.0f} s: {where}"
    assert shot.swarm_share >= shot.largest_share and shot.swarm_share > 0.3, (shot, where)
    assert shot.plots_with_estimates >= 3, (shot.plots_with_estimates, where)
    assert shot.full_width_below, f"no full-width view under the 3-D view: {where}"


def _auto_settled(shot: ViewerShot) -> bool:
    """Rerun's layout has its tiles: it opens on the 3-D view alone while the data loads."""
    return shot.drones >= 10 and 0.0 < shot.swarm_share < 0.15


@pytest.mark.timeout(240)
def test_layout_auto_leaves_it_to_rerun(report: Path, tmp_path: Path) -> None:
    """``swarm replay --layout auto``: Rerun's own layout, where the 3-D swarm is one tile among
    many (so the layout test above can fail)."""
    log = tmp_path / "replay.out"
    proc = _serve("replay", report, log, "--layout", "auto")
    try:
        url = _viewer_url(proc, log)
        shot = _screenshot(url, tmp_path / "auto", _auto_settled)
    finally:
        proc.terminate()
        proc.wait(15)
    assert shot.drones >= 10, f"no drones drawn after {SHOT_WAIT_S:.0f} s: {tmp_path / 'auto.png'}"
    assert shot.swarm_share < 0.15 and shot.largest_share > shot.swarm_share, shot


@pytest.mark.timeout(240)
def test_live_view_opens_on_the_swarm_layout(report: Path, tmp_path: Path) -> None:
    """``swarm view`` (as ``swarm up --view`` runs it) of a report folder: the same layout as
    the replay's, the drones in the largest view, the plots with the agents' estimates."""
    log = tmp_path / "view.out"
    proc = _serve("view", report, log)
    try:
        url = _viewer_url(proc, log)
        shot = _screenshot(url, tmp_path / "live", ViewerShot.layout_ok)
    finally:
        proc.terminate()
        proc.wait(15)
    where = tmp_path / "live.png"
    assert shot.drones >= 20 and shot.links >= 100, (
        f"no swarm drawn after {SHOT_WAIT_S:.0f} s: {where}"
    )
    assert shot.swarm_share >= shot.largest_share and shot.swarm_share > 0.3, (shot, where)
    assert shot.plots_with_estimates >= 3 and shot.full_width_below, (shot, where)


def test_view_help(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_info:
        main(["view", "--help"])
    assert exit_info.value.code == 0
    text = capsys.readouterr().out
    assert "report folder" in text and "--web-port" in text and "quadswarm[view]" in text


@pytest.mark.parametrize("command", ["view", "replay"])
def test_without_rerun_the_view_commands_say_how_to_install_it(
    command: str,
    report: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    real = importlib.util.find_spec
    monkeypatch.setattr(
        recording_module.importlib.util,
        "find_spec",
        lambda name, *a: None if name == "rerun" else real(name, *a),
    )
    assert main([command, str(report)]) == 2
    err = capsys.readouterr().err
    assert f"swarm {command}: the Rerun viewer is not installed" in err
    assert "pip install 'quadswarm[view]'" in err
    assert recording_module.write_recording(report) is None  # the reports go on without it


def test_nothing_else_imports_rerun() -> None:
    code = (
        "import sys, gcs.cli.main, gcs.reference.simulate, gcs.station.ground_station, "
        "gcs.report.from_logs, gcs.cli.view, "
        "sitl_sim.server, drone_agent.process.agent_cli; "
        "sys.exit(1 if any(m == 'rerun' or m.startswith('rerun.') for m in sys.modules) else 0)"
    )
    assert subprocess.run([sys.executable, "-c", code], env=ENV, cwd=ROOT).returncode == 0


@pytest.mark.slow
def test_swarm_up_view_serves_the_live_viewer(tmp_path: Path) -> None:
    """``swarm up --view`` on free ports: it prints the viewer's URL, the page is served while
    the swarm flies, and the viewer ends with the run."""
    from sitl_client import free_port_block, free_udp_port

    scenario = write_scenario(
        tmp_path / "hover.toml", SQUARE, centre=(2.0, 1.5, -2.0), spread=(2.0, 1.5, 0.0),
        duration_s=8.0,
    )  # fmt: skip
    web, grpc = _free_tcp_port(), _free_tcp_port()
    out = tmp_path / "up.out"
    report = tmp_path / "report"
    with out.open("wb") as f:
        proc = subprocess.Popen(
            swarm_command("up", str(scenario), "--report", str(report), "--base-port",
                          str(free_port_block(4)), "--gcs-port", str(free_udp_port()), "--view",
                          "--view-web-port", str(web), "--view-grpc-port", str(grpc)),
            stdout=f, stderr=subprocess.STDOUT, env=ENV, cwd=ROOT,
        )  # fmt: skip
    try:
        deadline = time.monotonic() + 60
        while "live view (Rerun) at" not in out.read_text() and time.monotonic() < deadline:
            assert proc.poll() is None, out.read_text()
            time.sleep(0.2)
        url = out.read_text().split("live view (Rerun) at ", 1)[1].split()[0]
        with urllib.request.urlopen(url, timeout=10) as page:
            assert page.status == 200
        assert proc.wait(120) == 0, out.read_text()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)
    assert "swarm up: finished" in out.read_text()
    assert (report / "flight.rrd").exists()
    # the ground station logged each agent's integrated neighbours (sent in its Zenoh status)
    track = read_tlog(report / "flight.tlog")
    for v in track.vehicles.values():
        assert v.status_t_s.size and (v.status_layout == 1).all()
        counts = [len(v.neighbour_ids(k) or ()) for k in range(v.status_t_s.size)]
        assert counts == v.status[:, 9].tolist() and max(counts) == 3
    drawn = _links_drawn(_rows(report / "flight.rrd"))
    assert max(len(pairs) for pairs in drawn.values()) == 6  # every pair of the four
    assert "swarm view: following" in (report / "logs" / "view.log").read_text()
    with socket.socket() as s:  # the viewer has ended: its port is free again
        s.bind(("127.0.0.1", web))


# -- the scene's arithmetic, without Rerun's I/O ---------------------------------------------
@pytest.mark.parametrize("euler", [(0.0, 0.0, 1.2), (0.3, -0.2, 2.9), (-0.5, 0.4, -1.0)])
def test_ellipsoid_quaternion_is_the_descriptor_orientation(euler: tuple[float, ...]) -> None:
    from gcs.view.rerun_log import quaternions_xyzw
    from protocols.model.frames import rot_zyx

    x, y, z, w = quaternions_xyzw(np.array([euler]))[0]
    rot = np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])  # fmt: skip
    roll, pitch, yaw = euler
    np.testing.assert_allclose(rot, rot_zyx(yaw, pitch, roll), atol=1e-12)


def test_min_separation_and_modes() -> None:
    from gcs.view.scene import Mode, event_lines, min_separation, modes

    rng = np.random.default_rng(3)
    pos = rng.normal(size=(20, 5, 3)) * 3
    air = rng.random((20, 5)) > 0.3
    got = min_separation(pos, air)
    for k in range(20):
        d = [np.linalg.norm(pos[k, i] - pos[k, j]) for i in range(5) for j in range(i + 1, 5)
             if air[k, i] and air[k, j]]  # fmt: skip
        assert (np.isnan(got[k]) and not d) or got[k] == pytest.approx(min(d))
    t = np.arange(10.0)
    record = type("R", (), {})()
    record.t_s, record.airborne, record.n_drones = t, np.ones((10, 2), dtype=bool), 2
    record.lost_at_s = {1: 6.0}
    events = [
        {"t_s": 4.0, "kind": "failsafe", "drone": 0},
        {"t_s": 6.0, "kind": "crash", "drone": 1},
    ]
    mode = modes(record, events)
    assert mode[3].tolist() == [Mode.FLYING, Mode.FLYING]
    assert mode[5].tolist() == [Mode.FAILSAFE, Mode.FLYING]
    assert mode[7].tolist() == [Mode.FAILSAFE, Mode.LOST]
    lines = event_lines(events)
    assert [(e.level, e.text) for e in lines] == [
        ("WARN", "drone 0 failsafe"),
        ("ERROR", "drone 1 crash"),
    ]
