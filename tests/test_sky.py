"""Azimuth and elevation against Google's own values for real phone measurements."""

import numpy as np
import pandas as pd
import pytest

from gnss_citygml.gnss.sky import (
    OMEGA_EARTH,
    azimuth_elevation,
    ecef_to_enu,
    geodetic_to_ecef,
    sagnac_rotate,
)

GOOGLE = [
    (
        "gsdc2022_mtv_2021-04-29_device_gnss_excerpt.csv",
        "gsdc2022_mtv_2021-04-29_ground_truth_excerpt.csv",
    ),
    (
        "gsdc2023_2023-09-07_Pixel7Pro_device_gnss_excerpt.csv",
        "gsdc2023_2023-09-07_Pixel7Pro_ground_truth_excerpt.csv",
    ),
]


@pytest.mark.parametrize(("device", "truth"), GOOGLE)
def test_matches_google_azimuth_elevation(repo_data, device, truth):
    gnss = pd.read_csv(repo_data / "gnss" / device).dropna(subset=["SvPositionXEcefMeters"])
    rx = pd.read_csv(repo_data / "gnss" / truth)
    m = gnss.merge(rx, left_on="utcTimeMillis", right_on="UnixTimeMillis")
    assert len(m) > 100
    sat = m[["SvPositionXEcefMeters", "SvPositionYEcefMeters", "SvPositionZEcefMeters"]]
    az, el = azimuth_elevation(m.LatitudeDegrees, m.LongitudeDegrees, m.AltitudeMeters, sat)
    d_az = (az - m.SvAzimuthDegrees + 180.0) % 360.0 - 180.0
    assert np.abs(el - m.SvElevationDegrees).max() < 0.001
    assert np.abs(d_az).max() < 0.001
    assert ((az >= 0) & (az < 360)).all()


def test_geodetic_to_ecef_against_pyproj():
    from pyproj import Transformer

    lat, lon, h = np.array([51.5246, -33.9, 89.9]), np.array([-0.134, 151.2, 10.0]), [30.0] * 3
    t = Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True, allow_ballpark=False)
    x, y, z = t.transform(lon, lat, h)
    assert np.abs(geodetic_to_ecef(lat, lon, h) - np.c_[x, y, z]).max() < 1e-6


def test_enu_axes_at_london():
    lat, lon = 51.5, -0.13
    up = geodetic_to_ecef(lat, lon, 100.0) - geodetic_to_ecef(lat, lon, 0.0)
    np.testing.assert_allclose(ecef_to_enu(up, lat, lon), [0.0, 0.0, 100.0], atol=1e-8)
    north = geodetic_to_ecef(lat + 1e-4, lon, 0.0) - geodetic_to_ecef(lat, lon, 0.0)
    e, n, u = ecef_to_enu(north, lat, lon)
    assert n > 11.0 and abs(e) < 1e-9 and abs(u) < 1e-3


def test_due_east_low_satellite():
    here = geodetic_to_ecef(51.5, -0.13, 0.0)
    east = ecef_to_enu(np.eye(3), 51.5, -0.13)[:, 0]  # ECEF components of the east axis
    az, el = azimuth_elevation(51.5, -0.13, 0.0, here + 2.0e7 * east)
    assert az == pytest.approx(90.0, abs=1e-9)
    assert -2.0 < el < 0.0  # the tangent plane drops away from a straight line over 20,000 km


def test_sagnac_rotation_turns_with_the_earth():
    sat = np.array([2.6e7, 0.0, 1.0e7])
    turned = sagnac_rotate(sat, 0.075)
    assert turned[2] == sat[2]
    assert np.linalg.norm(turned[:2]) == pytest.approx(2.6e7)
    assert turned[1] == pytest.approx(-2.6e7 * OMEGA_EARTH * 0.075, rel=1e-6)
