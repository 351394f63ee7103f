"""The swarm descriptor vector ``a`` (9,), its order, names and units.

Order follows the paper's gain tables: ``[mu_x, mu_y, mu_z, roll, pitch, yaw, s1, s2, s3]``:
centre in NED metres, orientation of the swarm frame as ZYX angles in radians (roll, pitch,
yaw), and the variances along the swarm's length, width and height axes in m^2.
"""

from __future__ import annotations

CENTRE = slice(0, 3)
ORIENTATION = slice(3, 6)  # roll, pitch, yaw (radians)
SHAPE = slice(6, 9)  # s_length, s_width, s_height (m^2)

I_ROLL, I_PITCH, I_YAW = 3, 4, 5
I_S1, I_S2, I_S3 = 6, 7, 8

NAMES: tuple[str, ...] = (
    "mu_x_m",
    "mu_y_m",
    "mu_z_m",
    "roll_rad",
    "pitch_rad",
    "yaw_rad",
    "s_length_m2",
    "s_width_m2",
    "s_height_m2",
)
