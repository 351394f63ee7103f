"""Separation safety layer: each agent filters its own commanded acceleration, minimally, so
that it keeps ``min_separation_m`` from every neighbour it hears, stays above an altitude floor
and inside the geofence (issue 10 item 3). Pure and I/O-free, batched over K agents.

Where it is wired in
--------------------
- *Where*: :class:`~drone_agent.core.agent_core.BatchAgentCore` filters the cooperative
  controller's acceleration (or the rejoin climb's) through its
  :class:`~drone_agent.core.separation.layer.SeparationLayer`, before thrust/attitude
  (drone_agent/thrust_attitude): the filter returns an acceleration inside what thrust/attitude
  can realise, so the limiter there does not undo it. Every tick an agent
  computes a setpoint, take-off included (that is where a dense grid collides); off when
  ``AgentConfig.separation`` is None.
- *Inputs*: own position and velocity (telemetry of this tick); the neighbours heard: the newest
  consensus message of each sender within the layer's age limit, position and velocity
  extrapolated to now (drone_agent/core/neighbours.py, one implementation). Senders publish their
  velocity in ``ConsensusMessage.velocity_ned_m_s`` (wire schema 2).
- *Parameters*: :meth:`~drone_agent.core.separation.layer.SeparationConfig.params`:
  ``min_separation_m`` and the geofence from the scenario's ``[safety]``, the altitude floor
  (0.5 m, below the 1 m LAND hand-over), ``accel=AccelBox.from_thrust_limits(limits)``;
  ``common_accel_ned_m_s2``: the plan's centre acceleration (exactly shared); not the
  controller's ``w_μ``, which depends on each agent's estimate and would void the reciprocal
  guarantee exactly when estimates disagree.
- *What is logged*: an agent whose command the filter changed this tick says so in its status
  (``Health.SEPARATING``, protocols/wire/status.py); the ground station writes a ``separation``
  event to events.jsonl when an agent's filter starts acting and ``separation_end`` when it stops
  (gcs/station/swarm_watch.py). ``closest_m``, ``n_constraints``, which kinds acted and
  ``infeasible`` are in each :class:`SeparationResult` but not logged.

The barrier (per pair of agents i, j; Wang, Ames and Egerstedt, "Safety barrier certificates for
collisions-free multi-robot systems", 2017)
-----------------------------------------------------------------------------------------------
With ``r = p_i - p_j``, ``ρ = |r|``, ``n = r / ρ``, ``w = v_i - v_j``, ``ρ̇ = n·w``,
``s = ρ - D`` (``D = min_separation_m + margin_m``) and ``A`` the relative deceleration the pair
can brake with (``2 brake`` when both brake: ``brake / share``)::

    h = sgn(s) sqrt(2 A |s|) + ρ̇          (>= 0: the pair can still stop before D)
    ḣ >= -α(h)   <=>   n·(u_i - u_j) >= -α(h) - A ρ̇ / sqrt(2 A |s|) - (|w|² - ρ̇²) / ρ
    α(h) = γ h (1 + (h / h_scale)²)

The class-K function ``α`` is linear near the boundary (a drone pushed inside is pushed back out
at rate γ) and cubic far from it, so the barrier never binds a formation that is merely close: at
rest 2 m apart an agent must accelerate at 12.7 m/s² towards the other to wake it (1.5 m: 3.5).
With a linear ``α`` the paper's take-off (every drone accelerating at 3.9 m/s² the same way from
2 m apart, the half-constraint cannot know the neighbour does the same) woke it at γ = 2 s⁻¹;
with this one a shadow run of the paper's flight never does (measured, not asserted here).

Unlike the second-order barrier on ``|r|² - D²`` (whose fixed gains ask for unbounded
acceleration at high closing speed) this one is built on the braking distance, so it never asks
a pair for more than ``A`` along ``n``: the safe set stays invariant with bounded acceleration.
*Reciprocal*: agent i takes its ``share`` (1/2) of the pair's right-hand side,
``n·u_i >= share · c`` (capped at ``brake``), and j, computing the same with ``-n``, the other
half. Floor and fence walls are the same barrier with the agent alone (``A = brake``).

*Minimal*: the filtered acceleration is the point closest to the command that meets every
barrier and stays inside ``accel`` (an inner polytope of what thrust and tilt allow), an exact
tiny QP (drone_agent/core/separation/small_qp.py). When the command already meets every barrier it
is returned unchanged, bit for bit: far from everyone (the paper's flight) the layer does nothing.

*Sampling*: the guarantee is for continuous time; ``margin_m`` absorbs the 50 Hz hold, the
one-tick-old neighbour data and the attitude loop's lag (closed-loop tests: closest 1.19 m for a
1.2 m barrier, also with a one-tick delay and a 0.1 s actuation lag). Two drones at one point have
no direction between them; both then use north (no antisymmetry: a degenerate case).

*Tie-break*: two drones head-on would only brake along their common line and stand nose to nose.
Each therefore adds to its command, before the projection, ``right_bias`` times each pair's
shortfall along its own right (horizontal, perpendicular to the line towards the other drone,
``(n_y, -n_x, 0)`` in NED). Both turn to their own right, so they pass port to port, as ships
do; the bias flips with the pair, so the filter stays symmetric.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from functools import lru_cache

import numpy as np
import numpy.typing as npt

from drone_agent.core.jit_math import f64, jit, nmax, nmin
from drone_agent.core.separation.small_qp import project
from drone_agent.core.thrust_attitude import ThrustLimits
from protocols.model.frames import G_M_S2, FloatArray

BoolArray = npt.NDArray[np.bool_]
IntArray = npt.NDArray[np.intp]

_S_EPS_M = 0.01  # |s| floor in the barrier's derivative term (m)
_UP = np.array([0.0, 0.0, -1.0])


@dataclass(frozen=True)
class AccelBox:
    """Accelerations (NED, m/s²) the filter may command: a frustum of two horizontal octagons,
    at ``u_z = -max_up_m_s2`` (circumradius ``horizontal_up_m_s2``) and ``u_z = max_down_m_s2``
    (``horizontal_down_m_s2``). Inside the convex set thrust/attitude realise exactly when its
    corners are."""

    max_up_m_s2: float = 4.0
    max_down_m_s2: float = 4.0
    horizontal_up_m_s2: float = 9.0
    horizontal_down_m_s2: float = 4.0

    @classmethod
    def from_thrust_limits(
        cls, limits: ThrustLimits, max_up_m_s2: float = 4.0, max_down_m_s2: float = 4.0
    ) -> AccelBox:
        """The frustum whose corners lie on the limits of thrust and tilt of ``limits``
        (thrust_attitude's rule: tilt ≤ max, thrust within range), the vertical range cut to
        what the thrust range allows."""
        t_min, t_max = (t / limits.mass_kg for t in limits.thrust_range_n)
        up = min(max_up_m_s2, t_max - G_M_S2)
        down = min(max_down_m_s2, G_M_S2 - t_min)

        def radius(lift: float) -> float:
            return min(math.tan(limits.max_tilt_rad) * lift, math.sqrt(t_max**2 - lift**2))

        return cls(up, down, radius(G_M_S2 + up), radius(G_M_S2 - down))

    def rows(self) -> tuple[FloatArray, FloatArray]:
        """Half-spaces ``g @ u >= b`` of the frustum: (10, 3), (10,)."""
        z_lo, z_hi = -self.max_up_m_s2, self.max_down_m_s2
        c8 = math.cos(math.pi / 8)
        d_lo, d_hi = self.horizontal_up_m_s2 * c8, self.horizontal_down_m_s2 * c8
        slope = (d_hi - d_lo) / (z_hi - z_lo)
        theta = (np.arange(8) + 0.5) * math.pi / 4
        sides = np.column_stack((-np.cos(theta), -np.sin(theta), np.full(8, slope)))
        g = np.vstack((sides, [0.0, 0.0, 1.0], [0.0, 0.0, -1.0]))
        b = np.concatenate((np.full(8, slope * z_lo - d_lo), [z_lo, -z_hi]))
        return g, b

    def inradius(self) -> float:
        """Radius of the largest ball about 0 inside the frustum (m/s²)."""
        g, b = self.rows()
        return float(np.min(-b / np.linalg.norm(g, axis=1)))


@dataclass(frozen=True)
class SeparationParams:
    """The separation layer's parameters (SI units; altitudes up, m).

    ``min_separation_m``: the scenario's ``[safety] min_separation_m``; ``margin_m`` is added to
    it in the barrier (sampling, one-tick-old neighbour data, the attitude loop's lag).
    ``brake_m_s2``: the deceleration an agent plans to avoid with (at most ``accel``'s inradius);
    ``gamma_1_s``, ``h_scale_m_s``: the class-K function (module docstring): how fast the
    barrier may be approached; ``share``: the agent's part of each
    pair constraint (1/2: reciprocal); ``right_bias``: the tie-break (module docstring).
    ``floor_m``: altitude floor, kept by every agent already above it (None: off, e.g. landing);
    ``fence_north_m`` / ``fence_east_m`` (min, max) and ``ceiling_m``: the geofence (None: off).
    ``wall_margin_m``: the floor and fence barriers sit this far inside (sampling); an agent
    above the floor but within the margin is pushed back up, one below the floor is left alone.
    """

    min_separation_m: float = 1.0
    margin_m: float = 0.2
    brake_m_s2: float = 2.5
    gamma_1_s: float = 1.0
    h_scale_m_s: float = 1.0
    share: float = 0.5
    right_bias: float = 0.5
    floor_m: float | None = 0.5
    fence_north_m: tuple[float, float] | None = None
    fence_east_m: tuple[float, float] | None = None
    ceiling_m: float | None = None
    wall_margin_m: float = 0.05
    accel: AccelBox = AccelBox()

    def validate(self) -> None:
        """ValueError naming the first bad field."""
        for name in ("min_separation_m", "margin_m", "right_bias", "wall_margin_m"):
            if not (math.isfinite(getattr(self, name)) and getattr(self, name) >= 0):
                raise ValueError(f"separation.{name} must be >= 0, got {getattr(self, name)!r}")
        for name in ("brake_m_s2", "gamma_1_s", "h_scale_m_s"):
            if not (math.isfinite(getattr(self, name)) and getattr(self, name) > 0):
                raise ValueError(f"separation.{name} must be > 0, got {getattr(self, name)!r}")
        if not 0 < self.share <= 1:
            raise ValueError(f"separation.share must be in (0, 1], got {self.share!r}")
        if self.brake_m_s2 > self.accel.inradius() + 1e-12:
            raise ValueError(
                f"separation.brake_m_s2 {self.brake_m_s2:g} exceeds what the vehicle can make "
                f"in every direction ({self.accel.inradius():.3g} m/s²)"
            )
        for name in ("fence_north_m", "fence_east_m"):
            fence = getattr(self, name)
            if fence is not None and not fence[0] < fence[1]:
                raise ValueError(f"separation.{name} must be (min, max) with min < max")

    @property
    def distance_m(self) -> float:
        """The distance the barrier keeps (m): the minimum plus the margin."""
        return self.min_separation_m + self.margin_m

    def without_floor(self) -> SeparationParams:
        """The same, with the altitude floor off (the plan lands)."""
        return replace(self, floor_m=None)


@dataclass(frozen=True)
class SeparationResult:
    """One filtered tick of K agents.

    ``accel_ned_m_s2`` (K, 3): the filtered acceleration (the input, unchanged, where not
    ``active``); ``active`` (K,): the command broke a barrier and was changed; ``closest_m``
    (K,): distance to the nearest neighbour heard (inf if none); ``n_constraints`` (K,): barriers
    the command broke; ``separation`` / ``floor`` / ``fence`` (K,): which kinds among them;
    ``infeasible`` (K,): the barriers conflict within the acceleration limits (best effort).
    """

    accel_ned_m_s2: FloatArray
    active: BoolArray
    closest_m: FloatArray
    n_constraints: IntArray
    separation: BoolArray
    floor: BoolArray
    fence: BoolArray
    infeasible: BoolArray


def pad_neighbours(
    positions: Sequence[FloatArray], velocities: Sequence[FloatArray]
) -> tuple[FloatArray, FloatArray, BoolArray]:
    """Per-agent neighbour lists ((M_k, 3) each) as padded arrays (K, M, 3), (K, M, 3) and the
    mask (K, M) of real entries, M = max M_k (at least 1)."""
    k = len(positions)
    m = max([len(p) for p in positions] + [1])
    pos, vel = np.zeros((k, m, 3)), np.zeros((k, m, 3))
    mask = np.zeros((k, m), dtype=bool)
    for i, (p, v) in enumerate(zip(positions, velocities, strict=True)):
        n = len(p)
        pos[i, :n], vel[i, :n], mask[i, :n] = np.reshape(p, (n, 3)), np.reshape(v, (n, 3)), True
    return pos, vel, mask


def _rows_any(mask: BoolArray) -> BoolArray:
    """Per row (K, N) -> (K,): any True."""
    return np.asarray(mask.any(axis=1), dtype=bool)


def _barrier(
    s: FloatArray, s_dot: FloatArray, a_brake: FloatArray | float, p: SeparationParams
) -> FloatArray:
    """``-α(h) - A ṡ / sqrt(2 A |s|)`` of the braking barrier for distance ``s`` to the boundary
    and its rate ``ṡ`` (the part of the bound on the normal acceleration common to pairs and
    walls)."""
    h = np.sign(s) * np.sqrt(2.0 * a_brake * np.abs(s)) + s_dot
    alpha = p.gamma_1_s * h * (1.0 + (h / p.h_scale_m_s) ** 2)
    return -alpha - a_brake * s_dot / np.sqrt(2.0 * a_brake * np.maximum(np.abs(s), _S_EPS_M))


def _pair_rows(
    own_pos: FloatArray,
    own_vel: FloatArray,
    nb_pos: FloatArray,
    nb_vel: FloatArray,
    share: FloatArray,
    p: SeparationParams,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Normals n (K, M, 3), bounds c (K, M) of ``n·u_i >= c``, distances ρ (K, M)."""
    r = own_pos[:, None, :] - nb_pos
    rho = np.linalg.norm(r, axis=-1)
    n = np.where(rho[..., None] > 1e-9, r / np.maximum(rho, 1e-9)[..., None], [1.0, 0.0, 0.0])
    w = own_vel[:, None, :] - nb_vel
    rho_dot = np.einsum("kmi,kmi->km", n, w)
    tangential2 = np.maximum(np.einsum("kmi,kmi->km", w, w) - rho_dot**2, 0.0)
    a_pair = p.brake_m_s2 / share
    c_pair = _barrier(rho - p.distance_m, rho_dot, a_pair, p)
    c_pair -= tangential2 / np.maximum(rho, p.distance_m * 0.5)
    return n, np.minimum(share * c_pair, p.brake_m_s2), rho


#: Room (relative, of 1 + the magnitudes compared) the pre-check leaves for rounding.
_PRECHECK_SLACK = 1e-9


def nobody_near(
    own_pos_ned_m: FloatArray,
    own_vel_ned_m_s: FloatArray,
    accel_ned_m_s2: FloatArray,
    nb_owner: IntArray,
    nb_pos_ned_m: FloatArray,
    nb_vel_ned_m_s: FloatArray,
    params: SeparationParams,
    common_accel_ned_m_s2: FloatArray | None = None,
) -> tuple[BoolArray, FloatArray]:
    """The cheap exact pre-check of :func:`filter_accelerations` (default ``nb_share`` and
    ``floor_on``): per agent (K,), True where the filter provably returns the command unchanged
    and not ``active``, and the distance to the nearest neighbour (K,) (inf if none).

    Neighbours flat: ``nb_owner`` (P,) the agent of each, ``nb_pos_ned_m``, ``nb_vel_ned_m_s``
    (P, 3). Each barrier is bounded over the direction it acts in, which needs no pairing and no
    QP: a pair holds for every command if ``share c(ρ, |w|) + |u_i - a| < 0`` (``c`` bounded by
    :func:`_barrier_bound` with the relative speed ``|w|``, the tangential term dropped, ``a`` the
    common acceleration), a wall if ``c(s, |v_i|) + |u_i| < 0``, with room for rounding. False
    means only "not sure": the filter decides. Far from everyone (a formation 2 m apart at rest
    needs 11 m/s² of command towards a neighbour to be unsure) it is True. One compiled loop
    over the agents, pairs and walls (drone_agent/core/jit_math.py)."""
    own_pos = f64(own_pos_ned_m).reshape(-1, 3)
    own_vel = f64(own_vel_ned_m_s).reshape(-1, 3)
    u0 = f64(accel_ned_m_s2).reshape(-1, 3)
    k = own_pos.shape[0]
    rel = u0 if common_accel_ned_m_s2 is None else f64(u0 - common_accel_ned_m_s2)
    sure = np.ones(k, dtype=bool)
    closest = np.full(k, np.inf)
    m, b, is_floor = _walls_of(params)
    _precheck_rows(
        own_pos,
        own_vel,
        u0,
        rel,
        np.ascontiguousarray(nb_owner, dtype=np.intp),
        f64(nb_pos_ned_m).reshape(-1, 3),
        f64(nb_vel_ned_m_s).reshape(-1, 3),
        m,
        b,
        is_floor,
        (
            float(params.share),
            float(params.distance_m),
            float(params.brake_m_s2),
            float(params.gamma_1_s),
            float(params.h_scale_m_s),
            float(params.wall_margin_m),
        ),
        sure,
        closest,
    )
    return sure, closest


@jit
def _barrier_bound(s: float, speed: float, a_brake: float, gamma: float, h_scale: float) -> float:
    """An upper bound of :func:`_barrier` ``(s, ṡ, a_brake)`` over every rate ``|ṡ| <= speed``,
    for ``s > 0`` (+inf elsewhere): ``α`` is increasing, so ``-α(h) <= -α(sqrt(2 A s) - speed)``,
    and ``-A ṡ <= A speed``."""
    h = np.sqrt(2.0 * a_brake * nmax(s, 0.0)) - speed
    alpha = gamma * h * (1.0 + (h / h_scale) ** 2)
    bound = a_brake * speed / np.sqrt(2.0 * a_brake * nmax(s, _S_EPS_M)) - alpha
    return bound if s > 0.0 else np.inf


@jit
def _norm3(x: float, y: float, z: float) -> float:
    return np.sqrt(x * x + y * y + z * z)


@jit
def _sure_below(c: float, u: float) -> bool:
    """``c + u < 0`` with room for rounding (:data:`_PRECHECK_SLACK`; NaN: not sure)."""
    return c + u < -_PRECHECK_SLACK * (1.0 + abs(c) + u)


@jit
def _precheck_rows(  # type: ignore[no-untyped-def]
    own_pos, own_vel, u0, rel, owner, nb_pos, nb_vel, m, b, is_floor, p, sure, closest
):
    """:func:`nobody_near`'s pairs (each clears its agent or not) and walls, per agent."""
    share, distance, brake, gamma, h_scale, wall_margin = p
    for t in range(owner.shape[0]):
        i = owner[t]
        rho = _norm3(
            own_pos[i, 0] - nb_pos[t, 0], own_pos[i, 1] - nb_pos[t, 1], own_pos[i, 2] - nb_pos[t, 2]
        )
        speed = _norm3(
            own_vel[i, 0] - nb_vel[t, 0], own_vel[i, 1] - nb_vel[t, 1], own_vel[i, 2] - nb_vel[t, 2]
        )
        c = share * _barrier_bound(rho - distance, speed, brake / share, gamma, h_scale)
        if not _sure_below(c, _norm3(rel[i, 0], rel[i, 1], rel[i, 2])):
            sure[i] = False
        closest[i] = nmin(closest[i], rho)
    for i in range(own_pos.shape[0]):
        speed_own = _norm3(own_vel[i, 0], own_vel[i, 1], own_vel[i, 2])
        u_abs = _norm3(u0[i, 0], u0[i, 1], u0[i, 2])
        for w in range(b.shape[0]):
            s = own_pos[i, 0] * m[w, 0] + own_pos[i, 1] * m[w, 1] + own_pos[i, 2] * m[w, 2] - b[w]
            c_wall = _barrier_bound(s - wall_margin, speed_own, brake, gamma, h_scale)
            ok = _sure_below(c_wall, u_abs)
            # the floor binds only agents at or above it: one surely below is not bound
            if is_floor[w] and s < -_PRECHECK_SLACK * (1.0 + abs(b[w])):
                ok = True
            if not ok:
                sure[i] = False


_LAST_WALLS: list[tuple[SeparationParams, tuple[FloatArray, FloatArray, BoolArray]]] = []


def _walls_of(p: SeparationParams) -> tuple[FloatArray, FloatArray, BoolArray]:
    """:func:`_walls`, remembered for the last parameter object (the layer passes the same one
    every tick: no hashing of the parameters each call)."""
    if _LAST_WALLS and _LAST_WALLS[0][0] is p:
        return _LAST_WALLS[0][1]
    walls = _walls(p)
    _LAST_WALLS[:] = [(p, walls)]
    return walls


@lru_cache(maxsize=32)
def _walls(p: SeparationParams) -> tuple[FloatArray, FloatArray, BoolArray]:
    """Inward normals m (W, 3), offsets b (W,) (inside: m·x >= b), and which is the floor
    (read-only arrays, made once per parameter set)."""
    normals: list[FloatArray] = []
    offsets: list[float] = []
    if p.floor_m is not None:
        normals.append(_UP)
        offsets.append(p.floor_m)
    for axis, fence in ((0, p.fence_north_m), (1, p.fence_east_m)):
        if fence is not None:
            e = np.eye(3)[axis]
            normals += [e, -e]
            offsets += [fence[0], -fence[1]]
    if p.ceiling_m is not None:
        normals.append(-_UP)
        offsets.append(-p.ceiling_m)
    is_floor = np.zeros(len(offsets), dtype=bool)
    is_floor[: int(p.floor_m is not None)] = True
    out = (np.reshape(normals, (-1, 3)).astype(float), np.array(offsets, dtype=float), is_floor)
    for a in out:  # shared by every call with these parameters (cached)
        a.flags.writeable = False
    return out


def _wall_rows(
    own_pos: FloatArray, own_vel: FloatArray, p: SeparationParams, floor_on: BoolArray | None
) -> tuple[FloatArray, FloatArray, BoolArray, BoolArray]:
    """Normals (W, 3), bounds c (K, W), which are in force (K, W), which is the floor (W,)."""
    m, b, is_floor = _walls_of(p)
    s = own_pos @ m.T - b
    c = _barrier(s - p.wall_margin_m, own_vel @ m.T, p.brake_m_s2, p)
    in_force = np.ones_like(s, dtype=bool)
    # the floor binds agents above it (not one taking off), or those the caller names
    in_force[:, is_floor] = (s[:, is_floor] >= 0.0) if floor_on is None else floor_on[:, None]
    return m, np.minimum(c, p.brake_m_s2), in_force, is_floor


def filter_accelerations(
    own_pos_ned_m: FloatArray,
    own_vel_ned_m_s: FloatArray,
    accel_ned_m_s2: FloatArray,
    nb_pos_ned_m: FloatArray,
    nb_vel_ned_m_s: FloatArray,
    nb_mask: BoolArray,
    params: SeparationParams,
    nb_share: FloatArray | None = None,
    common_accel_ned_m_s2: FloatArray | None = None,
    floor_on: BoolArray | None = None,
) -> SeparationResult:
    """Filter the commanded accelerations (K, 3) of K agents at positions and velocities (K, 3),
    each with up to M neighbours (K, M, 3) where ``nb_mask`` (K, M) (see :func:`pad_neighbours`;
    entries that are not finite are left out). All NED, SI units. Optional:

    - ``nb_share`` (K, M): the agent's part of each pair constraint (default ``params.share``;
      1 for a neighbour known not to avoid, e.g. a failed vehicle);
    - ``common_accel_ned_m_s2`` (K, 3) or (3,): an acceleration every agent knows alike, e.g.
      the plan's centre acceleration. Each agent then takes its share of a pair constraint
      relative to it, ``n·(u_i - a) >= share c``; the two halves still add up to the pair's
      ``n·(u_i - u_j) >= c`` (the ``a`` cancels), but a formation accelerating as one no longer
      looks like drones accelerating at each other. Default 0.
    - ``floor_on`` (K,): who keeps the floor (e.g. agents flying the formation); default: agents
      at or above ``floor_m``.
    """
    own_pos = np.asarray(own_pos_ned_m, dtype=float).reshape(-1, 3)
    own_vel = np.asarray(own_vel_ned_m_s, dtype=float).reshape(-1, 3)
    u0 = np.asarray(accel_ned_m_s2, dtype=float).reshape(-1, 3)
    nb_pos = np.asarray(nb_pos_ned_m, dtype=float)
    nb_vel = np.asarray(nb_vel_ned_m_s, dtype=float)
    finite = np.isfinite(nb_pos).all(axis=-1) & np.isfinite(nb_vel).all(axis=-1)
    mask = np.asarray(nb_mask, dtype=bool) & finite
    nb_pos, nb_vel = (
        np.where(finite[..., None], nb_pos, 0.0),
        np.where(finite[..., None], nb_vel, 0.0),
    )
    share = np.full(mask.shape, params.share) if nb_share is None else np.asarray(nb_share)
    n, c, rho = _pair_rows(own_pos, own_vel, nb_pos, nb_vel, share, params)
    if common_accel_ned_m_s2 is not None:
        common = np.broadcast_to(np.asarray(common_accel_ned_m_s2, dtype=float), own_pos.shape)
        c = c + np.einsum("kmi,ki->km", n, common)
    floor_mask = None if floor_on is None else np.asarray(floor_on, dtype=bool).reshape(-1)
    m, c_wall, in_force, is_floor = _wall_rows(own_pos, own_vel, params, floor_mask)
    pair_short = np.where(mask, c - np.einsum("kmi,ki->km", n, u0), -np.inf)
    wall_short = np.where(in_force, c_wall - u0 @ m.T, -np.inf)
    pair_hit, wall_hit = pair_short > 0.0, wall_short > 0.0
    separation, wall_any = _rows_any(pair_hit), _rows_any(wall_hit)
    active = separation | wall_any
    out = u0.copy()
    infeasible = np.zeros(len(u0), dtype=bool)
    box_g, box_b = params.accel.rows()
    for i in np.flatnonzero(active):
        right = np.column_stack((n[i, :, 1], -n[i, :, 0], np.zeros(n.shape[1])))
        bias = params.right_bias * np.maximum(pair_short[i], 0.0) @ right
        rows = mask[i]
        g = np.vstack((n[i, rows], m[in_force[i]], box_g))
        b = np.concatenate((c[i, rows], c_wall[i, in_force[i]], box_b))
        soft = np.arange(len(b)) < len(b) - len(box_b)
        result = project(u0[i] + bias, g, b, soft)
        out[i], infeasible[i] = result.u, not result.feasible
    return SeparationResult(
        accel_ned_m_s2=out,
        active=active,
        closest_m=np.where(mask, rho, np.inf).min(axis=1, initial=np.inf),
        n_constraints=(pair_hit.sum(axis=1) + wall_hit.sum(axis=1)).astype(np.intp),
        separation=separation,
        floor=_rows_any(wall_hit[:, is_floor]),
        fence=_rows_any(wall_hit[:, ~is_floor]),
        infeasible=infeasible,
    )
