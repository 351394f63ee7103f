"""``trajectory.json``: the shared descriptor plan of a flight, as its report keeps it.

Written by ``swarm simulate``, the ground station of ``swarm up`` and ``swarm report``; read back
by the drill judge. Light on purpose (json and numpy only): the ground station writes it at start.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from protocols.model.trajectory import DescriptorTrajectory


def write_trajectory(plan: DescriptorTrajectory, path: Path) -> Path:
    """Write ``plan`` (its seq, knots and polynomial coefficients) to ``path``; the path."""
    path.write_text(
        json.dumps(
            {
                "seq": plan.seq,
                "descriptor_order": "mu_x mu_y mu_z roll pitch yaw s1 s2 s3 (NED m, rad, m^2)",
                "t_knots_s": plan.t_knots_s.tolist(),
                "coeffs_ascending_powers": plan.coeffs.tolist(),
            }
        )
        + "\n"
    )
    return path


def read_trajectory(path: Path) -> DescriptorTrajectory:
    """The plan :func:`write_trajectory` wrote to ``path``.

    Raises:
        OSError: if the file cannot be read; ValueError (or KeyError) if it is not such a file.
    """
    data = json.loads(path.read_text())
    return DescriptorTrajectory(
        int(data["seq"]),
        np.array(data["t_knots_s"]),
        np.array(data["coeffs_ascending_powers"]),
    )
