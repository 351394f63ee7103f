"""Physical parameters of one quadcopter (paper Table II) and its rotor model (paper eq. 4).

Rotor ``i`` spinning at ``omega_i`` (rad/s) produces a thrust ``F_i = c * omega_i**2`` (N) along
body ``-z`` and a reaction yaw moment ``M_i = a * D * omega_i**2`` (N m), where ``c`` is
``thrust_coeff``, ``a`` is ``drag_coeff`` and ``D`` is ``arm_m``. The defaults give a
thrust-to-weight ratio of 2 at ``rotor_speed_max_rad_s = 1000`` and a yaw-moment-to-thrust ratio
``a * D / c = 0.016 m``.

Motor lag (``motor_tau_s``): each rotor's speed follows its command as a first-order lag,
``d omega / dt = (omega_cmd - omega) / tau`` (RotorPy's and PX4's Gazebo motor models), so its
thrust ``c omega^2`` lags too. ``tau = 0`` (the default, the paper's vehicle): the commanded speeds
act instantly. The rotor speeds are then state beside the (13, N) rigid body (the simulator's
world keeps them: ``sitl_sim.physics.kernel``).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, fields

import numpy as np

from protocols.model.frames import G_M_S2, FloatArray

_MASS_KG = 0.34
_ARM_M = 0.089
_ROTOR_SPEED_MAX_RAD_S = 1000.0
_THRUST_TO_WEIGHT = 2.0
_YAW_MOMENT_PER_THRUST_M = 0.016

#: ``c`` such that four rotors at full speed lift twice the weight (N s^2 / rad^2).
DEFAULT_THRUST_COEFF = _THRUST_TO_WEIGHT * _MASS_KG * G_M_S2 / (4.0 * _ROTOR_SPEED_MAX_RAD_S**2)
#: ``a`` such that ``a * D / c = 0.016 m`` (N s^2 / rad^2).
DEFAULT_DRAG_COEFF = _YAW_MOMENT_PER_THRUST_M * DEFAULT_THRUST_COEFF / _ARM_M


@dataclass(frozen=True)
class VehicleParams:
    """Mass, inertia, geometry and rotor model of a quadcopter (SI units).

    Attributes:
        mass_kg: total mass (kg).
        ixx, iyy, izz: principal moments of inertia about body FRD axes (kg m^2).
        arm_m: distance ``D`` from the centre of mass to each rotor (m).
        thrust_coeff: ``c`` in ``F = c omega^2`` (N s^2 / rad^2).
        drag_coeff: ``a`` in ``M = a D omega^2`` (N s^2 / rad^2).
        rotor_speed_min_rad_s: lowest rotor speed the motors hold (rad/s), may be 0.
        rotor_speed_max_rad_s: highest rotor speed (rad/s).
        body_drag_xy_n_s_m, body_drag_z_n_s_m: linear drag of the airframe and rotors against
            the air, along the body's x and y axes and along its z axis (N per m/s of airspeed;
            rotor drag of a small quadcopter is mostly in its xy plane). 0: no drag (the paper's
            vehicle).
        motor_tau_s: the motors' time constant (s): each rotor's speed follows its command as a
            first-order lag. 0: instantly (the paper's vehicle).
    """

    mass_kg: float = _MASS_KG
    ixx: float = 3.22e-4
    iyy: float = 3.06e-4
    izz: float = 5.78e-4
    arm_m: float = _ARM_M
    thrust_coeff: float = DEFAULT_THRUST_COEFF
    drag_coeff: float = DEFAULT_DRAG_COEFF
    rotor_speed_min_rad_s: float = 0.0
    rotor_speed_max_rad_s: float = _ROTOR_SPEED_MAX_RAD_S
    body_drag_xy_n_s_m: float = 0.0
    body_drag_z_n_s_m: float = 0.0
    motor_tau_s: float = 0.0

    @property
    def weight_n(self) -> float:
        """Weight ``m g`` (N)."""
        return self.mass_kg * G_M_S2

    @property
    def hover_thrust_n(self) -> float:
        """Collective thrust that balances gravity when level (N); equals ``weight_n``."""
        return self.weight_n

    @property
    def rotor_force_min_n(self) -> float:
        """Smallest thrust of one rotor, ``c omega_min^2`` (N)."""
        return self.thrust_coeff * self.rotor_speed_min_rad_s**2

    @property
    def rotor_force_max_n(self) -> float:
        """Largest thrust of one rotor, ``c omega_max^2`` (N)."""
        return self.thrust_coeff * self.rotor_speed_max_rad_s**2

    @property
    def max_thrust_n(self) -> float:
        """Collective thrust with all four rotors at full speed (N)."""
        return 4.0 * self.rotor_force_max_n

    @property
    def yaw_moment_per_thrust_m(self) -> float:
        """``k = a D / c``: reaction yaw moment per newton of rotor thrust (m)."""
        return self.drag_coeff * self.arm_m / self.thrust_coeff

    @property
    def inertia(self) -> FloatArray:
        """Principal moments of inertia ``(Ixx, Iyy, Izz)`` as a (3,) array (kg m^2)."""
        return np.array([self.ixx, self.iyy, self.izz])

    def scaled(
        self, mass: float = 1.0, thrust: float = 1.0, motor_tau: float = 1.0
    ) -> VehicleParams:
        """This vehicle with its mass times ``mass``, its rotors' thrust (and reaction torque)
        coefficients times ``thrust`` and its motors' time constant times ``motor_tau``: one
        vehicle of a fleet that differs (:func:`vehicle_scales`)."""
        if mass == 1.0 and thrust == 1.0 and motor_tau == 1.0:
            return self
        return dataclasses.replace(
            self,
            mass_kg=self.mass_kg * mass,
            thrust_coeff=self.thrust_coeff * thrust,
            drag_coeff=self.drag_coeff * thrust,
            motor_tau_s=self.motor_tau_s * motor_tau,
        ).validate()

    def validate(self) -> VehicleParams:
        """Check every field; return ``self`` so it can be chained.

        Raises:
            ValueError: naming the first field that is not finite, or not positive (the minimum
                rotor speed and the drags may be zero), or a maximum rotor speed not above the
                minimum.
        """
        for f in fields(self):
            value = getattr(self, f.name)
            is_number = isinstance(value, int | float) and not isinstance(value, bool)
            if not is_number or not math.isfinite(value):
                raise ValueError(f"VehicleParams.{f.name} must be a finite number, got {value!r}")
            if f.name in _MAY_BE_ZERO:
                if value < 0.0:
                    raise ValueError(f"VehicleParams.{f.name} must be >= 0, got {value!r}")
            elif value <= 0.0:
                raise ValueError(f"VehicleParams.{f.name} must be > 0, got {value!r}")
        if self.rotor_speed_max_rad_s <= self.rotor_speed_min_rad_s:
            raise ValueError(
                "VehicleParams.rotor_speed_max_rad_s must exceed rotor_speed_min_rad_s, got "
                f"{self.rotor_speed_max_rad_s!r} <= {self.rotor_speed_min_rad_s!r}"
            )
        return self


#: The fields that may be 0 (the others must be positive).
_MAY_BE_ZERO = ("rotor_speed_min_rad_s", "body_drag_xy_n_s_m", "body_drag_z_n_s_m", "motor_tau_s")

#: Salts of the draws of a fleet's spread, apart from the scenario's other random draws: the
#: masses and thrusts, and the motors' time constants (their own stream, so that a fleet's masses
#: and thrusts are the same with or without it).
_SPREAD_SALT = 0x53505244  # "SPRD"
_MOTOR_SALT = 0x4D544155  # "MTAU"


def vehicle_scales(
    n: int, mass_spread: float, thrust_spread: float, seed: int, motor_tau_spread: float = 0.0
) -> tuple[tuple[float, ...], ...]:
    """Each of ``n`` vehicles' (mass, thrust) factors, and its motors' time constant factor
    third when ``motor_tau_spread`` is not 0: normal about 1 with relative standard deviations
    ``mass_spread``, ``thrust_spread`` and ``motor_tau_spread``, cut at three of them, drawn for
    the whole fleet from ``seed`` (vehicle i's factors do not depend on which simulator shard
    flies it). Empty when none spreads: every vehicle is the nominal one."""
    if mass_spread == 0.0 and thrust_spread == 0.0 and motor_tau_spread == 0.0:
        return ()
    rng = np.random.default_rng([seed & 0xFFFF_FFFF, _SPREAD_SALT])
    z = np.clip(rng.standard_normal((n, 2)), -3.0, 3.0)
    mass = 1.0 + mass_spread * z[:, 0]
    thrust = 1.0 + thrust_spread * z[:, 1]
    pairs = tuple((float(m), float(t)) for m, t in zip(mass, thrust, strict=True))
    if motor_tau_spread == 0.0:
        return pairs
    rng = np.random.default_rng([seed & 0xFFFF_FFFF, _MOTOR_SALT])
    tau = 1.0 + motor_tau_spread * np.clip(rng.standard_normal(n), -3.0, 3.0)
    return tuple((*pair, float(t)) for pair, t in zip(pairs, tau, strict=True))
