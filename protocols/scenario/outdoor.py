"""What a small quadcopter meets outdoors, as scenario sections: ``swarm scenario new --outdoor
rtk|gnss`` writes them (protocols/scenario/generator.py); docs/scenarios.md cites the sources.

- The air: a light breeze, 3 m/s (Beaufort 2: 1.6 to 3.3 m/s) with gusts of 0.5 m/s (10 to 20 %
  of the mean wind near the ground, MIL-HDBK-1797's low-altitude model), unless the command
  gives its own wind.
- Vehicles that differ: 2 % in mass, 1 % in rotor thrust (one battery, payload and propeller
  batch to the next), motors of 20 ms time constant 10 % apart (PX4's Gazebo Iris: 12.5 ms up,
  25 ms down).
- Sensors, as the autopilot's EKF reports them, fusing an IMU with either
  - ``rtk``: an RTK GNSS receiver (u-blox ZED-F9P: 0.01 m + 1 ppm CEP horizontal in RTK, 0.05 m/s
    velocity accuracy): what drone-show fleets fly on; or
  - ``gnss``: a consumer GNSS receiver (u-blox NEO-M8N: 2.5 m CEP horizontal, 0.05 m/s velocity
    accuracy): a position error of about 2 m a component that wanders over minutes.
  The EKF's attitude to about 0.3 to 0.6 degrees; its output 20 ms late.
- The radio: a 1 Mbit/s class link (ESP-NOW, a Crazyradio) carrying about 100 kB/s, loss with
  distance as log-distance path loss (exponent 3, 6 dB fading; half lost at 60 m), 2 % of the
  messages in bursts of 5, 10 ms of jitter.
"""

from __future__ import annotations

from typing import Final

#: ``--outdoor`` choices
OUTDOOR_SENSORS: Final = ("rtk", "gnss")

#: a light breeze from the west (m/s) and its gusts (m/s), where the command gives no wind
BREEZE_M_S, GUSTS_M_S = 3.0, 0.5

#: [vehicle]: the motors' time constant (s)
VEHICLE: Final[dict[str, float]] = {"motor_tau_s": 0.02}

VEHICLES: Final[dict[str, float]] = {
    "mass_spread": 0.02,
    "thrust_spread": 0.01,
    "motor_tau_spread": 0.1,
}

SENSORS: Final[dict[str, dict[str, float]]] = {
    "rtk": {
        "gnss_bias_m": 0.02,
        "gnss_bias_tau_s": 300.0,
        "position_noise_m": 0.01,
        "velocity_noise_m_s": 0.05,
        "attitude_noise_rad": 0.005,
        "latency_s": 0.02,
    },
    "gnss": {
        "gnss_bias_m": 2.0,
        "gnss_bias_tau_s": 300.0,
        "position_noise_m": 0.1,
        "velocity_noise_m_s": 0.05,
        "attitude_noise_rad": 0.01,
        "latency_s": 0.02,
    },
}

RADIO: Final[dict[str, float]] = {
    "bandwidth_bytes_s": 100_000.0,
    "queue_messages": 8,
    "loss_half_m": 60.0,
    "path_loss_exponent": 3.0,
    "fading_db": 6.0,
    "burst_fraction": 0.02,
    "burst_length": 5.0,
    "jitter_s": 0.01,
}


def outdoor_lines(sensors: str) -> list[str]:
    """The [vehicles], [sensors] and [radio] sections (TOML lines) of ``--outdoor SENSORS``."""
    if sensors not in SENSORS:
        raise ValueError(f"outdoor sensors: one of {', '.join(OUTDOOR_SENSORS)}, got {sensors!r}")
    receiver = "an RTK GNSS (u-blox ZED-F9P class)" if sensors == "rtk" else (
        "a consumer GNSS (u-blox NEO-M8N class)"
    )  # fmt: skip

    def table(name: str, values: dict[str, float]) -> list[str]:
        return [f"[{name}]", *(f"{k} = {v!r}" for k, v in values.items()), ""]

    return [
        "# Outdoors (docs/scenarios.md cites where each value comes from): vehicles that differ,",
        *table("vehicles", VEHICLES),
        f"# each flying on its EKF's estimate with {receiver},",
        *table("sensors", SENSORS[sensors]),
        "# and a 1 Mbit/s class radio between them.",
        *table("radio", RADIO),
    ]
