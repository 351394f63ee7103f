"""Each vehicle's tunable parameters (the MAVLink parameter protocol's table). Pure.

Every value is a float (MAV_PARAM_TYPE_REAL32 on the wire) with a range; a set outside it is
refused and the value kept. Names follow PX4 where PX4 has the same tunable:

========================  =========================================================  ==========
name                      meaning                                                    unit
========================  =========================================================  ==========
ATT_ROLL_KP ... YAW_KP    attitude PD proportional gains (roll, pitch, yaw)           1/s^2
ATT_ROLL_KD ... YAW_KD    attitude PD derivative gains                               1/s
COM_OF_LOSS_T             offboard-loss timeout before the failsafe                  s
COM_FS_HOLD_T             failsafe level hold before the descent                     s
MPC_LAND_SPEED            descent speed in LAND and in the failsafe                  m/s
SYS_FAILURE_EN            1: MAV_CMD_INJECT_FAILURE is honoured, 0: denied           -
MAV_SYS_ID                the vehicle's MAVLink system id (read-only)                -
========================  =========================================================  ==========

A dialect may add parameters and leave some out (``extra``, ``without``: the ArduCopter
dialect's GUID_OPTIONS, MOT_THST_HOVER, ... in sitl_sim/vehicle/copter.py). Each parameter has a
MAVLink type (``param_type``, MAV_PARAM_TYPE): the value always travels as a float, the type says
what the autopilot stores (REAL32 for all of the table above; ArduPilot's integer parameters are
INT8/16/32, their value sent as the float of the integer, as ArduPilot does).

The attitude gains are per vehicle: :class:`FleetAttitudeGains` is an
:class:`~sitl_sim.physics.attitude_control.AttitudeGains` whose columns are the vehicles, so the
shared inner loop uses each vehicle's own gains.
"""

from __future__ import annotations

from collections.abc import Callable, Collection, Sequence
from dataclasses import dataclass
from enum import Enum

import numpy as np

from protocols.model.frames import FloatArray
from sitl_sim.physics.attitude_control import AttitudeGains
from sitl_sim.vehicle.autopilot import Autopilot

_AXES = ("ROLL", "PITCH", "YAW")
#: MAV_PARAM_TYPE values (MAVLink common.xml).
PARAM_INT8 = 2
PARAM_INT16 = 4
PARAM_INT32 = 6
PARAM_REAL32 = 9


class FleetAttitudeGains(AttitudeGains):
    """Attitude PD gains of ``n`` vehicles: ``kp_col``/``kd_col`` return (3, n) arrays, row =
    axis (roll, pitch, yaw), column = vehicle; they start at ``base`` and change per vehicle."""

    kp_matrix: FloatArray
    kd_matrix: FloatArray

    def __init__(self, base: AttitudeGains, n: int) -> None:
        super().__init__(kp=base.kp, kd=base.kd)
        object.__setattr__(self, "kp_matrix", np.tile(np.asarray(base.kp, float)[:, None], n))
        object.__setattr__(self, "kd_matrix", np.tile(np.asarray(base.kd, float)[:, None], n))

    def kp_col(self) -> FloatArray:
        """Proportional gains (3, n), 1/s^2."""
        return self.kp_matrix

    def kd_col(self) -> FloatArray:
        """Derivative gains (3, n), 1/s."""
        return self.kd_matrix


class SetStatus(Enum):
    """Outcome of a parameter set."""

    OK = "ok"
    UNKNOWN = "unknown parameter"
    OUT_OF_RANGE = "out of range"
    READ_ONLY = "read-only"


@dataclass(frozen=True)
class ParamSpec:
    """One tunable: name (<= 16 characters), range, and how to read and write vehicle ``i``'s
    value (``write`` None: read-only); ``param_type`` its MAV_PARAM_TYPE."""

    name: str
    minimum: float
    maximum: float
    read: Callable[[int], float]
    write: Callable[[int, float], None] | None
    param_type: int = PARAM_REAL32


class Tunables:
    """The parameter table of every vehicle, bound to the autopilot and gains it tunes; a
    dialect's ``extra`` parameters follow the common ones, those named in ``without`` are left
    out."""

    def __init__(
        self,
        autopilot: Autopilot,
        gains: FleetAttitudeGains,
        sysids: list[int],
        extra: Sequence[ParamSpec] = (),
        without: Collection[str] = (),
    ) -> None:
        common = (
            *_gain_specs(gains.kp_matrix, "KP", 10_000.0),
            *_gain_specs(gains.kd_matrix, "KD", 1_000.0),
            array_spec("COM_OF_LOSS_T", autopilot.offboard_timeout_s, 0.02, 60.0),
            array_spec("COM_FS_HOLD_T", autopilot.failsafe_hold_s, 0.0, 60.0),
            array_spec("MPC_LAND_SPEED", autopilot.land_speed_m_s, 0.1, 5.0),
            ParamSpec(
                "SYS_FAILURE_EN",
                0.0,
                1.0,
                lambda i: float(autopilot.failure_injection[i]),
                lambda i, v: autopilot.failure_injection.__setitem__(i, v >= 0.5),
            ),
            ParamSpec("MAV_SYS_ID", 1.0, 250.0, lambda i: float(sysids[i]), None),
        )
        self.specs: tuple[ParamSpec, ...] = (
            *(spec for spec in common if spec.name not in without),
            *extra,
        )
        self._index = {spec.name: k for k, spec in enumerate(self.specs)}

    @property
    def count(self) -> int:
        """Number of parameters of one vehicle."""
        return len(self.specs)

    def index_of(self, name: str) -> int | None:
        """Index of parameter ``name``, None if there is none."""
        return self._index.get(name)

    def value(self, vehicle: int, index: int) -> tuple[str, float]:
        """(name, value) of parameter ``index`` of ``vehicle``."""
        spec = self.specs[index]
        return spec.name, spec.read(vehicle)

    def param_type(self, index: int) -> int:
        """The MAV_PARAM_TYPE of parameter ``index``."""
        return self.specs[index].param_type

    def set(self, vehicle: int, name: str, value: float) -> SetStatus:
        """Set ``vehicle``'s parameter ``name`` to ``value`` if known, writable and in range."""
        index = self._index.get(name)
        if index is None:
            return SetStatus.UNKNOWN
        spec = self.specs[index]
        if spec.write is None:
            return SetStatus.READ_ONLY
        if not (np.isfinite(value) and spec.minimum <= value <= spec.maximum):
            return SetStatus.OUT_OF_RANGE
        spec.write(vehicle, float(value))
        return SetStatus.OK


def array_spec(
    name: str,
    values: FloatArray,
    minimum: float,
    maximum: float,
    param_type: int = PARAM_REAL32,
    writable: bool = True,
) -> ParamSpec:
    """A parameter stored in ``values`` (N,), one entry per vehicle. An integer ``param_type``
    stores the set value's integer part (as ArduPilot's integer parameters do)."""
    integer = param_type != PARAM_REAL32

    def write(i: int, v: float) -> None:
        values[i] = float(int(v)) if integer else v

    read = lambda i: float(values[i])  # noqa: E731
    return ParamSpec(name, minimum, maximum, read, write if writable else None, param_type)


def _gain_specs(matrix: FloatArray, kind: str, maximum: float) -> list[ParamSpec]:
    specs = []
    for row, axis in enumerate(_AXES):

        def read(i: int, row: int = row) -> float:
            return float(matrix[row, i])

        def write(i: int, v: float, row: int = row) -> None:
            matrix[row, i] = v

        specs.append(ParamSpec(f"ATT_{axis}_{kind}", 1e-3, maximum, read, write))
    return specs
