"""The per-vehicle rules of the simulated quadcopter, written once: attitude controller, mixer,
rotor wrench, motor lag, rigid-body derivative, RK4 and ground contact, on one vehicle's plain
floats.

Each rule is plain Python over floats and a (13,) state row (the layout of
:mod:`sitl_sim.physics.dynamics`), compiled by numba as it is
(:func:`protocols.runtime.compiled.jit`, inlined into the loops that call it), so the simulator's
vehicles (:class:`sitl_sim.physics.kernel.PhysicsKernel`, through
:func:`sitl_sim.physics.jit.advance`), :func:`sitl_sim.physics.dynamics.step` and
:func:`sitl_sim.physics.mixer.mix` all run this code; the loops of the last two (the rigid body
alone, the mixer alone, over N vehicles) end this module. The maths is that of the modules' docs:
attitude_control (eq. 20, 36-39 as corrected), mixer (eq. 3 inverted, with its saturation), dynamics
(eq. 3-6, RK4 with the quaternion re-normalised, then ground contact), the motors' lag
(sitl_sim/physics/vehicle_params.py; exact over a step, :func:`rk4_lagged_into`). No
``fastmath``: IEEE arithmetic term by term as written; ``math``'s functions are the C library's.
The numpy versions these replaced are the tests' oracle (tests/physics_oracle.py).

A fleet's parameters reach the rules as one float array (:func:`constants`, indexed by the names
below): numba then compiles one loop for every fleet.
"""

from __future__ import annotations

import math

import numpy as np

from protocols.model.frames import G_M_S2, FloatArray, yaw_from_wxyz, zyx_from_wxyz
from protocols.runtime.compiled import jit
from sitl_sim.physics.vehicle_params import VehicleParams

# The constants of one fleet, packed for the compiled loops (indices into ``constants()``).
(H, F_MIN, F_MAX, TOL, MAX_THRUST, HALF_ARM_INV, YAW_SHARE, INV_C, C, ARM, YAW_K,
 INV_MASS, WEIGHT, IXX, IYY, IZZ, ARM_LIMIT, YAW_LIMIT, E0, E1, E2, G,
 MIN_COS, AIR, DRAG_XY, DRAG_Z, LAG, DECAY_MID, DECAY_END, N_CONSTANTS) = range(30)  # fmt: skip


def euler_coeffs(params: VehicleParams) -> tuple[float, float, float]:
    """Inertia ratios of Euler's equations: ``(Iyy-Izz)/Ixx, (Izz-Ixx)/Iyy, (Ixx-Iyy)/Izz``."""
    ixx, iyy, izz = params.ixx, params.iyy, params.izz
    return (iyy - izz) / ixx, (izz - ixx) / iyy, (ixx - iyy) / izz


def constants(params: VehicleParams, dt_s: float, min_cos_pitch: float = math.nan) -> FloatArray:
    """The fleet's constants (N_CONSTANTS,) in the order of the indices above; ``dt_s`` the
    sub-step (s), ``min_cos_pitch`` the attitude controller's
    (:data:`sitl_sim.physics.attitude_control.MIN_COS_PITCH`, which :mod:`sitl_sim.physics.jit`
    gives: the rigid body and the mixer do not use it)."""
    f_min, f_max = params.rotor_force_min_n, params.rotor_force_max_n
    span = f_max - f_min
    c = np.empty(N_CONSTANTS)
    c[H] = dt_s
    c[F_MIN], c[F_MAX], c[TOL] = f_min, f_max, 1e-9 * f_max
    c[MAX_THRUST] = params.max_thrust_n
    c[HALF_ARM_INV] = 0.5 / params.arm_m
    c[YAW_SHARE] = 0.25 / params.yaw_moment_per_thrust_m
    c[INV_C], c[C] = 1.0 / params.thrust_coeff, params.thrust_coeff
    c[ARM], c[YAW_K] = params.arm_m, params.yaw_moment_per_thrust_m
    c[INV_MASS], c[WEIGHT] = 1.0 / params.mass_kg, params.weight_n
    c[IXX], c[IYY], c[IZZ] = params.ixx, params.iyy, params.izz
    c[ARM_LIMIT], c[YAW_LIMIT] = span * params.arm_m, 2.0 * span * params.yaw_moment_per_thrust_m
    c[E0], c[E1], c[E2] = euler_coeffs(params)
    c[G], c[MIN_COS] = G_M_S2, min_cos_pitch
    # the body's drag per mass (1/s); AIR says whether there is any (else the air is not read)
    c[DRAG_XY] = params.body_drag_xy_n_s_m / params.mass_kg
    c[DRAG_Z] = params.body_drag_z_n_s_m / params.mass_kg
    c[AIR] = 1.0 if c[DRAG_XY] > 0.0 or c[DRAG_Z] > 0.0 else 0.0
    # the motors' lag: LAG says whether there is any (else the rotors follow their commands at
    # once), DECAY_* how much of a rotor's speed error is left after half a sub-step and after one
    tau = params.motor_tau_s
    c[LAG] = 1.0 if tau > 0.0 else 0.0
    c[DECAY_MID] = math.exp(-0.5 * dt_s / tau) if tau > 0.0 else 0.0
    c[DECAY_END] = math.exp(-dt_s / tau) if tau > 0.0 else 0.0
    return c


# the quaternion formulas of protocols.model.frames, compiled as they are
_yaw_of = jit(yaw_from_wxyz, inline="always")
_zyx_of = jit(zyx_from_wxyz, calls={"yaw_from_wxyz": _yaw_of}, inline="always")


# -- the attitude controller (sitl_sim/physics/attitude_control.py's doc)
# --------------------------------
@jit(inline="always", calls={"zyx_from_wxyz": _zyx_of})
def attitude_moments(  # type: ignore[no-untyped-def]
    s, roll_d, pitch_d, yaw_d, kp0, kp1, kp2, kd0, kd1, kd2, c
):
    """Body moments ``(l, m, n)`` N m driving the attitude of state ``s`` (13,) to the ZYX
    setpoint ``(roll_d, pitch_d, yaw_d)`` rad with PD gains ``kp`` 1/s^2, ``kd`` 1/s, no
    feed-forward: feedback linearisation (eq. 20, 36-39), the yaw error wrapped to [-pi, pi)."""
    w, x, y, z, p, q, r = s[6], s[7], s[8], s[9], s[10], s[11], s[12]
    yaw, pitch, roll = zyx_from_wxyz(w, x, y, z)
    sphi, cphi = math.sin(roll), math.cos(roll)
    sth, cth = math.sin(pitch), math.cos(pitch)
    # Euler-angle rates from body rates (eq. 20), cos(pitch) kept away from 0
    ctheta = max(cth, c[MIN_COS])
    ttheta = sth / ctheta
    qr_roll = sphi * q + cphi * r
    phid = p + ttheta * qr_roll
    thd = cphi * q - sphi * r
    psid = qr_roll / ctheta
    # PD on the angles
    e0, e1 = roll_d - roll, pitch_d - pitch
    e2 = (yaw_d - yaw + math.pi) % (2.0 * math.pi) - math.pi
    tau0 = kp0 * e0 + kd0 * -phid
    tau1 = kp1 * e1 + kd1 * -thd
    tau2 = kp2 * e2 + kd2 * -psid
    # omega' = E tau + E' eta'
    od0 = tau0 - sth * tau2 - cth * thd * psid
    od1 = (
        cphi * tau1
        + sphi * cth * tau2
        - sphi * phid * thd
        + (cphi * cth * phid - sphi * sth * thd) * psid
    )
    od2 = (
        -sphi * tau1
        + cphi * cth * tau2
        - cphi * phid * thd
        - (sphi * cth * phid + cphi * sth * thd) * psid
    )
    # eq. 39
    m_l = c[IXX] * od0 + (c[IZZ] - c[IYY]) * (q * r)
    m_m = c[IYY] * od1 + (c[IXX] - c[IZZ]) * (p * r)
    m_n = c[IZZ] * od2 + (c[IYY] - c[IXX]) * (p * q)
    return m_l, m_m, m_n


# -- the mixer (sitl_sim/physics/mixer.py's doc)
# ---------------------------------------------------------
@jit(inline="always")
def collective_thrust(thrust_normalised, c):  # type: ignore[no-untyped-def]
    """The thrust demand (N) of a normalised one (a fraction of the maximum, clipped to [0, 1]),
    limited as :func:`mix` limits it (NaN counts as 0)."""
    return limited_thrust(min(max(thrust_normalised, 0.0), 1.0) * c[MAX_THRUST], c)


@jit(inline="always")
def limited_thrust(thrust_n, c):  # type: ignore[no-untyped-def]
    """A thrust demand (N) the four rotors could produce: NaN counts as 0, then limited to
    ``[4 F_min, 4 F_max]``."""
    t = 0.0 if thrust_n != thrust_n else thrust_n
    return min(max(t, 4.0 * c[F_MIN]), 4.0 * c[F_MAX])


@jit(inline="always")
def _room(base, share, f_min, f_max, tol):  # type: ignore[no-untyped-def]
    """How much of its yaw ``share`` a rotor whose other shares add up to ``base`` can take:
    inf for a share within round-off of 0."""
    mag = abs(share)
    if not mag > tol:
        return math.inf
    return (f_max - base if share > 0.0 else base - f_min) / mag


@jit(inline="always")
def mix(thrust_n, m_l, m_m, m_n, c):  # type: ignore[no-untyped-def]
    """Rotor speeds ``(w1, w2, w3, w4)`` rad/s realising the thrust (N, limited already:
    :func:`limited_thrust`) and moments N m where possible: NaN moments count as 0 and each is
    limited to what the rotors could ever produce, the yaw share is scaled down just enough for
    every rotor force to fit ``[F_min, F_max]`` (within round-off), then each force is clipped."""
    f_min, f_max, tol = c[F_MIN], c[F_MAX], c[TOL]
    arm_lim, yaw_lim = c[ARM_LIMIT], c[YAW_LIMIT]
    m_l = 0.0 if m_l != m_l else min(max(m_l, -arm_lim), arm_lim)
    m_m = 0.0 if m_m != m_m else min(max(m_m, -arm_lim), arm_lim)
    m_n = 0.0 if m_n != m_n else min(max(m_n, -yaw_lim), yaw_lim)
    quarter_t = 0.25 * thrust_n
    b0 = quarter_t + c[HALF_ARM_INV] * m_l
    b1 = quarter_t + c[HALF_ARM_INV] * m_m
    b2 = quarter_t - c[HALF_ARM_INV] * m_l
    b3 = quarter_t - c[HALF_ARM_INV] * m_m
    ys = m_n * c[YAW_SHARE]
    t0, t1, t2, t3 = b0 + ys, b1 - ys, b2 + ys, b3 - ys
    fit_lo, fit_hi = f_min - tol, f_max + tol
    if not (
        fit_lo <= t0 <= fit_hi
        and fit_lo <= t1 <= fit_hi
        and fit_lo <= t2 <= fit_hi
        and fit_lo <= t3 <= fit_hi
    ):  # scale the yaw share down
        scale = min(
            _room(b0, ys, f_min, f_max, tol),
            _room(b1, -ys, f_min, f_max, tol),
            _room(b2, ys, f_min, f_max, tol),
            _room(b3, -ys, f_min, f_max, tol),
        )
        scale = min(max(scale, 0.0), 1.0)
        t0, t1 = b0 + scale * ys, b1 + scale * -ys
        t2, t3 = b2 + scale * ys, b3 + scale * -ys
    inv_c = c[INV_C]
    return (
        math.sqrt(min(max(t0, f_min), f_max) * inv_c),
        math.sqrt(min(max(t1, f_min), f_max) * inv_c),
        math.sqrt(min(max(t2, f_min), f_max) * inv_c),
        math.sqrt(min(max(t3, f_min), f_max) * inv_c),
    )


# -- the rigid body (sitl_sim/physics/dynamics.py's doc)
# -------------------------------------------------
@jit(inline="always")
def rotor_wrench(w0, w1, w2, w3, c):  # type: ignore[no-untyped-def]
    """Thrust (N) and the specific inputs of rotor speeds rad/s (eq. 3-4): thrust per mass
    (m/s^2) and the body moments per inertia (rad/s^2)."""
    cf = c[C]
    f0, f1, f2, f3 = cf * (w0 * w0), cf * (w1 * w1), cf * (w2 * w2), cf * (w3 * w3)
    thrust = f0 + f1 + f2 + f3
    a0 = ((f0 - f2) * c[ARM]) / c[IXX]
    a1 = ((f1 - f3) * c[ARM]) / c[IYY]
    a2 = ((f0 - f1 + f2 - f3) * c[YAW_K]) / c[IZZ]
    return thrust, thrust * c[INV_MASS], a0, a1, a2


@jit(inline="always")
def derivative_into(out, st, t_m, a0, a1, a2, c, air):  # type: ignore[no-untyped-def]
    """The derivative (13,) of the state ``st`` (13,) into ``out`` under thrust per mass ``t_m``
    m/s^2 and moments per inertia ``(a0, a1, a2)`` rad/s^2: ``a = g e3 - (T/m) R_b e3``,
    ``q' = 0.5 q (0, p, q, r)`` and Euler's equations (eq. 6 corrected); with body drag
    (``c[AIR]``), ``- R_b diag(d_xy, d_xy, d_z) R_b^T (v - air) / m`` more, ``air`` (3,) the
    air's velocity NED (m/s) held over the step."""
    w, x, y, z, p, q, r = st[6], st[7], st[8], st[9], st[10], st[11], st[12]
    two_t_m = t_m + t_m
    hp, hq, hr = 0.5 * p, 0.5 * q, 0.5 * r
    out[0], out[1], out[2] = st[3], st[4], st[5]
    # R_b e3 = [2(xz + wy), 2(yz - wx), 1 - 2(x^2 + y^2)]
    out[3] = -two_t_m * (x * z + w * y)
    out[4] = -two_t_m * (y * z - w * x)
    out[5] = c[G] - t_m + two_t_m * (x * x + y * y)
    if c[AIR] != 0.0:
        drag_into(out, st, c, air)
    out[6] = -(x * hp + y * hq + z * hr)
    out[7] = w * hp + y * hr - z * hq
    out[8] = w * hq + z * hp - x * hr
    out[9] = w * hr + x * hq - y * hp
    out[10] = c[E0] * (q * r) + a0
    out[11] = c[E1] * (p * r) + a1
    out[12] = c[E2] * (p * q) + a2


@jit(inline="always")
def drag_into(out, st, c, air):  # type: ignore[no-untyped-def]
    """Add the body's drag per mass to the acceleration ``out[3:6]``: the airspeed ``v - air``
    into the body frame, each axis's drag (``c[DRAG_XY]``, ``c[DRAG_XY]``, ``c[DRAG_Z]``, 1/s),
    back to NED."""
    w, x, y, z = st[6], st[7], st[8], st[9]
    ux, uy, uz = st[3] - air[0], st[4] - air[1], st[5] - air[2]
    # R_b (body -> NED) of the unit quaternion (w, x, y, z)
    r00, r01, r02 = 1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y)
    r10, r11, r12 = 2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x)
    r20, r21, r22 = 2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y)
    bx = (r00 * ux + r10 * uy + r20 * uz) * c[DRAG_XY]
    by = (r01 * ux + r11 * uy + r21 * uz) * c[DRAG_XY]
    bz = (r02 * ux + r12 * uy + r22 * uz) * c[DRAG_Z]
    out[3] -= r00 * bx + r01 * by + r02 * bz
    out[4] -= r10 * bx + r11 * by + r12 * bz
    out[5] -= r20 * bx + r21 * by + r22 * bz


@jit(inline="always")
def rk4_into(s, t_m, a0, a1, a2, c, k1, k2, k3, k4, xt, air):  # type: ignore[no-untyped-def]
    """One classic Runge-Kutta step of ``c[H]`` s of the state ``s`` (13,) in place (inputs held
    over the step, and the air's velocity ``air`` (3,) NED), the quaternion re-normalised;
    ``k1``..``k4``, ``xt`` (13,) are scratch."""
    held = (t_m, a0, a1, a2)
    rk4_inputs_into(s, held, held, held, c, k1, k2, k3, k4, xt, air)


@jit(inline="always")
def rk4_inputs_into(s, u0, u_mid, u1, c, k1, k2, k3, k4, xt, air):  # type: ignore[no-untyped-def]
    """:func:`rk4_into` with inputs that change over the step: ``u0``, ``u_mid`` and ``u1`` are
    the inputs ``(t_m, a0, a1, a2)`` at its start, middle and end (RK4's stage times)."""
    h = c[H]
    half_h, sixth_h = 0.5 * h, h / 6.0
    derivative_into(k1, s, u0[0], u0[1], u0[2], u0[3], c, air)
    for j in range(13):
        xt[j] = k1[j] * half_h + s[j]
    derivative_into(k2, xt, u_mid[0], u_mid[1], u_mid[2], u_mid[3], c, air)
    for j in range(13):
        xt[j] = k2[j] * half_h + s[j]
    derivative_into(k3, xt, u_mid[0], u_mid[1], u_mid[2], u_mid[3], c, air)
    for j in range(13):
        xt[j] = k3[j] * h + s[j]
    derivative_into(k4, xt, u1[0], u1[1], u1[2], u1[3], c, air)
    for j in range(13):
        acc = k2[j] + k3[j]
        acc = acc + acc
        acc = acc + k1[j]
        acc = acc + k4[j]
        s[j] = acc * sixth_h + s[j]
    norm = math.sqrt(s[6] * s[6] + s[7] * s[7] + s[8] * s[8] + s[9] * s[9])
    s[6], s[7], s[8], s[9] = s[6] / norm, s[7] / norm, s[8] / norm, s[9] / norm


# -- the motors' lag (sitl_sim/physics/vehicle_params.py's doc)
# ------------------------------------------
@jit(inline="always")
def lagged(w, cmd, decay):  # type: ignore[no-untyped-def]
    """A rotor's speed (rad/s) at ``w`` that follows ``cmd`` as a first-order lag, once the
    error has decayed to ``decay`` of itself (``exp(-t / tau)`` after ``t`` s): exact, as the
    command is held."""
    return cmd + (w - cmd) * decay


@jit(inline="always")
def rk4_lagged_into(  # type: ignore[no-untyped-def]
    s, w0, w1, w2, w3, u0, u1, u2, u3, c, k1, k2, k3, k4, xt, air
):
    """One RK4 step (:func:`rk4_inputs_into`) of the state ``s`` (13,) in place, its rotors at
    ``(w0..w3)`` rad/s following the commands ``(u0..u3)`` rad/s held over the step with the
    motors' lag (``c[DECAY_MID]``, ``c[DECAY_END]``): the rotor speeds are exact at each stage
    time (the lag does not depend on the body's state), their wrench is the stage's input.
    Returns the thrust (N) and the rotor speeds at the step's end."""
    dm, de = c[DECAY_MID], c[DECAY_END]
    m0, m1 = lagged(w0, u0, dm), lagged(w1, u1, dm)
    m2, m3 = lagged(w2, u2, dm), lagged(w3, u3, dm)
    e0, e1 = lagged(w0, u0, de), lagged(w1, u1, de)
    e2, e3 = lagged(w2, u2, de), lagged(w3, u3, de)
    _, tm0, a00, a01, a02 = rotor_wrench(w0, w1, w2, w3, c)
    _, tmm, am0, am1, am2 = rotor_wrench(m0, m1, m2, m3, c)
    thrust, tm1, a10, a11, a12 = rotor_wrench(e0, e1, e2, e3, c)
    rk4_inputs_into(
        s, (tm0, a00, a01, a02), (tmm, am0, am1, am2), (tm1, a10, a11, a12), c,
        k1, k2, k3, k4, xt, air,
    )  # fmt: skip
    return thrust, e0, e1, e2, e3


@jit(inline="always", calls={"yaw_from_wxyz": _yaw_of})
def ground_contact(s, x0, y0, z0, vz0, thrust, c):  # type: ignore[no-untyped-def]
    """Ground contact on the state ``s`` (13,) in place, reached over a step from a state at
    ``(x0, y0, z0)`` m moving down at ``vz0`` m/s under ``thrust`` N. Returns whether it is on
    the ground, whether it was moving down (touching down) and then its touchdown speed m/s.

    At or below the ground: put on it; moving down (or resting: thrust below the weight) its
    velocity and rates are zeroed, and if it started on the ground it keeps its place; resting,
    it is levelled (yaw kept)."""
    z1, vz1 = s[2], s[5]
    if not z1 >= 0.0:
        return False, False, 0.0
    frac = 0.0
    if z0 < 0.0:  # the fraction of the step at which the ground was reached
        dz = z1 - z0
        frac = min(max(-z0 / (dz if dz > 0.0 else 1.0), 0.0), 1.0)
    moving_down = vz1 > 0.0
    impact = max(vz0 + frac * (vz1 - vz0), 0.0) if moving_down else 0.0
    resting = thrust < c[WEIGHT]
    s[2] = 0.0
    if moving_down or resting:
        s[3] = s[4] = s[5] = 0.0
        s[10] = s[11] = s[12] = 0.0
        if z0 >= 0.0:
            s[0], s[1] = x0, y0
    if resting:
        yaw = yaw_from_wxyz(s[6], s[7], s[8], s[9])
        s[6], s[7], s[8], s[9] = math.cos(0.5 * yaw), 0.0, 0.0, math.sin(0.5 * yaw)
    return True, moving_down, impact


# -- the rules over N vehicles (columns of a (13, N) state) --------------------------------------
@jit
def contact_column(s, x0, y0, z0, vz0, thrust, c, impacts, i):  # type: ignore[no-untyped-def]
    """:func:`ground_contact` on vehicle ``i``'s state ``s`` (13,) in place, its touchdown speed
    into ``impacts[i]`` (left as it is where none); whether it is on the ground."""
    on_ground, moving_down, impact = ground_contact(s, x0, y0, z0, vz0, thrust, c)
    if on_ground and moving_down:
        impacts[i] = impact
    return on_ground


@jit
def advance_rotors(
    state: FloatArray,
    rotor: FloatArray,
    c: FloatArray,
    new: FloatArray,
    impacts: FloatArray,
    air: FloatArray,
) -> bool:  # pragma: no cover - compiled
    """One sub-step of every vehicle under rotor speeds ``rotor`` (4, N) rad/s held over it, in
    air moving at ``air`` (3, N) m/s NED: ``new`` (13, N) the state, ``impacts`` (N,) the
    touchdown speeds (0 where none). Returns whether any vehicle was on the ground after it."""
    s, xt = np.empty(13), np.empty(13)
    k1, k2, k3, k4 = np.empty(13), np.empty(13), np.empty(13), np.empty(13)
    touched = False
    for i in range(state.shape[1]):
        s[:] = state[:, i]
        thrust, t_m, a0, a1, a2 = rotor_wrench(
            rotor[0, i], rotor[1, i], rotor[2, i], rotor[3, i], c
        )
        x0, y0, z0, vz0 = s[0], s[1], s[2], s[5]
        rk4_into(s, t_m, a0, a1, a2, c, k1, k2, k3, k4, xt, air[:, i])
        if contact_column(s, x0, y0, z0, vz0, thrust, c, impacts, i):
            touched = True
        new[:, i] = s
    return touched


@jit
def contact_rows(
    new: FloatArray, prev: FloatArray, thrust_n: FloatArray, c: FloatArray, impacts: FloatArray
) -> bool:  # pragma: no cover - compiled
    """Ground contact on every vehicle's state ``new`` (13, N) in place, reached from ``prev``
    (13, N) under thrust (N,) N: ``impacts`` (N,) the touchdown speeds (0 where none). Returns
    whether any vehicle is on the ground."""
    touched = False
    for i in range(new.shape[1]):
        s = new[:, i].copy()
        if contact_column(
            s, prev[0, i], prev[1, i], prev[2, i], prev[5, i], thrust_n[i], c, impacts, i
        ):
            touched = True
        new[:, i] = s
    return touched


@jit
def derivative_rows(
    state: FloatArray,
    t_m: FloatArray,
    alpha: FloatArray,
    c: FloatArray,
    out: FloatArray,
    air: FloatArray,
) -> None:  # pragma: no cover - compiled
    """The derivative (13, N) of every vehicle's state (13, N) into ``out`` under thrust per
    mass (N,) m/s^2 and moments per inertia (3, N) rad/s^2, in air moving at ``air`` (3, N)."""
    s, d = np.empty(13), np.empty(13)
    for i in range(state.shape[1]):
        s[:] = state[:, i]
        derivative_into(d, s, t_m[i], alpha[0, i], alpha[1, i], alpha[2, i], c, air[:, i])
        out[:, i] = d


@jit
def mix_rows(thrust_n: FloatArray, moments: FloatArray, c: FloatArray, out: FloatArray) -> None:
    """The mixer of every vehicle: thrust (N,) N and moments (3, N) N m -> rotor speeds into
    ``out`` (4, N) rad/s."""  # pragma: no cover - compiled
    for i in range(thrust_n.shape[0]):
        t = limited_thrust(thrust_n[i], c)
        w0, w1, w2, w3 = mix(t, moments[0, i], moments[1, i], moments[2, i], c)
        out[0, i], out[1, i], out[2, i], out[3, i] = w0, w1, w2, w3
