"""Satellite positions from broadcast ephemerides: the Keplerian model and GLONASS integration.

GPS, QZSS, Galileo and BeiDou ephemerides are propagated with the IS-GPS-200 Keplerian model
(each system's own GM and Earth rotation rate; BeiDou GEO satellites C01-C05 and C59-C63 with
their extra -5 deg rotation). GLONASS state vectors are integrated with 4th-order Runge-Kutta
in PZ-90 (J2 and the broadcast luni-solar accelerations). Both take the parameters of one
ephemeris per requested time (as arrays, from :func:`~gnss_citygml.gnss.navigation.read_nav`)
and return ECEF positions in the Earth-fixed frame at that time; which ephemeris serves which
time is decided by :class:`~gnss_citygml.gnss.orbits.BroadcastOrbits`.
"""

from __future__ import annotations

import numpy as np

__all__ = ["KEPLER_CONSTANTS", "glonass_positions", "kepler_positions"]

#: GM (m^3/s^2) and Earth rotation rate (rad/s) of each Keplerian system's ICD.
KEPLER_CONSTANTS = {
    "G": (3.986005e14, 7.2921151467e-5),
    "J": (3.986005e14, 7.2921151467e-5),
    "E": (3.986004418e14, 7.2921151467e-5),
    "C": (3.986004418e14, 7.292115e-5),
}
#: PZ-90 constants of the GLONASS ICD: GM, equatorial radius, J2, Earth rotation rate.
_GLO_GM, _GLO_AE, _GLO_J2, _GLO_OMEGA = 398600.4418e9, 6378136.0, 1082625.75e-9, 7.292115e-5
_GLO_STEP = 60.0


def kepler_positions(eph: dict[str, np.ndarray], tk: np.ndarray) -> np.ndarray:
    """ECEF positions (m) from Keplerian ephemerides at ``tk`` s from toe (IS-GPS-200)."""
    gm, omega_e = eph["gm"], eph["omega_e"]
    a = eph["sqrt_a"] ** 2
    e = eph["e"]
    mean = eph["m0"] + (np.sqrt(gm / a**3) + eph["delta_n"]) * tk
    ecc = mean.copy()
    for _ in range(10):
        ecc -= (ecc - e * np.sin(ecc) - mean) / (1.0 - e * np.cos(ecc))
    nu = np.arctan2(np.sqrt(1.0 - e**2) * np.sin(ecc), np.cos(ecc) - e)
    phi = nu + eph["omega"]
    s2, c2 = np.sin(2 * phi), np.cos(2 * phi)
    u = phi + eph["cus"] * s2 + eph["cuc"] * c2
    r = a * (1.0 - e * np.cos(ecc)) + eph["crs"] * s2 + eph["crc"] * c2
    inc = eph["i0"] + eph["idot"] * tk + eph["cis"] * s2 + eph["cic"] * c2
    xp, yp = r * np.cos(u), r * np.sin(u)
    geo = eph["geo"]
    # BeiDou GEO: the node in the inertial frame, then two rotations (BDS ICD 5.2.4.12).
    node = eph["omega0"] + (eph["omega_dot"] - np.where(geo, 0.0, omega_e)) * tk
    node -= omega_e * eph["toe_sow"]
    cn, sn, ci = np.cos(node), np.sin(node), np.cos(inc)
    xyz = np.column_stack([xp * cn - yp * ci * sn, xp * sn + yp * ci * cn, yp * np.sin(inc)])
    if geo.any():
        xyz[geo] = _bds_geo_rotation(xyz[geo], omega_e[geo] * tk[geo])
    return xyz


def _bds_geo_rotation(xyz: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Rz(angle) Rx(-5 deg) applied to BeiDou GEO positions in the inertial frame."""
    c5, s5 = np.cos(np.radians(5.0)), np.sin(np.radians(5.0))
    x, y, z = xyz.T
    y, z = c5 * y - s5 * z, s5 * y + c5 * z
    ca, sa = np.cos(angle), np.sin(angle)
    return np.column_stack([ca * x + sa * y, -sa * x + ca * y, z])


def _glonass_acceleration(state: np.ndarray, lunisolar: np.ndarray) -> np.ndarray:
    pos, vel = state[:, :3], state[:, 3:]
    r2 = np.einsum("ij,ij->i", pos, pos)
    r = np.sqrt(r2)
    z2 = 5.0 * pos[:, 2] ** 2 / r2
    j2 = 1.5 * _GLO_J2 * _GLO_GM * _GLO_AE**2 / r**5
    acc = -(_GLO_GM / r**3)[:, None] * pos + lunisolar
    acc[:, 0] += -j2 * pos[:, 0] * (1 - z2) + _GLO_OMEGA**2 * pos[:, 0] + 2 * _GLO_OMEGA * vel[:, 1]
    acc[:, 1] += -j2 * pos[:, 1] * (1 - z2) + _GLO_OMEGA**2 * pos[:, 1] - 2 * _GLO_OMEGA * vel[:, 0]
    acc[:, 2] += -j2 * pos[:, 2] * (3 - z2)
    return np.hstack([vel, acc])


def glonass_positions(eph: dict[str, np.ndarray], dt: np.ndarray) -> np.ndarray:
    """ECEF positions (m) from GLONASS state vectors at ``dt`` s from tb (RK4, PZ-90)."""
    state = np.column_stack([eph[k] for k in ("x", "y", "z", "vx", "vy", "vz")])
    lunisolar = np.column_stack([eph[k] for k in ("ax", "ay", "az")])
    steps = max(1, int(np.ceil(np.abs(dt).max(initial=0.0) / _GLO_STEP)))
    h = (dt / steps)[:, None]
    for _ in range(steps):
        k1 = _glonass_acceleration(state, lunisolar)
        k2 = _glonass_acceleration(state + h / 2 * k1, lunisolar)
        k3 = _glonass_acceleration(state + h / 2 * k2, lunisolar)
        k4 = _glonass_acceleration(state + h * k3, lunisolar)
        state = state + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return state[:, :3]
