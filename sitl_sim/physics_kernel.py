"""One physics sub-step of N vehicles, fused: inner loop, rotor wrench, RK4 and ground contact.

:class:`PhysicsKernel` does what ``inner_loop`` (:mod:`sitl_sim.inner_loop`, with an Euler-angle
setpoint) followed by ``step_with_contact`` (:mod:`sitl_sim.dynamics`, RK4) do, with the same
floating-point operations on the same operands, so it gives the same numbers bit for bit (only
commuted operands and exact sign identities such as ``a + (-b) = a - b`` differ;
tests/test_physics_kernel.py compares states, rotor speeds and touchdown speeds over hundreds of
steps with contact, saturation, NaN demands and motor failures). Those functions stay the readable
reference; this is the fast path that :class:`sitl_sim.world.World` (``swarm sim``) and
``swarm simulate`` step.

Why it is faster: at small N a numpy call costs its overhead (~0.2 us), not its arithmetic, and the
reference makes ~700 of them per sub-step, many creating temporaries, views, broadcasts or Python
float scalars (each of those costs 2-4 times a plain call). Here every buffer and view is made
once, constants are 0-d or full-width arrays (no broadcasting), every call writes into a buffer,
and the RK4 stages run on an *extended* state (:data:`_EXT_ROWS`) whose rows repeat quaternion and
rate components, so that each group of products the derivative needs (``w*(hp hq hr)``,
``(y z x)*(hr hp hq)``, ``(x y)*(z z)``, ``(q r p)*(r p q)`` ...) is one call on two aligned
views; rows of the attitude controller that share their form are computed two at a time. About
230 calls per sub-step remain, whatever N (~50 us at N = 9, ~61 us at N = 100 on the 2-core
machine, against ~150 and ~165 us for the reference). A saturated mixer scales the yaw share down
in place (as ``mixer._yaw_scale``); ground contact is applied with masks, or one vehicle at a time
in Python floats when at most :data:`_FEW_IN_CONTACT` vehicles touch the ground (a crashed drone).

Pure: no I/O, no clock. The kernel keeps scratch buffers between calls but no state: every call
takes the state and returns new arrays.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import numpy.typing as npt

from protocols.frames import G_M_S2, FloatArray
from sitl_sim.attitude_control import _MIN_COS_PITCH, AttitudeGains
from sitl_sim.dynamics import _euler_coeffs
from sitl_sim.mixer import mix
from sitl_sim.vehicle_params import VehicleParams

#: The extended RK4 state (22, N): pos 0:3, vel 3:6, then ``z z w w w x y z x y x`` 6:17 (the
#: quaternion ``w x y z`` is 10:14) and ``p q r p q`` 17:22, so that ``z z``, ``w w``, ``w w w``,
#: ``x y``, ``y x``, ``x y z``, ``y z x``, ``z x y``, ``p q r``, ``q r p`` and ``r p q`` are all
#: contiguous row slices.
_EXT_ROWS = 22

Enable = FloatArray | npt.NDArray[np.bool_] | None
#: ``substep(state, euler_des, thrust_normalised, enable) -> (state, rotor_speed, impact)``
SubStep = Callable[
    [FloatArray, FloatArray, FloatArray, Enable], tuple[FloatArray, FloatArray, FloatArray | None]
]
#: ``substeps(state, euler_des, thrust_normalised, enable, count) -> (state, rotor_speed,
#: impacts)``
SubSteps = Callable[
    [FloatArray, FloatArray, FloatArray, Enable, int],
    tuple[FloatArray, FloatArray, list[FloatArray]],
]


class PhysicsKernel:
    """Sub-steps of N vehicles sharing ``params``, each ``dt_s`` seconds (RK4).

    ``gains`` are the attitude PD gains: an :class:`AttitudeGains` (one set for every vehicle) or
    a fleet whose ``kp_col()``/``kd_col()`` are (3, N); :meth:`use_gains` changes them.
    """

    def __init__(
        self, params: VehicleParams, n: int, dt_s: float, gains: AttitudeGains | None = None
    ) -> None:
        self.params = params
        self.n = n
        self.dt_s = dt_s
        self._kp = np.empty((3, n))
        self._kd = np.empty((3, n))
        self._gains: list[FloatArray] = [self._kp, self._kd]
        g = gains if gains is not None else AttitudeGains()
        self.use_gains(g.kp_col(), g.kd_col())
        self._substep, self._substeps = _make_substep(params, n, dt_s, self._gains)

    def use_gains(self, kp: FloatArray, kd: FloatArray) -> None:
        """Attitude gains for the next sub-steps: (3, N) arrays are used as they are (so a fleet's
        live gain matrices stay live), (3, 1) or (3,) ones are spread over the N vehicles."""
        for slot, value in enumerate((kp, kd)):
            arr = np.asarray(value, dtype=np.float64)
            if arr.shape == (3, self.n):
                self._gains[slot] = arr
            else:
                own = self._kp if slot == 0 else self._kd
                own[...] = arr.reshape(3, -1)
                self._gains[slot] = own

    def substep(
        self,
        state: FloatArray,
        euler_des: FloatArray,
        thrust_normalised: FloatArray,
        enable: Enable = None,
    ) -> tuple[FloatArray, FloatArray, FloatArray | None]:
        """Advance ``state`` (13, N) by one sub-step under an attitude setpoint.

        Args:
            state: vehicle states (13, N), layout of :mod:`sitl_sim.dynamics`.
            euler_des: ZYX attitude setpoint (3, N) rad.
            thrust_normalised: collective thrust (N,) as a fraction of the maximum.
            enable: rotor speeds are multiplied by it: (N,) (armed) or (4, N) (armed and motor
                working) booleans or 0/1 floats; None: all rotors run.

        Returns:
            The new state (13, N) (a new array), the rotor speeds (4, N) rad/s applied (a new
            array: those of :func:`sitl_sim.inner_loop.inner_loop`, with disabled rotors at 0),
            and each vehicle's touchdown speed (N,) m/s, or None if no vehicle touched the ground.
        """
        return self._substep(state, euler_des, thrust_normalised, enable)

    def substeps(
        self,
        state: FloatArray,
        euler_des: FloatArray,
        thrust_normalised: FloatArray,
        enable: Enable,
        count: int,
    ) -> tuple[FloatArray, FloatArray, list[FloatArray]]:
        """``count`` (>= 1) sub-steps under the same setpoint and ``enable``: the same numbers
        as ``count`` calls of :meth:`substep` (about 12 numpy calls fewer per sub-step: the
        extended state is not contracted and loaded again between them). Returns the last
        state and rotor speeds, and the touchdown speeds (N,) of each sub-step in which a
        vehicle touched the ground, in order."""
        return self._substeps(state, euler_des, thrust_normalised, enable, count)


def _full(value: float | FloatArray, rows: int, n: int) -> FloatArray:
    """A (rows, n) array of ``value`` (a scalar or a column of ``rows`` values)."""
    out = np.empty((rows, n))
    out[...] = np.asarray(value, dtype=np.float64).reshape(-1, 1) if rows > 1 else value
    return out


def _make_substep(
    params: VehicleParams, n: int, dt_s: float, gains: list[FloatArray]
) -> tuple[SubStep, SubSteps]:
    """Build the sub-step (one, and several in a row): closures over preallocated buffers and
    their views.

    Everything the hot path touches is a local of this function (a closure cell for the
    sub-step): no global, attribute or index look-ups per call, no temporaries.
    """
    mul, add, sub, div = np.multiply, np.add, np.subtract, np.divide
    neg, sqrt, maximum, minimum, fmax = np.negative, np.sqrt, np.maximum, np.minimum, np.fmax
    arctan2, arcsin, sin, cos, rem = np.arctan2, np.arcsin, np.sin, np.cos, np.remainder
    einsum, empty, copyto = np.einsum, np.empty, np.copyto
    greater, greater_equal, less, invert = np.greater, np.greater_equal, np.less, np.invert
    isnan = np.isnan
    logical_and, logical_or = np.logical_and, np.logical_or

    def c0(x: float) -> FloatArray:
        return np.array(x, dtype=np.float64)

    zero, one, two, half, minus_one = c0(0.0), c0(1.0), c0(2.0), c0(0.5), c0(-1.0)
    pi, two_pi, eps_cos, g_m_s2 = c0(np.pi), c0(2.0 * np.pi), c0(_MIN_COS_PITCH), c0(G_M_S2)
    f_min, f_max = params.rotor_force_min_n, params.rotor_force_max_n
    tol = 1e-9 * f_max
    fit_lo, fit_hi = f_min - tol, f_max + tol
    c_f_min, c_f_max = c0(f_min), c0(f_max)
    max_thrust, thrust_lo, thrust_hi = c0(params.max_thrust_n), c0(4.0 * f_min), c0(4.0 * f_max)
    quarter, half_arm_inv = c0(0.25), c0(0.5 / params.arm_m)
    yaw_share = c0(0.25 / params.yaw_moment_per_thrust_m)
    inv_c, thrust_coeff = c0(1.0 / params.thrust_coeff), c0(params.thrust_coeff)
    arm, yaw_k = c0(params.arm_m), c0(params.yaw_moment_per_thrust_m)
    inv_mass = c0(1.0 / params.mass_kg)
    weight = params.weight_n
    weight_0d = c0(weight)
    span = f_max - f_min
    arm_limit, yaw_limit = span * params.arm_m, 2.0 * span * params.yaw_moment_per_thrust_m
    lim3 = _full(np.array([arm_limit, arm_limit, yaw_limit]), 3, n)
    neg_lim3 = -lim3
    ixx, iyy, izz = params.ixx, params.iyy, params.izz
    inertia3 = _full(np.array([ixx, iyy, izz]), 3, n)
    coupling3 = _full(np.array([izz - iyy, ixx - izz, iyy - ixx]), 3, n)
    euler_coef3 = _full(np.array(_euler_coeffs(params)), 3, n)
    sign3 = _full(np.array([1.0, 1.0, -1.0]), 3, n)
    h, h_half, h_sixth = c0(dt_s), c0(0.5 * dt_s), c0(dt_s / 6.0)

    # --- inner loop -----------------------------------------------------------------------
    e3, s3, sq3 = empty((3, n)), empty((3, n)), empty((3, n))
    e_yaw, e_roll, e_pitch = e3  # 2(wz + xy), 2(wx + yz), 2(wy - zx)
    sq_01, sq_12 = sq3[0:2], sq3[1:3]
    den2 = empty((2, n))
    den_roll, den_yaw = den2
    eta = empty((3, n))
    roll, pitch, yaw = eta
    # roll: -s c s c -s, so that [c s], [-s c], [s c] and [c -s] are row pairs; pitch: s s c c
    phi5, theta4 = empty((5, n)), empty((4, n))
    neg_s_phi, c_phi, s_phi, c_phi_b, neg_s_phi_b = phi5
    cs_phi, ns_c_phi, sc_phi, c_ns_phi = phi5[1:3], phi5[0:2], phi5[2:4], phi5[3:5]
    s_th, s_th_b, c_th, c_th_b = theta4
    ss_th, cc_th = theta4[0:2], theta4[2:4]
    eta_dot = empty((3, n))
    phid, thd, psid = eta_dot
    thd_qr = eta_dot[1:3]  # [theta', (s_phi q + c_phi r)] before psi' = (...) / cos(theta)
    err, tau, tmp3, od = empty((3, n)), empty((3, n)), empty((3, n)), empty((3, n))
    e_yaw_err = err[2]
    tau0, tau1, tau2 = tau
    od0, od12 = od[0], od[1:3]
    # two-row copies for the two rows of omega' that share their form
    qq, rr, t1t1, t2t2, ph2, th2, ps2 = (empty((2, n)) for _ in range(7))
    a2, b2, c2, sc_cth, sc_sth, c_ns_cth = (empty((2, n)) for _ in range(6))
    a, b, ctc, tth = (empty(n) for _ in range(4))
    mom, cp = empty((3, n)), empty((3, n))
    cp_qr, cp_pr, cp_pq = cp
    t1, qt = empty(n), empty(n)
    qt2, hl2, y2 = empty((2, n)), empty((2, n)), empty((2, n))
    y_plus, y_minus = y2
    lim_mom = empty((3, n))
    lim_lm, lim_n = lim_mom[0:2], lim_mom[2]
    base, total, forces = empty((4, n)), empty((4, n)), empty((4, n))
    yaw4, room, mag, safe = empty((4, n)), empty((4, n)), empty((4, n)), empty((4, n))
    yaw4_01, yaw4_23 = yaw4[0:2], yaw4[2:4]
    room_0, room_1, room_2, room_3 = room
    yaw_up, mag_big = np.empty((4, n), dtype=bool), np.empty((4, n), dtype=bool)
    scale = empty(n)
    c_tol = c0(tol)
    base_01, base_23, total_01, total_23 = base[0:2], base[2:4], total[0:2], total[2:4]
    # --- wrench and dynamics --------------------------------------------------------------
    f4 = empty((4, n))
    f0, f1, f2, f3 = f4
    f_01, f_23 = f4[0:2], f4[2:4]
    thrust = empty(n)
    moments = empty((3, n))
    mom_lm, mom_n = moments[0:2], moments[2]
    alpha = empty((3, n))
    t_m, two_t_m, gmt = empty(n), empty(n), empty(n)
    neg_two_t_m2 = empty((2, n))
    sign2 = _full(np.array([1.0, -1.0]), 2, n)
    xs = [empty((_EXT_ROWS, n)) for _ in range(4)]
    ks = [empty((_EXT_ROWS, n)) for _ in range(4)]
    d_h5, d_s2, d_a2, d_b2 = empty((5, n)), empty((2, n)), empty((2, n)), empty((2, n))
    d_p3, d_wh3, d_bb3, d_cc3, d_cp3 = (empty((3, n)) for _ in range(5))
    h_pqr, h_rpq, h_qrp = d_h5[0:3], d_h5[2:5], d_h5[1:4]
    d_p0, d_p1, d_p2 = d_p3
    d_s0, d_s1 = d_s2
    d_t, norm = empty(n), empty(n)

    def views(x: FloatArray, k: FloatArray) -> tuple[FloatArray, ...]:
        return (
            x[3:6], k[0:3], x[11:13], x[6:8], x[8:10], x[15:17], k[3:5], k[5],
            x[17:22], x[11:14], x[8:11], x[12:15], x[13:16],
            k[10], k[8:10], k[11:14], k[13], k[6:8], k[11:13], k[14:16], k[11], k[16],
            x[18:21], x[19:22], k[17:20], k[17:19], k[20:22],
        )  # fmt: skip

    stage_views = [views(x, k) for x, k in zip(xs, ks, strict=True)]

    def derivative(v: tuple[FloatArray, ...]) -> None:
        """The derivative of one extended stage state (dynamics._derivative_into)."""
        (vel, k_pos, xy, zz, ww, yx, k_v01, k_v2, pqr5, xyz, www, yzx, zxy,
         k_w, k_ww, k_xyz, k_z, k_zz, k_xy, k_xy2, k_x, k_x2,
         qrp, rpq, k_pqr, k_pq, k_pq2) = v  # fmt: skip
        k_pos[...] = vel
        # velocity: -2 T/m (xz + wy), -2 T/m (yz - wx), g - T/m + 2 T/m (x^2 + y^2)
        mul(xy, zz, d_a2)
        mul(ww, yx, d_b2)
        mul(d_b2, sign2, d_b2)
        add(d_a2, d_b2, d_a2)
        mul(neg_two_t_m2, d_a2, k_v01)
        mul(xy, xy, d_s2)
        add(d_s0, d_s1, d_t)
        mul(two_t_m, d_t, d_t)
        add(gmt, d_t, k_v2)
        # quaternion: 0.5 q (x) (0, p, q, r)
        mul(pqr5, half, d_h5)
        mul(xyz, h_pqr, d_p3)
        add(d_p0, d_p1, d_t)
        add(d_t, d_p2, d_t)
        neg(d_t, k_w)
        k_ww[...] = k_w
        mul(www, h_pqr, d_wh3)
        mul(yzx, h_rpq, d_bb3)
        mul(zxy, h_qrp, d_cc3)
        add(d_wh3, d_bb3, d_wh3)
        sub(d_wh3, d_cc3, k_xyz)
        k_zz[...] = k_z
        k_xy2[...] = k_xy
        k_x2[...] = k_x
        # body rates: Euler's equations
        mul(qrp, rpq, d_cp3)
        mul(euler_coef3, d_cp3, d_cp3)
        add(d_cp3, alpha, k_pqr)
        k_pq2[...] = k_pq

    x1, x2, x3, x4 = xs
    k1, k2, k3, k4 = ks
    v1, v2, v3, v4 = stage_views
    # stage 1 is the state itself: the inner loop reads it
    x1_pos_vel, x1_zz, x1_www, x1_xyz, x1_xy = x1[0:6], x1[6:8], x1[8:11], x1[11:14], x1[14:16]
    x1_x, x1_pqr, x1_pq, x1_yzx, x1_zxy = x1[16], x1[17:20], x1[20:22], x1[12:15], x1[13:16]
    k2_pos_vel, k2_quat, k2_pqr = k2[0:6], k2[10:14], k2[17:20]
    k2_z, k2_q11, k2_pqr5, x1_q11, x1_pqr5 = k2[2], k2[6:17], k2[17:22], x1[6:17], x1[17:22]
    p_row, q_row, r_row = x1[17], x1[18], x1[19]

    def load(state: FloatArray) -> None:
        """The stage-1 extended state from ``state`` (13, N)."""
        x1_pos_vel[...] = state[0:6]
        x1_zz[...] = state[9]
        x1_www[...] = state[6]
        x1_xyz[...] = state[7:10]
        x1_xy[...] = state[7:9]
        x1_x[...] = state[7]
        x1_pqr[...] = state[10:13]
        x1_pq[...] = state[10:12]

    def substep(
        state: FloatArray, euler_des: FloatArray, thrust_normalised: FloatArray, enable: Enable
    ) -> tuple[FloatArray, FloatArray, FloatArray | None]:
        load(state)
        rotor = advance(euler_des, thrust_normalised, enable)
        # contract to (13, N), normalising the quaternion
        sqrt(einsum("ij,ij->j", k2_quat, k2_quat), norm)
        new = empty((13, n))
        new[0:6] = k2_pos_vel
        div(k2_quat, norm, new[6:10])
        new[10:13] = k2_pqr
        # --- ground contact (dynamics._ground_contact_inplace) --------------------------------
        impact = None
        if not new[2].max() < 0.0:
            impact = contact(new, state)
        return new, rotor, impact

    def substeps(
        state: FloatArray,
        euler_des: FloatArray,
        thrust_normalised: FloatArray,
        enable: Enable,
        count: int,
    ) -> tuple[FloatArray, FloatArray, list[FloatArray]]:
        """``count`` sub-steps under the same setpoint and enable: the same numbers as
        ``count`` calls of :func:`substep`, without contracting to (13, N) and loading the
        extended state again between them: the next stage-1 state is the RK4 result (whose
        repeated rows hold the same values as the rows they repeat) with its quaternion rows,
        repeats included, divided by the same norm. A sub-step that touches the ground goes
        through the (13, N) state and :func:`contact`, as in :func:`substep`."""
        load(state)
        impacts: list[FloatArray] = []
        for left in range(count - 1, -1, -1):
            rotor = advance(euler_des, thrust_normalised, enable)
            sqrt(einsum("ij,ij->j", k2_quat, k2_quat), norm)
            if left and k2_z.max() < 0.0:  # in the air: the next stage-1 state directly
                x1_pos_vel[...] = k2_pos_vel
                div(k2_q11, norm, x1_q11)
                x1_pqr5[...] = k2_pqr5
                continue
            new = empty((13, n))
            new[0:6] = k2_pos_vel
            div(k2_quat, norm, new[6:10])
            new[10:13] = k2_pqr
            if not new[2].max() < 0.0:
                impacts.append(contact(new, x1))  # (x1's rows 0:6 are the previous pos, vel)
            if not left:
                return new, rotor, impacts
            load(new)
        raise ValueError(f"count must be at least 1, got {count}")

    def advance(euler_des: FloatArray, thrust_normalised: FloatArray, enable: Enable) -> FloatArray:
        """One sub-step from the stage-1 state ``x1``: the inner loop and RK4, the new extended
        state (not normalised) in ``k2``; the rotor speeds applied (a new array)."""
        kp, kd = gains
        # --- attitude controller (attitude_control.attitude_moments) --------------------------
        # ZYX Euler angles of the quaternion
        mul(x1_www, x1_zxy, e3)  # wz wx wy
        mul(x1_xyz, x1_yzx, s3)  # xy yz zx
        mul(s3, sign3, s3)
        add(e3, s3, e3)
        mul(e3, two, e3)
        mul(x1_xyz, x1_xyz, sq3)
        add(sq_01, sq_12, den2)
        mul(den2, two, den2)
        sub(one, den2, den2)
        arctan2(e_roll, den_roll, roll)
        arctan2(e_yaw, den_yaw, yaw)
        maximum(e_pitch, minus_one, out=a)
        minimum(a, one, out=a)
        arcsin(a, pitch)
        sin(roll, s_phi)
        cos(roll, c_phi)
        neg(s_phi, neg_s_phi)
        c_phi_b[...] = c_phi
        neg_s_phi_b[...] = neg_s_phi
        sin(pitch, s_th)
        cos(pitch, c_th)
        s_th_b[...] = s_th
        c_th_b[...] = c_th
        # Euler-angle rates from body rates (eq. 20)
        qq[...] = q_row
        rr[...] = r_row
        mul(cs_phi, qq, a2)
        mul(ns_c_phi, rr, b2)
        add(a2, b2, thd_qr)  # c_phi q - s_phi r, s_phi q + c_phi r
        maximum(c_th, eps_cos, out=ctc)
        div(s_th, ctc, tth)
        mul(tth, psid, a)
        add(p_row, a, phid)
        div(psid, ctc, psid)
        # PD on the Euler angles, yaw error wrapped
        sub(euler_des, eta, err)
        add(e_yaw_err, pi, e_yaw_err)
        rem(e_yaw_err, two_pi, e_yaw_err)
        sub(e_yaw_err, pi, e_yaw_err)
        mul(kp, err, tau)
        mul(kd, eta_dot, tmp3)
        sub(tau, tmp3, tau)
        # body acceleration omega' = E tau + E' eta'
        mul(s_th, tau2, a)
        sub(tau0, a, a)
        mul(c_th, thd, b)
        mul(b, psid, b)
        sub(a, b, od0)
        # rows 1 and 2 together, A tau1 + B tau2 - C phi' theta' + (D phi' - E theta') psi'
        # with A = [c, -s], B = [s c_th, c c_th], C = [s, c], D = [c c_th, -s c_th],
        # E = [s s_th, c s_th] (s, c of roll): the reference's second row is this one negated
        # term by term, which IEEE arithmetic gives exactly
        t1t1[...] = tau1
        t2t2[...] = tau2
        ph2[...] = phid
        th2[...] = thd
        ps2[...] = psid
        mul(sc_phi, cc_th, sc_cth)
        mul(sc_phi, ss_th, sc_sth)
        mul(c_ns_phi, cc_th, c_ns_cth)
        mul(c_ns_phi, t1t1, a2)
        mul(sc_cth, t2t2, b2)
        add(a2, b2, a2)
        mul(sc_phi, ph2, b2)
        mul(b2, th2, b2)
        sub(a2, b2, a2)
        mul(c_ns_cth, ph2, b2)
        mul(sc_sth, th2, c2)
        sub(b2, c2, b2)
        mul(b2, ps2, b2)
        add(a2, b2, od12)
        # moments (eq. 39)
        mul(inertia3, od, mom)
        mul(q_row, r_row, cp_qr)
        mul(p_row, r_row, cp_pr)
        mul(p_row, q_row, cp_pq)
        mul(coupling3, cp, cp)
        add(mom, cp, mom)
        # --- mixer (mixer.mix) ----------------------------------------------------------------
        fmax(thrust_normalised, zero, t1)  # a NaN thrust counts as 0, as in the mixer
        minimum(t1, one, out=t1)
        mul(t1, max_thrust, t1)
        maximum(t1, thrust_lo, out=t1)
        minimum(t1, thrust_hi, out=t1)
        maximum(mom, neg_lim3, out=lim_mom)
        minimum(lim_mom, lim3, out=lim_mom)
        mul(t1, quarter, qt)
        qt2[...] = qt
        mul(lim_lm, half_arm_inv, hl2)
        add(qt2, hl2, base_01)
        sub(qt2, hl2, base_23)
        mul(lim_n, yaw_share, y_plus)
        neg(y_plus, y_minus)
        add(base_01, y2, total_01)
        add(base_23, y2, total_23)
        finite = True
        if total.min() >= fit_lo and total.max() <= fit_hi:  # the whole yaw share fits
            maximum(total, c_f_min, out=forces)
        elif not isnan(lim_mom).any():  # scale the yaw share down (mixer._yaw_scale)
            yaw4_01[...] = y2
            yaw4_23[...] = y2
            greater(yaw4, zero, yaw_up)
            sub(c_f_max, base, room)
            sub(base, c_f_min, forces)
            copyto(room, forces, where=~yaw_up)
            np.abs(yaw4, mag)
            greater(mag, c_tol, mag_big)
            safe.fill(1.0)
            copyto(safe, mag, where=mag_big)
            div(room, safe, room)
            copyto(room, np.inf, where=~mag_big)
            minimum(room_0, room_1, out=scale)
            minimum(scale, room_2, out=scale)
            minimum(scale, room_3, out=scale)
            maximum(scale, zero, out=scale)
            minimum(scale, one, out=scale)
            mul(scale, yaw4, forces)
            add(base, forces, forces)
            maximum(forces, c_f_min, out=forces)
        else:  # a moment demand that is not a number: the reference mixer (it counts it as 0)
            finite = False
        if finite:
            minimum(forces, c_f_max, out=forces)
            mul(forces, inv_c, forces)
            rotor = sqrt(forces)
        else:
            thrust_n = np.clip(np.asarray(thrust_normalised, dtype=np.float64), 0.0, 1.0)
            rotor = mix(thrust_n * params.max_thrust_n, mom, params)
        if enable is not None:
            mul(rotor, enable, rotor)
        # --- rotor wrench (dynamics.wrench_from_rotor_speeds, _specific_inputs) --------------
        mul(rotor, rotor, f4)
        mul(thrust_coeff, f4, f4)
        add(f0, f1, thrust)
        add(thrust, f2, thrust)
        add(thrust, f3, thrust)
        sub(f_01, f_23, mom_lm)
        mul(mom_lm, arm, mom_lm)
        sub(f0, f1, a)
        add(a, f2, a)
        sub(a, f3, a)
        mul(a, yaw_k, mom_n)
        mul(thrust, inv_mass, t_m)
        div(moments, inertia3, alpha)
        add(t_m, t_m, two_t_m)
        neg(two_t_m, neg_two_t_m2[0])
        neg_two_t_m2[1] = neg_two_t_m2[0]
        sub(g_m_s2, t_m, gmt)
        # --- RK4 (dynamics._rk4) --------------------------------------------------------------
        derivative(v1)
        mul(k1, h_half, x2)
        add(x2, x1, x2)
        derivative(v2)
        mul(k2, h_half, x3)
        add(x3, x1, x3)
        derivative(v3)
        mul(k3, h, x4)
        add(x4, x1, x4)
        derivative(v4)
        add(k2, k3, k2)
        add(k2, k2, k2)
        add(k2, k1, k2)
        add(k2, k4, k2)
        mul(k2, h_sixth, k2)
        add(k2, x1, k2)
        return rotor

    # --- ground contact buffers -----------------------------------------------------------------
    bool_n = [np.empty(n, dtype=bool) for _ in range(6)]
    in_contact, moving_down, resting, stopped, mask, dz_pos = bool_n
    dz, den, frac, speed, yaw_half = (empty(n) for _ in range(5))
    level_num, level_den = empty(n), empty(n)

    def contact(new: FloatArray, prev: FloatArray) -> FloatArray:
        """Ground contact on ``new`` (13, N) in place (dynamics._ground_contact_inplace, over all
        columns with masks instead of on the gathered contact columns); touchdown speeds (N,)."""
        z0, vz0, z1, vz1 = prev[2], prev[5], new[2], new[5]
        greater_equal(z1, zero, in_contact)
        touching = in_contact.nonzero()[0]
        if touching.size <= _FEW_IN_CONTACT:  # a crashed or landed drone or two: one by one
            impact = np.zeros(n)
            for i in touching.tolist():
                impact[i] = _contact_one(new, prev, i, thrust.item(i) < weight)
            return impact
        # fraction of the step at which the ground was reached (0 if it started on the ground)
        sub(z1, z0, dz)
        greater(dz, zero, dz_pos)
        den.fill(1.0)
        copyto(den, dz, where=dz_pos)
        neg(z0, frac)
        div(frac, den, frac)
        less(z0, zero, mask)
        invert(mask, mask)
        copyto(frac, 0.0, where=mask)
        maximum(frac, zero, out=frac)
        minimum(frac, one, out=frac)
        greater(vz1, zero, moving_down)
        sub(vz1, vz0, speed)
        mul(frac, speed, speed)
        add(vz0, speed, speed)
        maximum(speed, zero, out=speed)
        impact = np.zeros(n)
        logical_and(moving_down, in_contact, mask)
        copyto(impact, speed, where=mask)
        less(thrust, weight_0d, resting)
        logical_or(moving_down, resting, stopped)
        logical_and(stopped, in_contact, stopped)
        copyto(z1, 0.0, where=in_contact)
        copyto(new[3:6], 0.0, where=stopped)
        copyto(new[10:13], 0.0, where=stopped)
        greater_equal(z0, zero, mask)
        logical_and(mask, stopped, mask)
        copyto(new[0:2], prev[0:2], where=mask)
        logical_and(resting, in_contact, resting)
        if resting.any():  # level them, keeping the yaw (dynamics._level_quat)
            w, x, y, z = new[6], new[7], new[8], new[9]
            mul(w, z, level_num)
            mul(x, y, yaw_half)
            add(level_num, yaw_half, level_num)
            mul(two, level_num, level_num)
            mul(y, y, level_den)
            mul(z, z, yaw_half)
            add(level_den, yaw_half, level_den)
            mul(two, level_den, level_den)
            sub(one, level_den, level_den)
            arctan2(level_num, level_den, yaw_half)
            mul(half, yaw_half, yaw_half)
            copyto(w, cos(yaw_half), where=resting)
            copyto(new[7:9], 0.0, where=resting)
            copyto(z, sin(yaw_half), where=resting)
        return impact

    return substep, substeps


#: Up to this many vehicles on the ground, contact is applied one by one (cheaper than masks).
_FEW_IN_CONTACT = 3


def _contact_one(new: FloatArray, prev: FloatArray, i: int, resting: bool) -> float:
    """Ground contact of vehicle ``i`` (on the ground in ``new``) in Python floats: the same
    operations as dynamics._ground_contact_inplace on one column; its touchdown speed (m/s)."""
    z0, vz0, z1, vz1 = prev.item(2, i), prev.item(5, i), new.item(2, i), new.item(5, i)
    frac = 0.0
    if z0 < 0.0:
        dz = z1 - z0
        frac = min(max(-z0 / (dz if dz > 0.0 else 1.0), 0.0), 1.0)
    moving_down = vz1 > 0.0
    impact = max(vz0 + frac * (vz1 - vz0), 0.0) if moving_down else 0.0
    new[2, i] = 0.0
    if moving_down or resting:
        new[3:6, i] = 0.0
        new[10:13, i] = 0.0
        if z0 >= 0.0:
            new[0:2, i] = prev[0:2, i]
    if resting:  # level, keeping the yaw (dynamics._level_quat; numpy's arctan2, as there)
        w, x, y, z = new[6:10, i].tolist()
        yaw = float(np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z)))
        new[6:10, i] = (math.cos(0.5 * yaw), 0.0, 0.0, math.sin(0.5 * yaw))
    return impact
