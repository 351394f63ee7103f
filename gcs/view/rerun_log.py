"""A :class:`~gcs.view.scene.Scene` into Rerun: the recording (``flight.rrd``) and the live view.

Imports ``rerun`` (the optional extra ``quadswarm[view]``): only the view commands and, when it is
installed, the report writers (:mod:`gcs.view.recording`) import this module.

Entities, on the timeline ``sim_time`` (simulated seconds), world frame NED (Rerun's FRD):

- ``swarm/drones``: every drone as a point labelled with its system id, coloured by
  :class:`~gcs.view.scene.Mode` (grey on the ground, green flying, orange fail-safe, red lost);
  ``swarm/trails``: the last :data:`TRAIL_S` seconds of each drone's path;
- ``swarm/formation/commanded`` and ``swarm/formation/actual``: the commanded and the true swarm
  ellipsoid (centre, heading, half-axes the spreads ``sqrt(variance)``, 1 sigma);
  ``swarm/formation/commanded_axes``: the commanded formation's frame, three arrows from its
  centre along its length, width and height axes (red, green, blue), each as long as that spread
  (at least :data:`AXIS_MIN_M`);
  ``swarm/estimates``: each agent's estimate of the centre;
- ``swarm/links``: the radio links that integrated (:func:`gcs.view.scene.link_pairs`), one
  segment per linked pair between the two drones, blue where both directions integrated, yellow
  where one did; drawn on the trails' rows (:data:`TRAIL_HZ`), at most :data:`MAX_LINKS` per row
  (a larger swarm's links evenly thinned, e.g. 250 drones in range of 20 each: ~2,500 links), with
  ``links/pairs`` their full count;
- ``events``: every event of events.jsonl as a text log line;
- the time series of :mod:`gcs.view.rerun_series`: each descriptor's command, true value and
  agents' estimates, the angles' errors, separation, consensus error, neighbours.

Everything is sent as columns (:func:`rerun.send_columns`): one call per entity and batch. The
recording carries the layout of :mod:`gcs.view.layout` as its default blueprint.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import numpy.typing as npt
import rerun as rr

from gcs.view.layout import LAYOUTS, blueprint, layout_blueprint
from gcs.view.rerun_series import (
    ACTUAL_RGB,
    ESTIMATE_RGB,
    TIMELINE,
    log_series,
    log_series_setup,
    scalar_series,
)
from gcs.view.scene import Mode, Scene, link_pairs
from protocols.model.frames import FloatArray, rot_zyx_batch

APP_ID = "quadswarm"
TRAIL_S = 2.0
#: At most this many trail rows and trail points per second of flight.
TRAIL_HZ = 10.0
MODE_RGB = {
    Mode.GROUND: (150, 150, 150),
    Mode.FLYING: (40, 180, 80),
    Mode.FAILSAFE: (255, 150, 0),
    Mode.LOST: (220, 40, 40),
}
_COMMANDED_RGB, _ACTUAL_RGB = (160, 160, 160), ACTUAL_RGB
#: The commanded frame's arrows: length, width and height axes; the shortest drawn (m).
AXIS_RGB = ((230, 50, 50), (50, 190, 60), (60, 90, 240))
AXIS_MIN_M = 0.5
#: At most this many links drawn per row (each two points; 1.5 UI points wide at any zoom): the
#: 250-drone scenario's ~1,700 links thinned, its flight.rrd 19 MB instead of 16 MB without links.
MAX_LINKS = 600
LINK_BOTH_RGB, LINK_ONE_WAY_RGB = (90, 170, 255), (240, 210, 40)
#: Link rows worked out at once (bounds the (rows, N, K) neighbour ids held).
_LINK_BATCH = 64
_PALETTE = np.array([MODE_RGB[m] for m in Mode], dtype=np.uint8)


def recording(recording_id: str) -> rr.RecordingStream:
    """A new recording of the application ``quadswarm`` (not the global one)."""
    return rr.RecordingStream(APP_ID, recording_id=recording_id)


def write_rrd(scene: Scene, path: Path, recording_id: str) -> Path:
    """Write ``scene`` to the Rerun recording ``path`` (a .rrd file), the swarm layout its
    default blueprint."""
    rec = recording(recording_id)
    rec.save(str(path), default_blueprint=blueprint())
    log_setup(rec, scene.n_drones)
    log_scene(rec, scene)
    rec.flush()
    rec.disconnect()
    return path


def log_setup(rec: rr.RecordingStream, n_drones: int) -> None:
    """The static parts: the NED frame and the series' names and colours."""
    rec.log("swarm", rr.ViewCoordinates.FRD, static=True)
    log_series_setup(rec, n_drones)


def log_scene(rec: rr.RecordingStream, scene: Scene, start: int = 0, events_from: int = 0) -> None:
    """Send the samples ``start:`` and the events ``events_from:`` of ``scene``."""
    t = scene.t_s[start:]
    if t.size:
        _drones(rec, scene, start)
        _trails(rec, scene, start)
        _links(rec, scene, start)
        _formations(rec, scene, start)
        log_series(rec, scene, start, _trail_rows(scene, start)[0])
    events = scene.events[events_from:]
    if events:
        rec.send_columns(
            "events",
            indexes=[rr.TimeColumn(TIMELINE, duration=[e.t_s for e in events])],
            columns=rr.TextLog.columns(
                text=[e.text for e in events], level=[e.level for e in events]
            ),
        )


def _index(t_s: FloatArray) -> list[rr.TimeColumn]:
    return [rr.TimeColumn(TIMELINE, duration=np.asarray(t_s, dtype=float))]


def _drones(rec: rr.RecordingStream, scene: Scene, start: int) -> None:
    pos = scene.position_ned_m[start:]
    seen = np.isfinite(pos[..., 0])
    k, i = np.nonzero(seen)
    colours = _PALETTE[scene.mode[start:][k, i]]
    rec.send_columns(
        "swarm/drones",
        indexes=_index(scene.t_s[start:]),
        columns=rr.Points3D.columns(
            positions=pos[k, i],
            colors=colours,
            labels=[str(j + 1) for j in i],
            radii=[0.15] * k.size,
        ).partition(seen.sum(axis=1)),
    )
    est = scene.estimate_centre_ned_m[start:]
    known = np.isfinite(est).all(axis=-1)
    rec.send_columns(
        "swarm/estimates",
        indexes=_index(scene.t_s[start:]),
        columns=rr.Points3D.columns(
            positions=est[known],
            colors=[ESTIMATE_RGB] * int(known.sum()),
            radii=[0.06] * int(known.sum()),
        ).partition(known.sum(axis=1)),
    )


def trail_stride(t_s: FloatArray) -> tuple[int, int]:
    """For samples at times ``t_s``: every how many samples a trail is drawn and a trail point
    taken, and how many points a trail has."""
    dt = float(np.median(np.diff(t_s))) if t_s.size > 1 else 1.0
    stride = max(1, round(1.0 / (TRAIL_HZ * dt)))
    return stride, max(2, round(TRAIL_S / (dt * stride)) + 1)


def _trail_rows(scene: Scene, start: int) -> tuple[np.ndarray, int, int]:
    """Sample indices (from ``start``) that get a trail, the trail's stride and its length."""
    t = scene.t_s
    stride, length = trail_stride(t)
    first = start + (-start) % stride
    return np.arange(first, t.size, stride), stride, length


def _trails(rec: rr.RecordingStream, scene: Scene, start: int) -> None:
    rows, stride, length = _trail_rows(scene, start)
    if rows.size == 0:
        return
    strips: list[FloatArray] = []
    counts: list[int] = []
    colours: list[tuple[int, int, int]] = []
    pos = scene.position_ned_m
    for k in rows:
        window = pos[max(0, k - stride * (length - 1)) : k + 1 : stride]
        n_row = 0
        for i in range(scene.n_drones):
            path = window[:, i]
            path = path[np.isfinite(path[:, 0])]
            if path.shape[0] >= 2:
                strips.append(path)
                colours.append(MODE_RGB[Mode(int(scene.mode[k, i]))])
                n_row += 1
        counts.append(n_row)
    rec.send_columns(
        "swarm/trails",
        indexes=_index(scene.t_s[rows]),
        columns=rr.LineStrips3D.columns(strips=strips, colors=colours, radii=[0.02] * len(strips))
        .partition(counts),
    )  # fmt: skip


def thin(n_links: int, cap: int = MAX_LINKS) -> npt.NDArray[np.int64]:
    """Which of ``n_links`` links are drawn: all up to ``cap``, else ``cap`` evenly spread."""
    if n_links <= cap:
        return np.arange(n_links)
    return np.floor(np.arange(cap) * (n_links / cap)).astype(np.int64)


def _links(rec: rr.RecordingStream, scene: Scene, start: int) -> None:
    rows, _, _ = _trail_rows(scene, start)
    if scene.links is None or rows.size == 0:
        return
    for b in range(0, rows.size, _LINK_BATCH):
        batch = rows[b : b + _LINK_BATCH]
        ids = scene.links.integrated(scene.t_s[batch])
        strips: list[FloatArray] = []
        colours: list[tuple[int, int, int]] = []
        counts: list[int] = []
        totals: list[int] = []
        for r, k in enumerate(batch):
            pos = scene.position_ned_m[k]
            pairs, both = link_pairs(ids[r], pos)
            keep = thin(pairs.shape[0])
            strips += list(np.stack([pos[pairs[keep, 0]], pos[pairs[keep, 1]]], axis=1))
            colours += [LINK_BOTH_RGB if x else LINK_ONE_WAY_RGB for x in both[keep]]
            counts.append(keep.size)
            totals.append(pairs.shape[0])
        rec.send_columns(
            "swarm/links",
            indexes=_index(scene.t_s[batch]),
            columns=rr.LineStrips3D.columns(
                strips=strips, colors=colours, radii=[-1.5] * len(strips)
            ).partition(counts),
        )
        scalar_series(rec, "links/pairs", scene.t_s[batch], np.asarray(totals, dtype=float))


def quaternions_xyzw(euler_rad: FloatArray) -> FloatArray:
    """(T, 4) quaternions (x, y, z, w; Rerun's order) of ZYX angles (T, 3) roll, pitch, yaw."""
    half = 0.5 * np.asarray(euler_rad, dtype=float)
    cr, sr = np.cos(half[:, 0]), np.sin(half[:, 0])
    cp, sp = np.cos(half[:, 1]), np.sin(half[:, 1])
    cy, sy = np.cos(half[:, 2]), np.sin(half[:, 2])
    return np.stack(
        [sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy,
         cr * cp * sy - sr * sp * cy, cr * cp * cy + sr * sp * sy],
        axis=1,
    )  # fmt: skip


def _formations(rec: rr.RecordingStream, scene: Scene, start: int) -> None:
    for name, values, colour in (
        ("commanded", scene.desired[start:], _COMMANDED_RGB),
        ("actual", scene.actual[start:], _ACTUAL_RGB),
    ):
        ok = np.isfinite(values).all(axis=1)
        rows = values[ok]
        rec.send_columns(
            f"swarm/formation/{name}",
            indexes=_index(scene.t_s[start:]),
            columns=rr.Ellipsoids3D.columns(
                centers=rows[:, :3],
                half_sizes=np.sqrt(np.maximum(rows[:, 6:9], 0.0)),
                quaternions=quaternions_xyzw(rows[:, 3:6]),
                colors=[colour] * rows.shape[0],
                fill_mode=["MajorWireframe"] * rows.shape[0],
            ).partition(ok.astype(int)),
        )
    _commanded_axes(rec, scene, start)


def formation_axes(descriptors: FloatArray) -> FloatArray:
    """(T, 3, 3) the arrows of the formation frames of ``descriptors`` (T, 9): row j the vector
    along principal axis j (length, width, height; NED, m), as long as that axis's spread
    ``sqrt(variance)`` and at least :data:`AXIS_MIN_M`."""
    rot = rot_zyx_batch(descriptors[:, 5], descriptors[:, 4], descriptors[:, 3])
    length = np.maximum(np.sqrt(np.maximum(descriptors[:, 6:9], 0.0)), AXIS_MIN_M)
    return np.swapaxes(rot, 1, 2) * length[:, :, None]


def _commanded_axes(rec: rr.RecordingStream, scene: Scene, start: int) -> None:
    values = scene.desired[start:]
    ok = np.isfinite(values).all(axis=1)
    rows = values[ok]
    vectors = formation_axes(rows).reshape(-1, 3)
    rec.send_columns(
        "swarm/formation/commanded_axes",
        indexes=_index(scene.t_s[start:]),
        columns=rr.Arrows3D.columns(
            origins=np.repeat(rows[:, :3], 3, axis=0),
            vectors=vectors,
            colors=list(AXIS_RGB) * rows.shape[0],
            radii=[0.03] * vectors.shape[0],
        ).partition(3 * ok.astype(int)),
    )


def serve(rec: rr.RecordingStream, web_port: int, grpc_port: int, layout: str = LAYOUTS[0]) -> str:
    """Serve ``rec`` to a local web viewer, on the swarm layout (or Rerun's with ``layout``
    ``"auto"``); the viewer's URL (open it in a browser)."""
    grpc_url = rec.serve_grpc(grpc_port=grpc_port, default_blueprint=layout_blueprint(layout))
    rr.serve_web_viewer(web_port=web_port, open_browser=False, connect_to=grpc_url)
    return f"http://127.0.0.1:{web_port}/?url={grpc_url}"
