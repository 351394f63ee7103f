"""NED about a home point -> WGS-84 latitude/longitude, against references computed elsewhere:
pymap3d's tangent-plane conversion (to 0.1 mm), Vincenty's geodesic distance on the ellipsoid (to
1 cm over 1 km) and cases worked by hand."""

from __future__ import annotations

import math

import numpy as np
import pymap3d
import pytest
from pymap3d.vincenty import vdist

from protocols.model.geodesy import WGS84_A_M, GeoPoint, ecef_to_geodetic, ned_to_geodetic

HOMES = [
    GeoPoint(),  # PX4 SITL's, Zürich
    GeoPoint(0.0, 0.0, 0.0),
    GeoPoint(-33.8568, 151.2153, 5.0),
    GeoPoint(69.65, 18.96, 100.0),
    GeoPoint(12.0, 179.9995, 30.0),  # 1 km east crosses the antimeridian
]
#: Up to 1 km horizontally in every direction, and up to 120 m above home.
OFFSETS = np.array(
    [[1000, 0, 0], [0, 1000, 0], [-1000, 0, -50], [0, -1000, -120], [707.1, -707.1, -10],
     [-500, 866, 0], [3.2, -1.7, -2.5], [0, 0, -100]],
    dtype=float,
)  # fmt: skip
CM_IN_DEG = 0.01 / 111_000  # 1 cm of latitude, degrees


@pytest.mark.parametrize("home", HOMES, ids=lambda h: f"{h.lat_deg:g},{h.lon_deg:g}")
def test_agrees_with_pymap3d_tangent_plane(home: GeoPoint) -> None:
    lat, lon, alt = ned_to_geodetic(home, OFFSETS)
    for k, (n, e, d) in enumerate(OFFSETS):
        ref_lat, ref_lon, _ = pymap3d.ned2geodetic(n, e, d, home.lat_deg, home.lon_deg, home.alt_m)
        assert lat[k] == pytest.approx(ref_lat, abs=CM_IN_DEG / 100)
        wrapped = (lon[k] - ref_lon + 180.0) % 360.0 - 180.0
        assert wrapped * math.cos(math.radians(ref_lat)) == pytest.approx(0, abs=CM_IN_DEG / 100)
        assert -180.0 <= lon[k] < 180.0
        assert alt[k] == pytest.approx(home.alt_m - d, abs=1e-9)  # the flat world's altitude


@pytest.mark.parametrize("home", HOMES[:4], ids=lambda h: f"{h.lat_deg:g},{h.lon_deg:g}")
def test_ground_distance_and_bearing_match_the_geodesic(home: GeoPoint) -> None:
    """Vincenty on the ellipsoid: the distance from home is the horizontal NED distance and the
    bearing its direction, to 1 cm over 1 km (home on the ellipsoid: at a height h distances
    grow by h / R, 1.6 cm per km per 100 m)."""
    home = GeoPoint(home.lat_deg, home.lon_deg, 0.0)
    flat = OFFSETS.copy()
    flat[:, 2] = 0.0
    lat, lon, _ = ned_to_geodetic(home, flat)
    for k, (n, e, _) in enumerate(flat):
        dist_m, az_deg = vdist(home.lat_deg, home.lon_deg, lat[k], lon[k])
        assert float(dist_m) == pytest.approx(math.hypot(n, e), abs=0.01)
        if math.hypot(n, e) > 100:
            expected_az = math.degrees(math.atan2(e, n)) % 360.0
            off = (float(az_deg) - expected_az + 180.0) % 360.0 - 180.0
            assert off == pytest.approx(0.0, abs=math.degrees(0.01 / 1000))


def test_hand_computed_equator_cases() -> None:
    """At (0, 0, 0) the tangent plane is x = a in ECEF: 1 km east is the point (a, 1000, 0),
    whose longitude is atan(1000 / a) and latitude 0; straight up changes only the altitude."""
    lat, lon, alt = ned_to_geodetic(GeoPoint(0.0, 0.0, 0.0), np.array([[0, 1000, 0], [0, 0, -80]]))
    assert lat[0] == pytest.approx(0.0, abs=1e-12)
    assert lon[0] == pytest.approx(math.degrees(math.atan(1000 / WGS84_A_M)), abs=1e-12)
    assert (lat[1], lon[1], alt[1]) == pytest.approx((0.0, 0.0, 80.0), abs=1e-12)
    # the poles and the equator of the ellipsoid itself
    la, _, h = ecef_to_geodetic(np.array([[0.0, 0.0, 6356752.314245], [WGS84_A_M, 0.0, 0.0]]))
    np.testing.assert_allclose(np.degrees(la), [90.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(h, [0.0, 0.0], atol=1e-6)
