"""What a real quadcopter believes about itself: its state estimate as a GNSS + EKF autopilot
reports it, from the true state. Pure.

A real vehicle never reports the truth. Its GNSS position wanders by a bias that drifts over
minutes (multipath, atmosphere, satellite geometry), the EKF's output jitters by some noise, it
is refreshed at the filter's output rate rather than every control tick, and it describes the
vehicle as it was some time ago (sensor and filter latency). This module models those four
effects, each vehicle and each axis independently, for N vehicles at once, updated once a control
tick ``k`` of period ``dt = 1 / control_hz``:

* **GNSS bias** (position only): a first-order Gauss–Markov process per axis, stationary standard
  deviation ``sigma = gnss_bias_m`` north and east and ``altitude_bias_m`` down (an EKF that
  takes its height from the barometer, PX4's and ArduPilot's default, drifts in height far less
  than its GNSS does), correlation time ``tau = gnss_bias_tau_s``::

      b[0]   = sigma * w[0]
      b[k+1] = a * b[k] + sigma * sqrt(1 - a^2) * w[k+1],    a = exp(-dt / tau),  w ~ N(0, 1)

  ``b[0]`` is drawn from the stationary distribution N(0, sigma^2), so every ``b[k]`` has it.
  The lag-``m`` autocorrelation is ``a^m`` and ``var(b[k+m] - b[k]) = 2 sigma^2 (1 - a^m)``: over
  times much shorter than ``tau`` the bias wanders like a random walk,
  ``≈ 2 sigma^2 m dt / tau``, and over times much longer it forgets where it was. It advances
  every tick, whether the estimate is refreshed or held.
* **White noise**: independent N(0, s^2) on each position (``position_noise_m``), velocity
  (``velocity_noise_m_s``) and attitude (``attitude_noise_rad``: roll, pitch, yaw) component,
  drawn anew at each refresh; the yaw is wrapped to (-pi, pi].
* **Output rate** ``rate_hz`` (0: every control tick): the estimate is sample-and-hold, refreshed
  at the ticks where ``floor(k * rate_hz / control_hz)`` changes (tick 0 always; a rate at or
  above the control rate refreshes every tick) and held, the very same values, in between.
* **Latency** ``latency_s``: the estimate describes the truth of ``L = round(latency_s *
  control_hz)`` ticks ago, kept in a ring buffer of the last ``L + 1`` truths (before ``L`` ticks
  have passed, tick 0's truth, the oldest there is).

At tick ``k`` (order of operations) the truth goes into the buffer, the truth of tick
``max(k - L, 0)`` comes out, and on a refresh tick the estimate becomes::

    position = delayed position + b[k] + noise,   velocity = delayed velocity + noise,
    attitude = delayed attitude + noise

otherwise it stays the last one. The default :class:`Sensors` is the ideal sensor: the estimate
is the truth itself and nothing is drawn.

Each vehicle's draws come from a generator of its own, seeded by ``(seed, _SALT, its index in the
swarm)`` (the salt keeps them apart from the scenario's other random draws; the index makes a
simulator shard's vehicle err as in the whole swarm's world), in a fixed order — at each tick the
bias's draw then the three noises', refresh tick or not, whichever terms are zero — so the draws
depend only on the seed, the vehicle and the tick sequence, never on the state: one seed flies
the same errors bit for bit, and turning one error term on or off leaves the others' draws as
they were. No clock, no I/O: the caller gives the tick and the truth.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, fields

import numpy as np

from protocols.model.frames import FloatArray
from protocols.scenario.scenario_file import SensorsConfig

#: Salt of the estimate's seed, so that its draws do not share the scenario's other random draws.
_SALT = 0x4553544D  # "ESTM"
#: Seeds are taken modulo 2^64 (so a negative seed is usable too).
_SEED_MASK = 0xFFFF_FFFF_FFFF_FFFF
#: Tolerance (in refresh periods) of the refresh schedule's floor, so that a decimal rate
#: (0.3 Hz, stored as 0.29999...) refreshes at the ticks its decimal value says.
_FLOOR_EPS = 1e-9


@dataclass(frozen=True)
class Sensors(SensorsConfig):
    """The errors of a vehicle's state estimate: a scenario's ``[sensors]`` (its fields, defaults
    and predicates: protocols/scenario/scenario_file.py ``SensorsConfig``), checked. A GNSS
    position bias (stationary standard deviation ``gnss_bias_m``, m, north and east and
    ``altitude_bias_m``, m, down, wandering with correlation time ``gnss_bias_tau_s``, s), white
    noise on each position (m), velocity (m/s) and attitude (rad) component (standard deviations),
    the estimate's output rate ``rate_hz`` (Hz; 0: every control tick) and its latency
    ``latency_s`` (s). The defaults are the ideal sensor: no error at all."""

    def validate(self) -> Sensors:
        """Raise ValueError naming the field unless every value is usable: all finite and
        >= 0, and ``gnss_bias_tau_s`` > 0."""
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise ValueError(f"{f.name} must be a number, not {value!r}")
            if not math.isfinite(value):
                raise ValueError(f"{f.name} must be finite, not {value!r}")
            if value < 0.0:
                raise ValueError(f"{f.name} must be >= 0, not {value!r}")
        if self.gnss_bias_tau_s <= 0.0:
            raise ValueError(f"gnss_bias_tau_s must be > 0 s, not {self.gnss_bias_tau_s!r}")
        return self


class StateEstimate:
    """The state estimate of ``n`` vehicles with the errors of ``config``, updated once a tick of
    a ``control_hz`` control loop, its errors drawn from ``seed``. Each vehicle draws from a
    stream of its own, named by its index in the swarm (``ids``; default ``0..n-1``), so that a
    simulator shard flying some of the vehicles gives each the errors the whole swarm's world
    gives it."""

    def __init__(
        self,
        config: Sensors,
        n: int,
        control_hz: int,
        seed: int,
        ids: Sequence[int] | None = None,
    ) -> None:
        self.config = config.validate()
        if n < 1:
            raise ValueError(f"n must be >= 1 vehicle, not {n}")
        if control_hz < 1:
            raise ValueError(f"control_hz must be >= 1, not {control_hz}")
        self.n = n
        self.control_hz = control_hz
        dt = 1.0 / control_hz
        #: the bias's per-tick decay ``a = exp(-dt / tau)`` and innovation scale
        #: ``sigma * sqrt(1 - a^2)`` (expm1: exact also for tau >> dt)
        self.decay = math.exp(-dt / config.gnss_bias_tau_s)
        #: the bias's stationary standard deviation per axis (3, 1): north, east, down
        self._sigma = np.array(
            [[config.gnss_bias_m], [config.gnss_bias_m], [config.altitude_bias_m]]
        )
        self._innovation = self._sigma * math.sqrt(-math.expm1(-2.0 * dt / config.gnss_bias_tau_s))
        #: the estimate describes the truth of this many ticks ago
        self.latency_ticks = round(config.latency_s * control_hz)
        ids = list(range(n)) if ids is None else [int(i) for i in ids]
        if len(ids) != n or any(i < 0 for i in ids):
            raise ValueError(f"ids must be {n} vehicle indices >= 0, not {ids!r}")
        key = seed & _SEED_MASK
        self._rngs = [np.random.default_rng(np.random.SeedSequence([key, _SALT, i])) for i in ids]
        self._next_tick = 0
        self._bias: FloatArray = np.zeros((3, n))
        # the last L + 1 truths, (position, velocity, attitude) stacked: (L + 1, 9, N)
        self._history: FloatArray = np.zeros((self.latency_ticks + 1, 9, n))
        self._estimate: FloatArray = np.zeros((9, n))
        self._noise_std = np.repeat(
            [config.position_noise_m, config.velocity_noise_m_s, config.attitude_noise_rad], 3
        )[:, None]  # (9, 1)

    @property
    def bias_m(self) -> FloatArray:
        """The GNSS position bias (3, N) NED, m, of the last tick updated (zeros before the
        first); a held estimate carries the bias of its refresh tick."""
        return self._bias.copy()

    def refreshes(self, tick: int) -> bool:
        """Whether the estimate is refreshed at ``tick`` (else held from the tick before)."""
        rate = self.config.rate_hz
        if tick == 0 or rate == 0.0:
            return True
        ratio = rate / self.control_hz
        return math.floor(tick * ratio + _FLOOR_EPS) != math.floor((tick - 1) * ratio + _FLOOR_EPS)

    def update(
        self,
        tick: int,
        position_ned_m: FloatArray,
        velocity_ned_m_s: FloatArray,
        euler_rad: FloatArray,
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """The estimate at ``tick`` (ticks consecutive from 0) of the true position (3, N) NED m,
        velocity (3, N) NED m/s and (roll, pitch, yaw) (3, N) rad: new arrays (3, N) each. The
        ideal sensor returns the inputs themselves and draws nothing."""
        if tick != self._next_tick:
            raise ValueError(f"tick {tick} out of order: expected tick {self._next_tick}")
        if self.config.ideal:
            self._next_tick += 1
            return position_ned_m, velocity_ned_m_s, euler_rad
        n = self.n
        truth = np.concatenate(
            [
                np.asarray(position_ned_m, dtype=float),
                np.asarray(velocity_ned_m_s, dtype=float),
                np.asarray(euler_rad, dtype=float),
            ]
        )
        if truth.shape != (9, n):
            raise ValueError(f"the true state must be three (3, {n}) arrays")
        self._next_tick += 1
        slots = self.latency_ticks + 1
        self._history[tick % slots] = truth
        delayed = self._history[max(tick - self.latency_ticks, 0) % slots]
        # the draws of the tick, always all of them in this order: bias, then the noises
        w = np.stack([rng.standard_normal((4, 3)) for rng in self._rngs], axis=-1)
        if tick == 0:  # the stationary distribution N(0, sigma^2)
            self._bias = self._sigma * w[0]
        else:
            self._bias = self.decay * self._bias + self._innovation * w[0]
        if self.refreshes(tick):
            estimate = delayed.copy()
            estimate[0:3] += self._bias
            estimate += self._noise_std * w[1:].reshape(9, n)
            if self.config.attitude_noise_rad > 0.0:
                estimate[8] = _wrap_pi(estimate[8])
            self._estimate = estimate
        est = self._estimate
        return est[0:3].copy(), est[3:6].copy(), est[6:9].copy()


def _wrap_pi(angle: FloatArray) -> FloatArray:
    """``angle`` wrapped to (-pi, pi]; values already there are returned bit for bit."""
    wrapped = math.pi - np.mod(math.pi - angle, 2.0 * math.pi)
    wrapped[wrapped <= -math.pi] = math.pi  # mod's rounding can give 2 pi exactly
    out: FloatArray = np.where((angle > math.pi) | (angle <= -math.pi), wrapped, angle)
    return out
