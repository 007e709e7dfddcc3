"""Nominal Keplerian GNSS constellations and the sky they draw over a receiver.

Circular orbits in each system's nominal Walker geometry are enough for a simulator: what
matters for building heights is how many satellites a phone sees and how they spread in
azimuth and elevation, not metre-level orbits (the orbit readers of ``gnss_citygml.gnss`` are
for real data).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

__all__ = ["CONSTELLATIONS", "Constellation", "satellite_ecef", "sky"]

_GM = 3.986004418e14  # m^3/s^2
_OMEGA_E = 7.2921151467e-5  # rad/s
_WGS84_A = 6378137.0
_WGS84_E2 = 6.69437999014e-3


@dataclass(frozen=True)
class Constellation:
    """A Walker constellation: ``n_planes`` planes of ``per_plane`` satellites."""

    letter: str
    n_planes: int
    per_plane: int
    inclination: float  # deg
    semi_major_axis: float  # m
    phasing: int  # Walker phasing factor f

    @property
    def size(self) -> int:
        return self.n_planes * self.per_plane


#: GPS (6 planes x 5, as the ~31 satellites in orbit), GLONASS (3 x 8), Galileo (Walker
#: 27/3/1 with spares) and BeiDou-3 MEO (Walker 24/3/1).
CONSTELLATIONS = (
    Constellation("G", 6, 5, 55.0, 26_559_700.0, 1),
    Constellation("R", 3, 8, 64.8, 25_508_200.0, 1),
    Constellation("E", 3, 9, 56.0, 29_599_800.0, 1),
    Constellation("C", 3, 8, 55.0, 27_906_100.0, 1),
)


def satellite_ecef(
    seconds: npt.ArrayLike, constellations: Iterable[Constellation] = CONSTELLATIONS
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """ECEF positions (m) of every satellite at times ``seconds`` (s since the simulation epoch).

    Returns
    -------
    (letters, svids, xyz)
        Arrays of length ``n_sat`` and an ``(n_times, n_sat, 3)`` array.
    """
    t = np.atleast_1d(np.asarray(seconds, dtype=float))[:, None]
    letters, svids, xyz = [], [], []
    for k, con in enumerate(constellations):
        plane = np.repeat(np.arange(con.n_planes), con.per_plane)
        slot = np.tile(np.arange(con.per_plane), con.n_planes)
        raan = np.radians(360.0 * plane / con.n_planes + 17.0 * k)
        phase = 2 * np.pi * (slot / con.per_plane + con.phasing * plane / con.size)
        mean_motion = np.sqrt(_GM / con.semi_major_axis**3)
        u = phase + mean_motion * t  # argument of latitude (circular orbit)
        node = raan - _OMEGA_E * t  # right ascension of the node in the rotating Earth frame
        inc = np.radians(con.inclination)
        r = con.semi_major_axis
        x = r * (np.cos(u) * np.cos(node) - np.sin(u) * np.cos(inc) * np.sin(node))
        y = r * (np.cos(u) * np.sin(node) + np.sin(u) * np.cos(inc) * np.cos(node))
        z = r * np.sin(u) * np.sin(inc) * np.ones_like(node)
        letters.append(np.full(con.size, con.letter))
        svids.append(np.arange(1, con.size + 1))
        xyz.append(np.stack([x, y, z], axis=-1))
    return np.concatenate(letters), np.concatenate(svids), np.concatenate(xyz, axis=1)


def sky(
    lat: float, lon: float, height: float, sat_xyz: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Azimuth (deg from true north) and elevation (deg, on the WGS84 ellipsoid's tangent plane)
    of satellites ``sat_xyz`` (``(..., 3)``, ECEF m) seen from one geodetic position."""
    phi, lam = np.radians(lat), np.radians(lon)
    n = _WGS84_A / np.sqrt(1 - _WGS84_E2 * np.sin(phi) ** 2)
    rx = (n + height) * np.cos(phi) * np.cos(lam)
    ry = (n + height) * np.cos(phi) * np.sin(lam)
    rz = (n * (1 - _WGS84_E2) + height) * np.sin(phi)
    d = sat_xyz - np.array([rx, ry, rz])
    east = -np.sin(lam) * d[..., 0] + np.cos(lam) * d[..., 1]
    north = (
        -np.sin(phi) * np.cos(lam) * d[..., 0]
        - np.sin(phi) * np.sin(lam) * d[..., 1]
        + np.cos(phi) * d[..., 2]
    )
    up = (
        np.cos(phi) * np.cos(lam) * d[..., 0]
        + np.cos(phi) * np.sin(lam) * d[..., 1]
        + np.sin(phi) * d[..., 2]
    )
    az = np.degrees(np.arctan2(east, north)) % 360.0
    el = np.degrees(np.arctan2(up, np.hypot(east, north)))
    return az, el
