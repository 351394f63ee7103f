"""The air the vehicles fly in: a steady wind plus turbulence, one field for the whole swarm. Pure.

The turbulence is a frozen, homogeneous and isotropic velocity field carried by the mean wind
(Taylor's hypothesis: ``u(x, t) = u0(x - W t)``), synthesised as a sum of ``M`` random Fourier
modes (Kraichnan's method)::

    u0(x) = sum_m  a_m  d_m  cos(k_m . x + phi_m)

with wavenumbers ``|k_m|`` log-spaced over the von Kármán spectrum's range, three modes a
wavenumber along the axes of a random rotation, each mode's velocity ``d_m`` along the next axis
(perpendicular to ``k_m``: the field is divergence-free, as air at these speeds; and the three
together add the same variance to each component, so the field is isotropic in variance for
every seed), random phases, and amplitudes
from the von Kármán energy spectrum ``E(k) ~ (k L)^4 / (1 + (k L)^2)^(17/6)`` scaled so that
each component's variance is ``sigma^2`` (the turbulence intensity). ``L`` is the integral length
scale: gusts at points closer than ``L`` are alike, gusts ``L`` and more apart barely so; a
vehicle crossing the field at the wind's speed ``W`` feels gusts of about ``L / W`` seconds.

Every vehicle samples the same field at its own position, so neighbours feel correlated gusts;
the field is drawn once from its own seed, so every simulator shard and both runners (``swarm
simulate``, ``swarm up``) fly the same air. No clock, no I/O: the caller gives the time.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from protocols.model.frames import FloatArray

#: Random Fourier modes of the field (three a wavenumber bin); each vehicle costs ``M`` cosines a
#: control tick.
N_MODES = 192
#: The spectrum is synthesised from ``KMIN_L / L`` to ``KMAX_L / L`` (rad/m): below, the von
#: Kármán energy is negligible; above, gusts shorter than a vehicle (a 25 cm wave at L = 20 m).
#: With these, the correlation against distance is the von Kármán one to within ~0.05 (averaged
#: over seeds; one seed's field is one realisation of it).
KMIN_L, KMAX_L = 0.02, 500.0
#: Salt of the field's seed, so that it does not share the scenario's other random draws.
_SALT = 0x57494E44  # "WIND"


@dataclass(frozen=True)
class Air:
    """The air of a flight: mean wind ``wind_ned_m_s`` (3,) NED, m/s, the velocity the air
    moves with (a wind from the west blowing east is ``(0, w, 0)``), turbulence intensity
    ``turbulence_m_s`` (each component's standard deviation, m/s; 0: none) and its integral
    length scale ``turbulence_scale_m`` (m)."""

    wind_ned_m_s: tuple[float, float, float] = (0.0, 0.0, 0.0)
    turbulence_m_s: float = 0.0
    turbulence_scale_m: float = 20.0

    @property
    def calm(self) -> bool:
        """No wind and no turbulence: the vehicles fly in still air."""
        return not any(self.wind_ned_m_s) and self.turbulence_m_s == 0.0

    def validate(self) -> Air:
        """Raise ValueError naming the field unless every value is usable."""
        if len(self.wind_ned_m_s) != 3 or not all(map(math.isfinite, self.wind_ned_m_s)):
            raise ValueError("wind_ned_m_s must be three finite numbers (m/s, NED)")
        if math.hypot(*self.wind_ned_m_s) > 30.0:
            raise ValueError("wind_ned_m_s: above 30 m/s no small quadcopter flies")
        if not (math.isfinite(self.turbulence_m_s) and 0.0 <= self.turbulence_m_s <= 10.0):
            raise ValueError("turbulence_m_s must be between 0 and 10 m/s")
        if not (math.isfinite(self.turbulence_scale_m) and 0.5 <= self.turbulence_scale_m <= 1e4):
            raise ValueError("turbulence_scale_m must be between 0.5 and 10000 m")
        return self


def von_karman_energy(k: FloatArray, scale_m: float) -> FloatArray:
    """The shape of the von Kármán energy spectrum at wavenumbers ``k`` (rad/m): ``(kL)^4 /
    (1 + (kL)^2)^(17/6)`` (unnormalised; the field scales it to its intensity)."""
    kl2 = (np.asarray(k, dtype=float) * scale_m) ** 2
    out: FloatArray = kl2 * kl2 / (1.0 + kl2) ** (17.0 / 6.0)
    return out


class WindField:
    """The air of ``air`` drawn once from ``seed``: :meth:`at` gives the air's velocity where
    the vehicles are, at a time."""

    def __init__(self, air: Air, seed: int, n_modes: int = N_MODES) -> None:
        self.air = air.validate()
        self.mean = np.asarray(air.wind_ned_m_s, dtype=float)
        rng = np.random.default_rng([seed & 0xFFFF_FFFF, _SALT])
        scale = air.turbulence_scale_m
        n_bins = n_modes // 3
        # wavenumber magnitudes: log-spaced bins, each at a random place in its bin
        edges = np.geomspace(KMIN_L / scale, KMAX_L / scale, n_bins + 1)
        k = edges[:-1] * (edges[1:] / edges[:-1]) ** rng.random(n_bins)
        energy = von_karman_energy(k, scale) * np.diff(edges)
        # three modes a bin, along the axes of a random rotation R, each one's velocity along
        # the next axis (k // R e1, u // R e2; R e2, R e3; R e3, R e1): perpendicular to its k
        # (divergence-free), and the three together add the same variance to every component
        axes = _rotations(rng, n_bins)  # (bins, 3, 3), columns R e1, R e2, R e3
        direction = np.concatenate([axes[:, :, i] for i in range(3)])
        velocity = np.concatenate([axes[:, :, (i + 1) % 3] for i in range(3)])
        # each component's variance is the sum over bins of a^2 / 2: sigma^2
        amplitude = np.sqrt(energy / energy.sum() * 2.0) * air.turbulence_m_s
        self.k = np.tile(k, 3)[:, None] * direction  # (M, 3) rad/m
        self.a = np.tile(amplitude, 3)[:, None] * velocity  # (M, 3) m/s
        self.phase = rng.uniform(0.0, 2.0 * math.pi, 3 * n_bins)

    def at(self, positions_ned_m: FloatArray, t_s: float) -> FloatArray:
        """The air's velocity (3, N) NED, m/s, at positions (3, N) NED, m, at time ``t_s``: the
        mean wind plus the turbulence the mean wind has carried there."""
        p = np.asarray(positions_ned_m, dtype=float)
        out = np.repeat(self.mean[:, None], p.shape[1], axis=1)
        if self.air.turbulence_m_s == 0.0:
            return out
        frozen = p - (self.mean * t_s)[:, None]  # where the air now here was at t = 0
        angle = self.k @ frozen + self.phase[:, None]  # (M, N)
        out += self.a.T @ np.cos(angle)
        return out


def _rotations(rng: np.random.Generator, n: int) -> FloatArray:
    """``n`` random rotation matrices (n, 3, 3), uniform over the rotations (QR of Gaussian
    matrices with the signs of R's diagonal fixed)."""
    q, r = np.linalg.qr(rng.normal(size=(n, 3, 3)))
    q = q * np.sign(np.diagonal(r, axis1=1, axis2=2))[:, None, :]
    flip = np.linalg.det(q) < 0.0
    q[flip, :, 0] = -q[flip, :, 0]
    return q
