"""The shared descriptor trajectory a_d(t): piecewise quintic polynomials (SPEC.md). Pure, I/O-free.

Every drone evaluates the same plan locally: the desired descriptor vector ``a_d(t)`` (9,), in
protocols.model.descriptor_vector order (``mu_x, mu_y, mu_z`` NED m; ``roll, pitch, yaw`` rad;
``s1, s2, s3`` m^2), and its first and second time derivatives. Time is simulated time in seconds.

Layout: knots ``t_knots_s`` (K,), strictly increasing, and ``coeffs`` (K-1, 9, 6): on segment ``k``
(``t_knots_s[k] <= t <= t_knots_s[k+1]``) descriptor ``d`` is
``sum_n coeffs[k, d, n] * tau**n`` with ``tau = t - t_knots_s[k]`` in seconds (ascending powers,
not normalised). Before the first knot the plan holds the first value at rest; after the last knot
it holds the last value at rest. Angles are interpolated as plain numbers: no wrapping.
"""

from __future__ import annotations

import math
from bisect import bisect_right
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from protocols.model.frames import FloatArray

N_DESCRIPTORS = 9
N_COEFFS = 6  # quintic
#: Length of the constant segment that represents a single-waypoint plan (s).
HOLD_SEGMENT_S = 1.0

_POWERS = np.arange(N_COEFFS, dtype=float)
# d/dtau of sum c_n tau^n = sum n c_n tau^(n-1): multipliers for the shifted coefficients.
_D1 = np.arange(1, N_COEFFS, dtype=float)  # n for n = 1..5
_D2 = _D1[1:] * (_D1[1:] - 1.0)  # n (n - 1) for n = 2..5

StateTriple = tuple[FloatArray, FloatArray, FloatArray]


def _vector9(x: object, what: str) -> FloatArray:
    """A read-only finite float copy of a (9,) vector; ValueError naming ``what`` otherwise."""
    arr = np.array(x, dtype=float)
    if arr.shape != (N_DESCRIPTORS,):
        raise ValueError(f"{what} must have shape (9,), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{what} must be finite, got {arr.tolist()}")
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True, eq=False)
class Waypoint:
    """A point the plan passes through at time ``t_s`` (s).

    ``value`` (9,): descriptors (m, rad, m^2). ``rate`` (9,) (per s) and ``accel`` (9,) (per s^2)
    are optional: None means "derive it" (see DescriptorTrajectory.from_waypoints).
    """

    t_s: float
    value: FloatArray
    rate: FloatArray | None = None
    accel: FloatArray | None = None

    def __post_init__(self) -> None:
        if not math.isfinite(self.t_s):
            raise ValueError(f"Waypoint.t_s must be finite, got {self.t_s!r}")
        object.__setattr__(self, "t_s", float(self.t_s))
        object.__setattr__(self, "value", _vector9(self.value, "Waypoint.value"))
        if self.rate is not None:
            object.__setattr__(self, "rate", _vector9(self.rate, "Waypoint.rate"))
        if self.accel is not None:
            object.__setattr__(self, "accel", _vector9(self.accel, "Waypoint.accel"))


def quintic_hermite(
    p0: FloatArray,
    v0: FloatArray,
    a0: FloatArray,
    p1: FloatArray,
    v1: FloatArray,
    a1: FloatArray,
    h_s: float | FloatArray,
) -> FloatArray:
    """Coefficients (..., 6), ascending powers of tau (s), of the quintic on ``[0, h_s]`` that
    matches value, rate and acceleration (each (...,), e.g. (9,)) at both ends; ``h_s`` > 0
    broadcasts against them."""
    dp = p1 - p0
    h = h_s
    c3 = (20.0 * dp - (8.0 * v1 + 12.0 * v0) * h - (3.0 * a0 - a1) * h**2) / (2.0 * h**3)
    c4 = (-30.0 * dp + (14.0 * v1 + 16.0 * v0) * h + (3.0 * a0 - 2.0 * a1) * h**2) / (2.0 * h**4)
    c5 = (12.0 * dp - 6.0 * (v1 + v0) * h + (a1 - a0) * h**2) / (2.0 * h**5)
    return np.stack([p0, v0, 0.5 * a0, c3, c4, c5], axis=-1)


@dataclass(frozen=True, eq=False)
class DescriptorTrajectory:
    """A plan of piecewise quintic segments (see the module docstring for the layout).

    ``seq``: sequence number (a newer plan has a larger one). ``t_knots_s`` (K,), K >= 2, s.
    ``coeffs`` (K-1, 9, 6). Arrays are copied and made read-only.
    """

    seq: int
    t_knots_s: FloatArray
    coeffs: FloatArray

    def __post_init__(self) -> None:
        knots = np.array(self.t_knots_s, dtype=float)
        coeffs = np.array(self.coeffs, dtype=float)
        if isinstance(self.seq, bool) or not isinstance(self.seq, int | np.integer) or self.seq < 0:
            raise ValueError(f"seq must be an integer >= 0, got {self.seq!r}")
        if knots.ndim != 1 or knots.shape[0] < 2:
            raise ValueError(f"t_knots_s must be 1-D with at least 2 knots, got {knots.shape}")
        if not np.all(np.isfinite(knots)) or not np.all(np.diff(knots) > 0):
            raise ValueError("t_knots_s must be finite and strictly increasing")
        if coeffs.shape != (knots.shape[0] - 1, N_DESCRIPTORS, N_COEFFS):
            raise ValueError(
                f"coeffs must have shape ({knots.shape[0] - 1}, 9, 6), got {coeffs.shape}"
            )
        if not np.all(np.isfinite(coeffs)):
            raise ValueError("coeffs must be finite")
        knots.setflags(write=False)
        coeffs.setflags(write=False)
        object.__setattr__(self, "seq", int(self.seq))
        object.__setattr__(self, "t_knots_s", knots)
        object.__setattr__(self, "coeffs", coeffs)

    @property
    def start_s(self) -> float:
        """Time of the first knot (s)."""
        return float(self.t_knots_s[0])

    @property
    def end_s(self) -> float:
        """Time of the last knot (s); the plan holds its last value after it."""
        return float(self.t_knots_s[-1])

    @property
    def n_segments(self) -> int:
        """Number of quintic segments, K - 1."""
        return int(self.coeffs.shape[0])

    def retimed(self, shift_s: float) -> DescriptorTrajectory:
        """The same plan ``shift_s`` seconds later (every knot moved; same ``seq``): what
        ``evaluate(t - shift_s)`` flies, as a plan of its own (protocols/model/plan_timing.py)."""
        if shift_s == 0.0:
            return self
        return DescriptorTrajectory(self.seq, self.t_knots_s + float(shift_s), self.coeffs)

    def evaluate(self, t_s: float) -> StateTriple:
        """``(a, a_dot, a_ddot)``, each (9,), at time ``t_s`` (s).

        Before the first knot: the first value, zero rate and acceleration. At the last knot: the
        end of the last segment. After it: the last value, zero rate and acceleration.
        """
        t = float(t_s)
        knots, rate, accel = self._tables
        k = min(max(bisect_right(knots, t) - 1, 0), len(knots) - 2)
        tau = min(max(t - knots[k], 0.0), knots[k + 1] - knots[k])
        tau_pow = tau**_POWERS
        a = self.coeffs[k] @ tau_pow  # (9, 6) @ (6,)
        if t < knots[0] or t > knots[-1]:
            return a, np.zeros(N_DESCRIPTORS), np.zeros(N_DESCRIPTORS)
        return a, rate[k] @ tau_pow[:-1], accel[k] @ tau_pow[:-2]

    @cached_property
    def _tables(self) -> tuple[list[float], list[FloatArray], list[FloatArray]]:
        """What :meth:`evaluate` reads, made once per plan: the knots as floats, and per segment
        the coefficients of the rate (9, 5) and of the acceleration (9, 4)."""
        coeffs = list(self.coeffs)
        rate = [c[:, 1:] * _D1 for c in coeffs]
        return self.t_knots_s.tolist(), rate, [c[:, 2:] * _D2 for c in coeffs]

    def evaluate_many(self, t_s: FloatArray) -> StateTriple:
        """Vectorised :meth:`evaluate`: times (T,) s -> ``(a, a_dot, a_ddot)``, each (T, 9)."""
        t = np.asarray(t_s, dtype=float).reshape(-1)
        knots = self.t_knots_s
        idx = np.clip(np.searchsorted(knots, t, side="right") - 1, 0, self.n_segments - 1)
        tau = np.clip(t - knots[idx], 0.0, knots[idx + 1] - knots[idx])
        c = self.coeffs[idx]  # (T, 9, 6)
        tau_pow = tau[:, None] ** _POWERS  # (T, 6)
        a = np.einsum("tdn,tn->td", c, tau_pow)
        a_dot = np.einsum("tdn,tn->td", c[:, :, 1:] * _D1, tau_pow[:, :-1])
        a_ddot = np.einsum("tdn,tn->td", c[:, :, 2:] * _D2, tau_pow[:, :-2])
        outside = (t < knots[0]) | (t > knots[-1])
        a_dot[outside] = 0.0
        a_ddot[outside] = 0.0
        return a, a_dot, a_ddot

    @classmethod
    def from_waypoints(cls, waypoints: Sequence[Waypoint], seq: int = 0) -> DescriptorTrajectory:
        """The C2 plan through ``waypoints``: a quintic Hermite segment between consecutive ones.

        Each segment matches value, rate and acceleration at both of its ends. A waypoint without
        ``rate``/``accel`` takes shape-preserving ones (:func:`_derived_rates`: no overshoot, a
        value repeated at consecutive waypoints is held); the first and last waypoints default to
        rest, so two bare waypoints give a minimum-jerk rest-to-rest move.
        A single waypoint gives a constant segment of HOLD_SEGMENT_S (a hold).

        Raises:
            ValueError: no waypoints, or times not strictly increasing.
        """
        wps = list(waypoints)
        if not wps:
            raise ValueError("a trajectory needs at least one waypoint")
        for k in range(1, len(wps)):
            if not wps[k].t_s > wps[k - 1].t_s:
                raise ValueError(
                    f"waypoint times must be strictly increasing: waypoints[{k}].t_s = "
                    f"{wps[k].t_s} is not after waypoints[{k - 1}].t_s = {wps[k - 1].t_s}"
                )
        if len(wps) == 1:
            wp = wps[0]
            zero = np.zeros(N_DESCRIPTORS)
            coeffs = quintic_hermite(wp.value, zero, zero, wp.value, zero, zero, HOLD_SEGMENT_S)
            return cls(seq, np.array([wp.t_s, wp.t_s + HOLD_SEGMENT_S]), coeffs[None])
        t = np.array([wp.t_s for wp in wps])
        p = np.stack([wp.value for wp in wps])
        v, acc = _derived_rates(wps, t, p)
        h = np.diff(t)
        coeffs = quintic_hermite(
            p[:-1].T, v[:-1].T, acc[:-1].T, p[1:].T, v[1:].T, acc[1:].T, h
        )  # (9, K-1, 6)
        return cls(seq, t, np.transpose(coeffs, (1, 0, 2)))

    def append(
        self, new: Sequence[Waypoint] | DescriptorTrajectory, t_start_s: float | None = None
    ) -> DescriptorTrajectory:
        """A new plan (``seq + 1``): this one up to ``t_start_s``, then ``new``.

        ``new`` as waypoints (all after ``t_start_s``, default :attr:`end_s`): the plan continues
        from this plan's value, rate and acceleration at ``t_start_s`` through them (C2 at the
        join). ``new`` as a trajectory (e.g. :func:`rest_to_rest_segment`): it starts at its own
        first knot, where this plan's state must already equal its start (else ValueError).
        The earlier segments are kept, so the new plan agrees with this one before the join.
        """
        if isinstance(new, DescriptorTrajectory):
            if t_start_s is not None and t_start_s != new.start_s:
                raise ValueError(f"t_start_s {t_start_s} differs from the segment's {new.start_s}")
            t0 = new.start_s
            _check_join(self.evaluate(t0), new.evaluate(t0), t0)
            tail_knots, tail_coeffs = new.t_knots_s, new.coeffs
        else:
            t0 = self.end_s if t_start_s is None else float(t_start_s)
            wps = list(new)
            if not wps:
                raise ValueError("append needs at least one waypoint")
            if not wps[0].t_s > t0:
                raise ValueError(f"appended waypoints must start after t_start_s = {t0}")
            a, a_dot, a_ddot = self.evaluate(t0)
            tail = DescriptorTrajectory.from_waypoints([Waypoint(t0, a, a_dot, a_ddot), *wps])
            tail_knots, tail_coeffs = tail.t_knots_s, tail.coeffs
        head_knots, head_coeffs = self._head(t0)
        return DescriptorTrajectory(
            self.seq + 1,
            np.concatenate([head_knots, tail_knots]),
            np.concatenate([head_coeffs, tail_coeffs]),
        )

    def _head(self, t0: float) -> tuple[FloatArray, FloatArray]:
        """Knots before ``t0`` and the segments from them to ``t0`` (the last one cut at t0);
        a constant hold segment bridges a gap after the end of the plan."""
        knots = self.t_knots_s
        n_before = int(np.searchsorted(knots, t0, side="left"))  # knots strictly before t0
        if n_before == 0:
            return np.empty(0), np.empty((0, N_DESCRIPTORS, N_COEFFS))
        head_coeffs = self.coeffs[: min(n_before, self.n_segments)]
        if n_before > self.n_segments:  # t0 after the end: hold the last value until t0
            last = self.evaluate(self.end_s)[0]
            zero = np.zeros(N_DESCRIPTORS)
            hold = quintic_hermite(last, zero, zero, last, zero, zero, t0 - self.end_s)
            head_coeffs = np.concatenate([head_coeffs, hold[None]])
        return knots[:n_before], head_coeffs


def _derived_rates(
    wps: Sequence[Waypoint], t: FloatArray, p: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Rates and accelerations (K, 9) at the waypoints: the given ones, else shape-preserving.

    A waypoint without a rate takes, per descriptor, the harmonic mean of the slopes of its two
    segments when they have the same sign, and 0 otherwise (Fritsch-Butland, as PCHIP): a value
    equal at two consecutive waypoints stays there, a local extremum is a waypoint, and between
    monotone waypoints the plan is monotone (a quintic Hermite segment at zero end accelerations
    is monotone while both end slopes are within [0, 2] times its mean slope, and this mean is at
    most twice the smaller slope). Without an acceleration a waypoint takes 0. The first and last
    waypoints default to rest (zero rate and acceleration): two bare waypoints give a
    minimum-jerk rest-to-rest move. (A C2 cubic spline used to give the rates: it overshot, e.g.
    a heading held at 45 deg at two waypoints flew 65 deg between them.)
    """
    k = len(wps)
    slope = np.diff(p, axis=0) / np.diff(t)[:, None]  # (K-1, 9)
    v = np.zeros((k, N_DESCRIPTORS))
    if k > 2:
        left, right = slope[:-1], slope[1:]
        same = left * right > 0
        with np.errstate(divide="ignore", invalid="ignore"):
            harmonic = 2.0 * left * right / (left + right)
        v[1:-1] = np.where(same, harmonic, 0.0)
    acc = np.zeros((k, N_DESCRIPTORS))
    for i, wp in enumerate(wps):
        if wp.rate is not None:
            v[i] = wp.rate
        if wp.accel is not None:
            acc[i] = wp.accel
    return v, acc


def _check_join(before: StateTriple, after: StateTriple, t_s: float) -> None:
    """ValueError unless the two states (value, rate, accel) agree at the join time ``t_s``."""
    for name, x, y in zip(("value", "rate", "acceleration"), before, after, strict=True):
        if not np.allclose(x, y, rtol=1e-9, atol=1e-9):
            d = int(np.argmax(np.abs(x - y)))
            raise ValueError(
                f"segment does not join the plan at t = {t_s} s: descriptor {d} {name} "
                f"{y[d]:.6g} != plan's {x[d]:.6g}"
            )


def rest_to_rest_segment(
    t0_s: float, a0: FloatArray, t1_s: float, a1: FloatArray, seq: int = 0
) -> DescriptorTrajectory:
    """The minimum-jerk quintic from ``a0`` (9,) at ``t0_s`` to ``a1`` (9,) at ``t1_s`` (s), at
    rest (zero rate and acceleration) at both ends."""
    zero = np.zeros(N_DESCRIPTORS)
    return DescriptorTrajectory.from_waypoints(
        [Waypoint(t0_s, a0, zero, zero), Waypoint(t1_s, a1, zero, zero)], seq=seq
    )
