"""A nominal flight battery per vehicle, for SYS_STATUS's battery fields. Pure.

The current is an idle draw while armed plus a share proportional to the total rotor thrust
(a 0.34 kg quadrotor hovers on ~3.3 N, ~4.5 A at 11.1 V: ~50 W, about 20 min on 1500 mAh). The
voltage falls linearly with the charge used, from 4.2 V a cell full to 3.5 V empty, less the sag
of the current through the pack's resistance. The battery is reported, never acted on: an empty
one does not stop the motors (the scenarios fly minutes, not the 20 min a charge lasts).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from protocols.model.frames import FloatArray

BoolArray = npt.NDArray[np.bool_]


@dataclass(frozen=True)
class BatteryConfig:
    """Cells in series, capacity (mAh), idle draw while armed (A), draw per newton of total
    rotor thrust (A/N), per-cell open-circuit voltage full and empty (V), pack resistance (ohm)."""

    cells: int = 3
    capacity_mah: float = 1500.0
    idle_a: float = 0.5
    amps_per_newton: float = 1.2
    cell_full_v: float = 4.2
    cell_empty_v: float = 3.5
    resistance_ohm: float = 0.05


class Battery:
    """The charge (N,) of N vehicles' batteries, all full at start."""

    def __init__(self, n: int, config: BatteryConfig | None = None) -> None:
        self.config = config or BatteryConfig()
        self.capacity_c = self.config.capacity_mah * 3.6
        self.charge_c = np.full(n, self.capacity_c)
        self.current_a = np.zeros(n)

    def drain(self, armed: BoolArray, thrust_n: FloatArray, dt_s: float) -> None:
        """Draw ``dt_s`` seconds of current: idle where ``armed`` (N,) plus the
        share of the total rotor thrust ``thrust_n`` (N,) N."""
        cfg = self.config
        self.current_a = cfg.idle_a * armed + cfg.amps_per_newton * thrust_n
        self.charge_c = np.maximum(self.charge_c - self.current_a * dt_s, 0.0)

    def remaining(self) -> FloatArray:
        """The charge left (N,) as a fraction 0..1."""
        return self.charge_c / self.capacity_c

    def voltage_v(self) -> FloatArray:
        """The pack voltage (N,) V under the present current."""
        cfg = self.config
        cell = cfg.cell_empty_v + (cfg.cell_full_v - cfg.cell_empty_v) * self.remaining()
        return cfg.cells * cell - cfg.resistance_ohm * self.current_a

    def reading(self, i: int) -> tuple[float, float, float]:
        """Vehicle ``i``'s voltage (V), current (A) and remaining charge (0..1), as scalars."""
        cfg = self.config
        remaining = float(self.charge_c[i]) / self.capacity_c
        current = float(self.current_a[i])
        cell = cfg.cell_empty_v + (cfg.cell_full_v - cfg.cell_empty_v) * remaining
        return cfg.cells * cell - cfg.resistance_ohm * current, current, remaining
