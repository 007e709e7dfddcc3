"""Where each satellite is in a receiver's sky: azimuth from true north and elevation.

Angles are measured in the tangent plane of the WGS84 ellipsoid at the receiver (the plane
normal to the geodetic vertical), which is what a building's walls stand on: a geocentric
"up" would tilt every ray by up to 0.2 deg in London.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

__all__ = [
    "OMEGA_EARTH",
    "SPEED_OF_LIGHT",
    "azimuth_elevation",
    "ecef_to_enu",
    "geodetic_to_ecef",
    "sagnac_rotate",
]

#: WGS84 semi-major axis (m) and first eccentricity squared.
WGS84_A = 6378137.0
WGS84_E2 = 6.69437999014e-3
#: Earth's rotation rate (rad/s, IS-GPS-200) and the speed of light (m/s).
OMEGA_EARTH = 7.2921151467e-5
SPEED_OF_LIGHT = 299792458.0


def geodetic_to_ecef(lat: npt.ArrayLike, lon: npt.ArrayLike, h: npt.ArrayLike) -> np.ndarray:
    """WGS84 / ETRS89 latitude, longitude (deg) and ellipsoidal height (m) to ECEF (m).

    >>> np.round(geodetic_to_ecef(0.0, 0.0, 0.0), 3).tolist()
    [6378137.0, 0.0, 0.0]
    """
    lat, lon = np.radians(lat), np.radians(lon)
    h = np.asarray(h, dtype=float)
    sin_lat = np.sin(lat)
    radius = WGS84_A / np.sqrt(1.0 - WGS84_E2 * sin_lat**2)  # prime vertical radius
    x = (radius + h) * np.cos(lat) * np.cos(lon)
    y = (radius + h) * np.cos(lat) * np.sin(lon)
    z = (radius * (1.0 - WGS84_E2) + h) * sin_lat
    return np.stack(np.broadcast_arrays(x, y, z), axis=-1)


def ecef_to_enu(vector: npt.ArrayLike, lat: npt.ArrayLike, lon: npt.ArrayLike) -> np.ndarray:
    """Rotate ECEF vectors (..., 3) into east, north, up at geodetic ``lat``, ``lon`` (deg)."""
    lat, lon = np.radians(lat), np.radians(lon)
    v = np.asarray(vector, dtype=float)
    sl, cl, so, co = np.sin(lat), np.cos(lat), np.sin(lon), np.cos(lon)
    east = -so * v[..., 0] + co * v[..., 1]
    north = -sl * co * v[..., 0] - sl * so * v[..., 1] + cl * v[..., 2]
    up = cl * co * v[..., 0] + cl * so * v[..., 1] + sl * v[..., 2]
    return np.stack([east, north, up], axis=-1)


def azimuth_elevation(
    lat: npt.ArrayLike, lon: npt.ArrayLike, h: npt.ArrayLike, satellite: npt.ArrayLike
) -> tuple[np.ndarray, np.ndarray]:
    """Azimuth (deg clockwise from true north, in [0, 360)) and elevation (deg) of satellites
    at ECEF ``satellite`` (..., 3) seen from receivers at ``lat``, ``lon``, ``h``.

    >>> az, el = azimuth_elevation(0.0, 0.0, 0.0, [2.6e7, 0.0, 0.0])
    >>> float(el)
    90.0
    >>> az, el = azimuth_elevation(0.0, 0.0, 0.0, [WGS84_A, 0.0, 1000.0])
    >>> float(az), round(float(el), 6)
    (0.0, 0.0)
    """
    line = np.asarray(satellite, dtype=float) - geodetic_to_ecef(lat, lon, h)
    e, n, u = np.moveaxis(ecef_to_enu(line, lat, lon), -1, 0)
    azimuth = np.degrees(np.arctan2(e, n)) % 360.0
    elevation = np.degrees(np.arctan2(u, np.hypot(e, n)))
    return azimuth, elevation


def sagnac_rotate(satellite: npt.ArrayLike, travel_time: npt.ArrayLike) -> np.ndarray:
    """Satellite ECEF positions at transmission, expressed in the ECEF frame of reception:
    the Earth turns by ``OMEGA_EARTH * travel_time`` while the signal travels (about 130 m
    at GNSS orbit radius, 0.02 deg of elevation)."""
    theta = OMEGA_EARTH * np.asarray(travel_time, dtype=float)
    s = np.asarray(satellite, dtype=float)
    c, sn = np.cos(theta), np.sin(theta)
    x = c * s[..., 0] + sn * s[..., 1]
    y = -sn * s[..., 0] + c * s[..., 1]
    return np.stack([x, y, s[..., 2]], axis=-1)
