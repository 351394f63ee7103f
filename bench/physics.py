"""Throughput of the vectorised physics: drone-steps per second of
``sitl_sim.physics.dynamics.step``.

Measures RK4 steps alone (the compiled rules of sitl_sim/physics/rules.py over N vehicles), the
inner loop (the numpy attitude controller + the compiled mixer) followed by an RK4 step, and the
same through the fused
:class:`sitl_sim.physics.kernel.PhysicsKernel` (``kernel``: inner loop, RK4 and ground contact, as
the simulator runs them), for N = 1, 10, 100, 1000 hovering vehicles. Each figure is the
best of a few repeats, each at least ``MIN_SECONDS`` long.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np

from protocols.model.frames import FloatArray
from sitl_sim.physics import dynamics
from sitl_sim.physics.inner_loop import inner_loop
from sitl_sim.physics.kernel import PhysicsKernel
from sitl_sim.physics.vehicle_params import VehicleParams

SIZES = (1, 10, 100, 1000)
DT_S = 0.002
MIN_SECONDS = 0.5
REPEATS = 3
TARGET_N = 1000
TARGET_DRONE_STEPS_PER_S = 1e6
_BATCH = 20


def _hover_fleet(n: int, params: VehicleParams) -> tuple[FloatArray, FloatArray]:
    """States (13, n) of vehicles hovering on a 2 m grid at 10 m, and hover rotor speeds (4, n)."""
    side = int(np.ceil(np.sqrt(n)))
    cells = np.arange(n)
    positions = np.stack([2.0 * (cells // side), 2.0 * (cells % side), np.full(n, -10.0)], axis=1)
    speed = np.sqrt(params.hover_thrust_n / 4.0 / params.thrust_coeff)
    return dynamics.initial_state(positions), np.full((4, n), speed)


def _drone_steps_per_s(advance: Callable[[FloatArray], FloatArray], state: FloatArray) -> float:
    """Best rate over ``REPEATS`` runs of ``state = advance(state)``, each >= ``MIN_SECONDS``."""
    n = state.shape[1]
    best = 0.0
    for _ in range(REPEATS):
        steps = 0
        start = time.perf_counter()
        while (elapsed := time.perf_counter() - start) < MIN_SECONDS:
            for _ in range(_BATCH):
                state = advance(state)
            steps += _BATCH
        best = max(best, steps * n / elapsed)
    return best


def _variants(
    params: VehicleParams, speeds: FloatArray
) -> dict[str, Callable[[FloatArray], FloatArray]]:
    """Named ``state -> state`` functions to time for one fleet."""
    n = speeds.shape[1]
    level, hover = np.zeros((3, n)), np.full(n, params.hover_thrust_n / params.max_thrust_n)

    def rk4(s: FloatArray) -> FloatArray:
        return dynamics.step(s, speeds, params, DT_S, "rk4")

    def inner_loop_rk4(s: FloatArray) -> FloatArray:
        return dynamics.step(s, inner_loop(s, level, hover, params), params, DT_S, "rk4")

    kernel = PhysicsKernel(params, n, DT_S)

    def fused(s: FloatArray) -> FloatArray:
        return kernel.substep(s, level, hover)[0]

    return {"rk4": rk4, "inner_loop+rk4": inner_loop_rk4, "kernel": fused}


def physics_step() -> dict[str, Any]:
    """Run the physics benchmark; a JSON-able dict of drone-steps/s per variant and N."""
    params = VehicleParams()
    rows: list[dict[str, Any]] = []
    for n in SIZES:
        state, speeds = _hover_fleet(n, params)
        for variant, advance in _variants(params, speeds).items():
            rate = _drone_steps_per_s(advance, state.copy())
            rows.append({"variant": variant, "n": n, "drone_steps_per_s": round(rate)})
    at_target = next(r for r in rows if r["variant"] == "rk4" and r["n"] == TARGET_N)
    return {
        "dt_s": DT_S,
        "min_seconds_per_repeat": MIN_SECONDS,
        "repeats": REPEATS,
        "rows": rows,
        "target": {"variant": "rk4", "n": TARGET_N, "drone_steps_per_s": TARGET_DRONE_STEPS_PER_S},
        "target_met": at_target["drone_steps_per_s"] >= TARGET_DRONE_STEPS_PER_S,
    }
