"""The simulated world on the map: local NED (m) about a home point <-> WGS-84 latitude/longitude.

The simulator's world is flat: gravity is along +D everywhere, and the NED frame is the plane
tangent to the WGS-84 ellipsoid at the home point (``[home]`` of a scenario). A point ``(n, e, d)``
of that plane has the latitude and longitude of the same point in space (local tangent plane ->
ECEF -> geodetic, exact; what ``pymap3d.ned2geodetic`` computes). Its altitude is the flat world's
own: ``home alt - d``, so that the ground reads the home altitude everywhere (the ellipsoid falls
away from the plane by ``(n² + e²) / 2R``, 8 cm at 1 km, which a flat world does not have).

The home altitude is taken as the ellipsoidal height of the plane (the geoid's undulation, tens
of metres, is ignored: it moves a point by under 1 mm per km). Pure numpy; angles in degrees at
the edges (as in the scenario file), radians inside.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from protocols.model.frames import FloatArray

#: WGS-84 semi-major axis (m) and flattening.
WGS84_A_M = 6378137.0
WGS84_F = 1.0 / 298.257223563
WGS84_B_M = WGS84_A_M * (1.0 - WGS84_F)
WGS84_E2 = WGS84_F * (2.0 - WGS84_F)
_EP2 = WGS84_E2 / (1.0 - WGS84_E2)


@dataclass(frozen=True)
class GeoPoint:
    """A point on the map: WGS-84 latitude and longitude (deg) and altitude above mean sea level
    (m). The default is PX4 SITL's home (Zürich), which map ground stations show at once."""

    lat_deg: float = 47.397742
    lon_deg: float = 8.545594
    alt_m: float = 488.0


def geodetic_to_ecef(lat_rad: FloatArray, lon_rad: FloatArray, h_m: FloatArray) -> FloatArray:
    """ECEF (..., 3) m of geodetic latitude, longitude (rad) and ellipsoidal height (m)."""
    sl, cl = np.sin(lat_rad), np.cos(lat_rad)
    prime_vertical = WGS84_A_M / np.sqrt(1.0 - WGS84_E2 * sl * sl)
    r = (prime_vertical + h_m) * cl
    return np.stack(
        [r * np.cos(lon_rad), r * np.sin(lon_rad), (prime_vertical * (1.0 - WGS84_E2) + h_m) * sl],
        axis=-1,
    )


def ecef_to_geodetic(ecef_m: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Latitude, longitude (rad) and ellipsoidal height (m) of ECEF points (..., 3) m.

    Bowring's method with two refinements: below 1e-11 rad (0.1 mm) near the Earth's surface."""
    x, y, z = ecef_m[..., 0], ecef_m[..., 1], ecef_m[..., 2]
    p = np.hypot(x, y)
    lon = np.arctan2(y, x)
    beta = np.arctan2(z * WGS84_A_M, p * WGS84_B_M)  # parametric latitude, first guess
    for _ in range(2):
        sb, cb = np.sin(beta), np.cos(beta)
        lat = np.arctan2(z + _EP2 * WGS84_B_M * sb**3, p - WGS84_E2 * WGS84_A_M * cb**3)
        beta = np.arctan2((1.0 - WGS84_F) * np.sin(lat), np.cos(lat))
    sl = np.sin(lat)
    prime_vertical = WGS84_A_M / np.sqrt(1.0 - WGS84_E2 * sl * sl)
    h = p * np.cos(lat) + (z + WGS84_E2 * prime_vertical * sl) * sl - prime_vertical
    return lat, lon, h


def _ned_axes(lat_rad: float, lon_rad: float) -> FloatArray:
    """Rows: the north, east and down unit vectors (3, 3) in ECEF at a point."""
    sl, cl, so, co = np.sin(lat_rad), np.cos(lat_rad), np.sin(lon_rad), np.cos(lon_rad)
    return np.array([[-sl * co, -sl * so, cl], [-so, co, 0.0], [-cl * co, -cl * so, -sl]])


def ned_to_geodetic(home: GeoPoint, ned_m: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Latitude, longitude (deg) and altitude (m MSL) of NED points ``ned_m`` (N, 3) m about
    ``home``: the tangent plane's point exactly, the altitude flat (``home.alt_m - d``)."""
    ned = np.asarray(ned_m, dtype=float).reshape(-1, 3)
    lat0, lon0 = np.radians(home.lat_deg), np.radians(home.lon_deg)
    origin = geodetic_to_ecef(np.asarray(lat0), np.asarray(lon0), np.asarray(home.alt_m))
    lat, lon, _ = ecef_to_geodetic(origin + ned @ _ned_axes(lat0, lon0))
    lon_deg = (np.degrees(lon) + 180.0) % 360.0 - 180.0
    return np.degrees(lat), lon_deg, home.alt_m - ned[:, 2]


def geodetic_to_ned(
    home: GeoPoint, lat_deg: FloatArray, lon_deg: FloatArray, alt_m: FloatArray
) -> FloatArray:
    """NED points (N, 3) m about ``home`` of latitudes, longitudes (deg) and altitudes (m MSL):
    the inverse of :func:`ned_to_geodetic` (within 0.1 mm over 1 km). The point in space is
    found from its ellipsoidal height, taken as its altitude plus the plane's rise above the
    ellipsoid there (``(n² + e²) / 2R``, from a first pass); down is flat (``home.alt_m - alt``)."""
    lat = np.radians(np.asarray(lat_deg, dtype=float).reshape(-1))
    lon = np.radians(np.asarray(lon_deg, dtype=float).reshape(-1))
    alt = np.asarray(alt_m, dtype=float).reshape(-1)
    lat0, lon0 = np.radians(home.lat_deg), np.radians(home.lon_deg)
    origin = geodetic_to_ecef(np.asarray(lat0), np.asarray(lon0), np.asarray(home.alt_m))
    axes = _ned_axes(lat0, lon0).T
    first = (geodetic_to_ecef(lat, lon, alt) - origin) @ axes
    rise = (first[:, 0] ** 2 + first[:, 1] ** 2) / (2.0 * WGS84_A_M)
    ned = (geodetic_to_ecef(lat, lon, alt + rise) - origin) @ axes
    ned[:, 2] = home.alt_m - alt
    return ned


def ned_of_global_int(
    home: GeoPoint, lat_e7: FloatArray, lon_e7: FloatArray, alt_mm: FloatArray
) -> FloatArray:
    """NED points (N, 3) m about ``home`` of MAVLink GLOBAL_POSITION_INT fields: latitude and
    longitude in 1e-7 degrees, altitude in mm above sea level (:func:`geodetic_to_ned`)."""
    return geodetic_to_ned(
        home,
        np.asarray(lat_e7, dtype=float) * 1e-7,
        np.asarray(lon_e7, dtype=float) * 1e-7,
        np.asarray(alt_mm, dtype=float) * 1e-3,
    )
