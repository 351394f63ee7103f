"""Run metrics from a FlightRecord, as a JSON-able dict (written as ``metrics.json``). Pure.

Definitions (descriptor order and names from protocols.model.descriptor_vector; errors a − a_ref
with the three angle rows wrapped to [−π, π); "RMS" is sqrt(mean(e²)), "max" is max |e|):

- **True descriptors** ``a_true(t)``: the descriptors (ALGORITHM.md §2) of the drones that are
  members of the swarm at ``t`` (and have a finite position), with the principal axes assigned to
  the desired orientation at ``t``; NaN with fewer than 2 members. Orientation rows are *masked*
  (left out) where the heading is undefined: |s1 − s2|/(s1 + s2) < 0.05 on the true variances.
- **tracking**: per descriptor, RMS and max of |a_true − a_d| over samples with t ≥ ``settle_s``
  (faults included); angles also in degrees, and ``heading_deg``, ``pitch_deg``, ``roll_deg``
  (RMS and max in degrees) beside ``centroid_m``: the Euclidean norm of the centre
  error; ``shape_m2``: at each sample the RMS over the three variance errors; RMS and max over time.
- **tracking_steady**: the same, leaving out ``[t_loss, t_loss + 10 s)`` after each drone lost:
  the steady-state figures (ALGORITHM.md §7 "away from the drop-out"); the transient itself is
  judged by **reconvergence** below and is included in **tracking**. **consensus_steady** likewise.
- **consensus**: for each member agent i and sample t ≥ ``settle_s``, |estimate_i − a_true| per
  descriptor (angles wrapped, heading mask as above); RMS and max over agents and samples; per
  agent the RMS and max of the centroid estimate error and the RMS of the variance estimate errors.
  Member samples with no (NaN) estimate are left out and counted as ``n_missing_estimates``.
- **reconvergence**, per fault (t_f, description): the fault's window runs to the next later fault
  (or the end). The swarm is *converged* at a sample when the centroid tracking error < 0.05 m,
  every variance tracking error < 0.1 m², and every member agent's centroid estimate error
  < 0.05 m and variance estimate errors < 0.1 m² (a missing estimate counts as not converged).
  The re-convergence time is from t_f to the start of the run of converged samples that lasts to
  the window's end, provided that run lasts ≥ min(1 s, the window's length); None otherwise.
  Also the peak centroid and shape (as in tracking) errors in the window.
- **separation**: the minimum distance between two airborne drones (lost drones included while
  airborne) with its time and pair. **collisions**: episodes in which an airborne pair is closer
  than ``collision_distance_m``, counted once per pair per contact (entering contact).
- **rejoins**: per absence a drone came back from (its agent restarted), ``{"index", "sysid",
  "left_s", "back_s", "gap_s"}``; the drone is not a member in between.
- **drones_lost** (index, system id, time), **max_tilt_deg** (angle of the body z axis from the
  vertical, airborne samples), **max_thrust_ratio** (thrust / ``max_thrust_n``, all samples; None
  without ``max_thrust_n``), ``n_samples``, ``duration_s``.
- ``extra`` (run info: real-time factor, wall time, ...) is merged in at the top level.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

from gcs.report.events import jsonable
from gcs.report.flight_record import FlightRecord
from protocols.model.descriptor_vector import (
    CENTRE,
    I_PITCH,
    I_ROLL,
    I_YAW,
    NAMES,
    ORIENTATION,
    SHAPE,
)
from protocols.model.descriptors import (
    HEADING_TIE_RATIO,
    align_axes_batch,
    desired_axes_batch,
    frame_vector_batch,
)
from protocols.model.frames import FloatArray, wrap_pi
from protocols.runtime.compiled import loaded

BoolArray = npt.NDArray[np.bool_]
IntArray = npt.NDArray[np.intp]
CENTROID_TOL_M = 0.05
VARIANCE_TOL_M2 = 0.1
HOLD_S = 1.0
#: After a drone is lost, this long is left out of the steady-state figures (s).
LOSS_WINDOW_S = 10.0
_ANGLE_ROWS = range(ORIENTATION.start, ORIENTATION.stop)
#: :func:`descriptors_of` works on blocks of at most this many positions (samples x drones)
_BLOCK_VALUES = 200_000


def descriptors_of(
    positions_ned_m: FloatArray, member: BoolArray, desired: FloatArray
) -> FloatArray:
    """True descriptors (T, 9) of the members' positions (T, N, 3), axes assigned to ``desired``.

    ``member`` (T, N); ``desired`` (T, 9). NaN rows where fewer than 2 members have a position.
    All samples at once, in blocks of :data:`_BLOCK_VALUES` positions: each sample's centre and
    population covariance over its members (the others weigh nothing), its axes assigned to its
    desired orientation (the world's where that is not finite) as one stacked decomposition.
    """
    t_n = positions_ned_m.shape[0]
    out = np.full((t_n, 9), np.nan)
    ok = member & np.all(np.isfinite(positions_ned_m), axis=2)
    count = ok.sum(axis=1)
    rows = np.flatnonzero(count >= 2)
    step = max(1, _BLOCK_VALUES // max(1, positions_ned_m.shape[1]))
    for start in range(0, rows.size, step):
        r = rows[start : start + step]
        w = ok[r][:, :, None]
        x = np.where(w, positions_ned_m[r], 0.0)
        c = count[r].astype(float)
        mu = x.sum(axis=1) / c[:, None]
        p = np.where(w, x - mu[:, None, :], 0.0)
        sigma = np.einsum("tni,tnj->tij", p, p) / c[:, None, None]
        d = desired[r]
        axes_d = np.broadcast_to(np.eye(3), (r.size, 3, 3)).copy()
        finite = np.all(np.isfinite(d), axis=1)
        if finite.any():
            axes_d[finite] = desired_axes_batch(d[finite])
        axes, s = align_axes_batch(sigma, axes_d, compiled=loaded())
        out[r] = frame_vector_batch(mu, axes, s)
    return out


def true_descriptors(record: FlightRecord) -> FloatArray:
    """True descriptors (T, 9) of the record's member drones; NaN where fewer than 2 members."""
    return descriptors_of(record.position_ned_m, record.member, record.desired)


def heading_mask(a_true: FloatArray) -> BoolArray:
    """(T,) True where the heading of ``a_true`` (T, 9) is defined (and the row finite): the
    rule of :func:`~protocols.model.descriptors.heading_defined`, over every row at once."""
    shape = a_true[:, SHAPE]
    s1, s2 = shape[:, 0], shape[:, 1]
    with np.errstate(invalid="ignore"):
        defined = np.abs(s1 - s2) >= HEADING_TIE_RATIO * np.maximum(s1 + s2, 1e-12)
    return np.all(np.isfinite(shape), axis=1) & defined


def descriptor_errors(a: FloatArray, ref: FloatArray, heading_ok: BoolArray) -> FloatArray:
    """``a - ref`` (T, 9) or (T, N, 9); angles wrapped, orientation NaN where not ``heading_ok``."""
    e = np.asarray(a - ref, dtype=float)
    ok = heading_ok.reshape((-1,) + (1,) * (e.ndim - 1))
    e[..., ORIENTATION] = np.where(ok, wrap_pi(e[..., ORIENTATION]), np.nan)
    return e


def _stat(err: FloatArray, t_s: FloatArray | None = None, deg: bool = False) -> dict[str, Any]:
    """RMS and max of |err| over its finite entries (K,) or (K, N); time of the max if ``t_s``."""
    x = np.abs(np.asarray(err, dtype=float))
    ok = np.isfinite(x)
    n = int(ok.sum())
    out: dict[str, Any] = {"rms": None, "max": None, "n": n}
    if n:
        flat = np.where(ok, x, -np.inf)
        out["rms"] = float(np.sqrt(np.mean(x[ok] ** 2)))
        out["max"] = float(flat.max())
        if t_s is not None:
            out["t_max_s"] = float(t_s[np.unravel_index(np.argmax(flat), x.shape)[0]])
        if deg:
            out["rms_deg"], out["max_deg"] = np.degrees(out["rms"]), np.degrees(out["max"])
    return out


def _centroid_shape(e: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Centroid error norm and RMS-over-variances shape error of errors (..., 9)."""
    return np.linalg.norm(e[..., CENTRE], axis=-1), np.sqrt(np.mean(e[..., SHAPE] ** 2, axis=-1))


def outside(t_s: FloatArray, windows: Sequence[tuple[float, float]]) -> BoolArray:
    """True for samples outside every ``[t0, t1)`` window."""
    keep = np.ones(t_s.shape, dtype=bool)
    for t0, t1 in windows:
        keep &= (t_s < t0) | (t_s >= t1)
    return keep


def loss_windows(
    record: FlightRecord, window_s: float = LOSS_WINDOW_S
) -> list[tuple[float, float]]:
    """``[t_loss, t_loss + window_s)`` for each drone lost: the transient left out of the
    steady-state figures (and judged by the re-convergence metric instead)."""
    return [(t, t + window_s) for t in sorted(record.lost_at_s.values())]


def tracking_errors(
    t_s: FloatArray,
    a_true: FloatArray,
    desired: FloatArray,
    settle_s: float,
    exclude: Sequence[tuple[float, float]] = (),
) -> dict[str, Any]:
    """Tracking metrics (see module doc) of true descriptors (T, 9) against ``desired`` (T, 9),
    over samples after ``settle_s`` and outside the ``exclude`` windows."""
    after = (t_s >= settle_s) & np.all(np.isfinite(a_true), axis=1) & outside(t_s, exclude)
    e = descriptor_errors(a_true, desired, heading_mask(a_true))[after]
    t = t_s[after]
    centroid, shape = _centroid_shape(e)
    return {
        "settle_s": float(settle_s),
        "excluded_windows_s": [list(w) for w in exclude],
        "n_samples": int(after.sum()),
        "descriptors": {
            name: _stat(e[:, k], t, deg=k in _ANGLE_ROWS) for k, name in enumerate(NAMES)
        },
        "centroid_m": _stat(centroid, t),
        "shape_m2": _stat(shape, t),
        # the formation's orientation beside centroid and shape, in degrees (issue 15)
        **{
            f"{name}_deg": _stat(np.degrees(e[:, k]), t)
            for name, k in (("heading", I_YAW), ("pitch", I_PITCH), ("roll", I_ROLL))
        },
    }


def tracking_from_positions(
    t_s: FloatArray,
    positions_ned_m: FloatArray,
    member: BoolArray,
    desired: FloatArray,
    settle_s: float,
    exclude: Sequence[tuple[float, float]] = (),
) -> dict[str, Any]:
    """Tracking metrics from positions (T, N, 3) (e.g. resampled from a tlog), ``member`` (T, N)."""
    a_true = descriptors_of(positions_ned_m, member, desired)
    return tracking_errors(t_s, a_true, desired, settle_s, exclude)


def consensus_errors(
    t_s: FloatArray,
    a_true: FloatArray,
    estimate: FloatArray,
    member: BoolArray,
    settle_s: float,
    exclude: Sequence[tuple[float, float]] = (),
) -> dict[str, Any]:
    """Consensus metrics (see module doc): ``estimate`` (T, N, 9) against ``a_true`` (T, 9),
    after ``settle_s`` and outside the ``exclude`` windows."""
    when = (t_s >= settle_s) & outside(t_s, exclude) & np.all(np.isfinite(a_true), axis=1)
    use = member & when[:, None]
    have = np.all(np.isfinite(estimate[..., CENTRE]), axis=-1) & np.all(
        np.isfinite(estimate[..., SHAPE]), axis=-1
    )
    e = descriptor_errors(estimate, a_true[:, None, :], heading_mask(a_true))
    e[~(use & have)] = np.nan
    centroid, shape = _centroid_shape(e)
    per_agent = [
        {
            "index": i,
            "sysid": i + 1,
            "centroid_rms_m": _stat(centroid[:, i])["rms"],
            "centroid_max_m": _stat(centroid[:, i])["max"],
            "shape_rms_m2": _stat(shape[:, i])["rms"],
        }
        for i in range(estimate.shape[1])
    ]
    return {
        "settle_s": float(settle_s),
        "n_missing_estimates": int((use & ~have).sum()),
        "descriptors": {
            name: _stat(e[..., k], t_s, deg=k in _ANGLE_ROWS) for k, name in enumerate(NAMES)
        },
        "centroid_m": _stat(centroid, t_s),
        "shape_m2": _stat(shape, t_s),
        "per_agent": per_agent,
    }


def converged_mask(
    a_true: FloatArray,
    desired: FloatArray,
    estimate: FloatArray,
    member: BoolArray,
    centroid_tol_m: float = CENTROID_TOL_M,
    variance_tol_m2: float = VARIANCE_TOL_M2,
) -> BoolArray:
    """(T,) the re-convergence condition of the module doc at each sample."""
    with np.errstate(invalid="ignore"):
        e = a_true - desired
        ok = (np.linalg.norm(e[:, CENTRE], axis=1) < centroid_tol_m) & np.all(
            np.abs(e[:, SHAPE]) < variance_tol_m2, axis=1
        )
        est = estimate - a_true[:, None, :]
        agent_ok = (np.linalg.norm(est[..., CENTRE], axis=-1) < centroid_tol_m) & np.all(
            np.abs(est[..., SHAPE]) < variance_tol_m2, axis=-1
        )
    return np.asarray(ok & np.all(agent_ok | ~member, axis=1), dtype=bool)


def reconvergence(
    t_s: FloatArray,
    a_true: FloatArray,
    desired: FloatArray,
    estimate: FloatArray,
    member: BoolArray,
    faults: Sequence[tuple[float, str]],
    hold_s: float = HOLD_S,
) -> list[dict[str, Any]]:
    """Re-convergence after each fault (see module doc), in time order."""
    conv = converged_mask(a_true, desired, estimate, member)
    centroid, shape = _centroid_shape(a_true - desired)
    dt = float(np.median(np.diff(t_s))) if t_s.size > 1 else 0.0
    ordered = sorted(faults, key=lambda f: f[0])
    out: list[dict[str, Any]] = []
    for t_f, description in ordered:
        later = [f[0] for f in ordered if f[0] > t_f]
        t_end = later[0] if later else np.inf
        idx = np.flatnonzero((t_s >= t_f) & (t_s < t_end))
        item: dict[str, Any] = {"t_s": float(t_f), "description": description}
        item["window_end_s"] = float(min(t_end, t_s[-1] + dt)) if t_s.size else None
        item["time_to_reconverge_s"] = None
        item["peak_centroid_error_m"] = _stat(centroid[idx])["max"]
        item["peak_shape_error_m2"] = _stat(shape[idx])["max"]
        if idx.size:
            bad = np.flatnonzero(~conv[idx])
            start = int(bad[-1]) + 1 if bad.size else 0
            run_s = (idx.size - start) * dt
            if start < idx.size and run_s >= min(hold_s, idx.size * dt) - 1e-9:
                item["time_to_reconverge_s"] = float(t_s[idx[start]] - t_f)
        out.append(item)
    return out


def separation(
    t_s: FloatArray,
    positions_ned_m: FloatArray,
    airborne: BoolArray,
    collision_distance_m: float = 0.3,
    max_listed: int = 100,
    chunk_samples: int | None = None,
) -> tuple[dict[str, Any], dict[str, Any]]:
    """Minimum separation of airborne pairs and collision episodes (see module doc).

    ``positions_ned_m`` (T, N, 3), ``airborne`` (T, N). Returns ``(separation, collisions)``;
    pairs are drone indices (i < j); at most ``max_listed`` episodes are listed (all are counted).
    Time is processed in chunks of ``chunk_samples`` (default: up to 25, about 1e6 pair
    coordinates); in each, only the pairs that can be the closest or collide are measured
    (:func:`_near_pairs`), with the arithmetic of all of them: the same bits, ties and order.
    """
    n = positions_ned_m.shape[1]
    best: dict[str, Any] = {"min_m": None, "t_s": None, "pair": None}
    episodes: list[dict[str, Any]] = []
    if n < 2 or t_s.size == 0:
        return best, {"distance_m": collision_distance_m, "count": 0, "episodes": episodes}
    # the pairs i < j in row order: (T, pairs) arrays, the order an (T, N, N) argmin or argwhere
    # over the upper triangle visits them in (ties and episodes listed as they were)
    first, second = np.triu_indices(n, k=1)
    prev = np.zeros(first.shape[0], dtype=bool)
    count = 0
    chunk = chunk_samples or max(1, min(25, 1_000_000 // max(1, first.shape[0] * 3)))
    for k0 in range(0, t_s.shape[0], chunk):
        x = positions_ned_m[k0 : k0 + chunk]
        air = airborne[k0 : k0 + chunk]
        near, bound = _near_pairs(x, air, first, second, collision_distance_m)
        d = _pair_distances(x, air, first[near], second[near])
        if near.size and not (d <= bound).any():  # no measured pair proved the bound: all
            near = np.arange(first.shape[0])
            d = _pair_distances(x, air, first, second)
        if near.size:
            k, p = np.unravel_index(np.argmin(d), d.shape)
            if np.isfinite(d[k, p]) and (best["min_m"] is None or d[k, p] < best["min_m"]):
                q = int(near[p])
                pair = [int(first[q]), int(second[q])]
                best = {"min_m": float(d[k, p]), "t_s": float(t_s[k0 + k]), "pair": pair}
        close = d < collision_distance_m
        rising = close & ~np.concatenate([prev[near][None], close[:-1]])
        prev[:] = False  # a pair left out is nowhere near colliding in this chunk
        prev[near] = close[-1]
        count += int(rising.sum())
        for k, p in np.argwhere(rising)[: max(0, max_listed - len(episodes))]:
            q = int(near[p])
            episodes.append({"t_s": float(t_s[k0 + k]), "pair": [int(first[q]), int(second[q])]})
    collisions = {"distance_m": collision_distance_m, "count": count, "episodes": episodes}
    return best, collisions


def _pair_distances(x: FloatArray, air: BoolArray, first: IntArray, second: IntArray) -> FloatArray:
    """(T, pairs) distances of the pairs, inf where a pair is not both airborne and known."""
    diff = x[:, first] - x[:, second]
    # np.linalg.norm's own arithmetic (the sum of the squares, then its root): its bits
    d = np.sqrt(np.add.reduce(diff * diff, axis=-1))
    valid = air[:, first] & air[:, second] & np.isfinite(d)
    return np.where(valid, d, np.inf)


#: Slack (m) on the bound of :func:`_near_pairs` against rounding: a pair left out is farther
#: than the bound by more than this, so never the closest pair, tied with it or colliding.
_BOUND_SLACK_M = 1e-6


def _near_pairs(
    x: FloatArray, air: BoolArray, first: IntArray, second: IntArray, collision_m: float
) -> tuple[IntArray, float]:
    """The pairs (indices into ``first``/``second``, ascending) that may come within a bound of
    each other in the chunk ``x`` (T, N, 3), and that bound (m).

    Each drone's samples where it is airborne and known lie in a box: within half its diagonal
    of its centre. At every sample where both are, two drones are within their centres' distance
    plus both half-diagonals of each other: the smallest such reach over the pairs (at least
    ``collision_m``) is the bound, and a pair whose boxes are farther apart than it is never the
    chunk's closest pair, tied with it or colliding, as long as some pair measured within it
    (the caller checks; none when no two drones are airborne together)."""
    seen = air[..., None] & np.isfinite(x)
    lo = np.where(seen, x, np.inf).min(axis=0)
    hi = np.where(seen, x, -np.inf).max(axis=0)
    active = np.all(seen.any(axis=0), axis=-1)
    both = active[first] & active[second]
    if not both.any():
        return np.zeros(0, dtype=np.intp), collision_m
    with np.errstate(invalid="ignore"):
        centre = np.where(active[:, None], (lo + hi) / 2.0, 0.0)
        half = np.where(active, np.linalg.norm(hi - lo, axis=-1) / 2.0, 0.0)
    apart = np.linalg.norm(centre[first] - centre[second], axis=-1)
    reach = half[first] + half[second]
    bound = max(collision_m, float(np.where(both, apart + reach, np.inf).min()))
    return np.flatnonzero(both & (apart - reach <= bound + _BOUND_SLACK_M)), bound


def _max_over(values: FloatArray, mask: BoolArray, t_s: FloatArray) -> dict[str, Any] | None:
    """Max of ``values`` (T, N) over ``mask`` with its time and drone, None if nothing."""
    v = np.where(mask & np.isfinite(values), values, -np.inf)
    if not np.isfinite(v.max(initial=-np.inf)):
        return None
    k, i = np.unravel_index(np.argmax(v), v.shape)
    return {"value": float(v[k, i]), "t_s": float(t_s[k]), "drone": int(i), "sysid": int(i) + 1}


def compute_metrics(
    record: FlightRecord,
    settle_s: float,
    faults: Sequence[tuple[float, str]] = (),
    collision_distance_m: float = 0.3,
    max_thrust_n: float | None = None,
    extra: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """All metrics of the module doc for one run; ``extra`` keys must not clash with them."""
    t = record.t_s
    a_true = true_descriptors(record)
    sep, collisions = separation(t, record.position_ned_m, record.airborne, collision_distance_m)
    roll, pitch = record.euler_rad[..., 0], record.euler_rad[..., 1]
    tilt = np.degrees(np.arccos(np.clip(np.cos(roll) * np.cos(pitch), -1.0, 1.0)))
    thrust = (
        None
        if max_thrust_n is None
        else _max_over(record.thrust_n / max_thrust_n, np.ones_like(record.airborne), t)
    )
    out: dict[str, Any] = {
        "n_samples": int(t.shape[0]),
        "n_drones": record.n_drones,
        "duration_s": float(t[-1] - t[0]) if t.size else 0.0,
        "tracking": tracking_errors(t, a_true, record.desired, settle_s),
        "tracking_steady": tracking_errors(
            t, a_true, record.desired, settle_s, loss_windows(record)
        ),
        "consensus": consensus_errors(t, a_true, record.estimate, record.member, settle_s),
        "consensus_steady": consensus_errors(
            t, a_true, record.estimate, record.member, settle_s, loss_windows(record)
        ),
        "reconvergence": reconvergence(
            t, a_true, record.desired, record.estimate, record.member, faults
        ),
        "separation": sep,
        "collisions": collisions,
        "drones_lost": [
            {"index": i, "sysid": i + 1, "t_s": float(ts)}
            for i, ts in sorted(record.lost_at_s.items(), key=lambda kv: kv[1])
        ],
        "rejoins": [
            {"index": i, "sysid": i + 1, "left_s": left, "back_s": back, "gap_s": back - left}
            for i, left, back in record.returns
        ],
        "max_tilt_deg": _max_over(tilt, record.airborne, t),
        "max_thrust_ratio": thrust,
    }
    clash = set(out) & set(extra or {})
    if clash:
        raise ValueError(f"extra keys clash with metrics: {sorted(clash)}")
    out.update(extra or {})
    result: dict[str, Any] = jsonable(out)
    return result
