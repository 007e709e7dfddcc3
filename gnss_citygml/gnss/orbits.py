"""Satellite positions from SP3 precise orbits and RINEX navigation files.

:func:`load_orbits` reads any mix of files and returns an :class:`Orbits`: SP3 files when there
are any (precise, preferred), otherwise the broadcast ephemerides of the navigation files. Both
kinds answer the same questions, with times given in UTC (converted to GPS time inside):

* :meth:`Orbits.positions` -- ECEF positions of given satellites at given times;
* :meth:`Orbits.positions_all` -- every satellite of the source at a set of epochs, the input of
  the sky stage ("all satellites above the mask").

**SP3** (versions c and d, GPS/GLONASS/Galileo/BeiDou/QZSS): positions (km in the file, m
here) are interpolated with a 10-point Lagrange polynomial centred on each requested time
(millimetres; within two epochs of either end of the data the window is one-sided and the error
grows to centimetres: give the neighbouring days' files too). The header's epoch count is not
trusted (real files are often cut). A position of 0.000000 is a missing value; a window may
bridge one missing epoch, larger gaps give NaN. Epochs are read in the file's time system
(the ``%c`` line: GPS, GAL, QZS, BDT, TAI, UTC or GLO).

**RINEX navigation** (RINEX 2 GPS ``.n``, RINEX 3 mixed): GPS, QZSS, Galileo and BeiDou
ephemerides are propagated with the IS-GPS-200 Keplerian model (each system's own GM and Earth
rotation rate; BeiDou GEO satellites C01-C05 and C59-C63 with their extra -5 deg rotation).
GLONASS state vectors are integrated with 4th-order Runge-Kutta in PZ-90 (J2 and the broadcast
luni-solar accelerations). For each satellite and time the ephemeris nearest in time (toe, or tb
for GLONASS) within the maximum age :data:`MAX_AGE` is used, a healthy one when there is one;
:meth:`Orbits.positions_all` leaves out satellites with only unhealthy ephemerides. SBAS and
NavIC/IRNSS records are skipped (listed in :attr:`Orbits.notes`).

Positions are in the Earth-fixed frame *at the requested instant* (ITRF/IGS for SP3, WGS84 /
PZ-90 / GTRF / CGCS2000 for broadcast: centimetres apart). SP3 gives the centre of mass,
broadcast orbits the antenna phase centre (1-2 m apart for GPS). Where a signal's transmit time
matters, ask for that time and rotate for the travel time yourself; for azimuth and elevation
the 0.07 s travel time changes the direction by less than 0.001 deg.

Satellites the source does not have, or has no usable data for at a time (a position no GNSS
orbit has, 20,000 to 50,000 km from the Earth's centre, counts as none), give NaN rows in
:meth:`Orbits.positions` and no rows in :meth:`Orbits.positions_all`. Times outside the span of
the source raise :class:`OrbitSpanError`, which names both spans: nothing is extrapolated.
"""

from __future__ import annotations

import datetime
import gzip
from abc import ABC, abstractmethod
from collections.abc import Iterable
from pathlib import Path

import numpy as np
import pandas as pd

from gnss_citygml.errors import InputError
from gnss_citygml.gnss.gpstime import (
    BDT_MINUS_GPS,
    GPS_EPOCH,
    gps_seconds,
    gps_to_utc,
    to_datetime64,
    utc_to_gps,
)
from gnss_citygml.paths import input_file

__all__ = [
    "MAX_AGE",
    "BroadcastOrbits",
    "OrbitSpanError",
    "Orbits",
    "Sp3Orbits",
    "load_orbits",
    "read_nav",
    "read_sp3",
]

#: Longest time (s) between a requested time and the ephemeris used, per constellation.
MAX_AGE = {"G": 4 * 3600.0, "J": 2 * 3600.0, "E": 4 * 3600.0, "C": 2 * 3600.0, "R": 1800.0}

_WEEK = 604800.0
_NS = 1_000_000_000
_LAGRANGE_POINTS = 10
#: Distance (m) from the Earth's centre of every GNSS satellite, with a margin: GLONASS at
#: 25,500 km to QZSS's inclined geosynchronous orbits at up to 45,300 km.
_ORBIT_RADIUS = (2.0e7, 5.0e7)
#: Missing epochs a Lagrange window may bridge.
_MAX_MISSING_EPOCHS = 1
#: GM (m^3/s^2) and Earth rotation rate (rad/s) of each Keplerian system's ICD.
_KEPLER_CONSTANTS = {
    "G": (3.986005e14, 7.2921151467e-5),
    "J": (3.986005e14, 7.2921151467e-5),
    "E": (3.986004418e14, 7.2921151467e-5),
    "C": (3.986004418e14, 7.292115e-5),
}
#: PZ-90 constants of the GLONASS ICD: GM, equatorial radius, J2, Earth rotation rate.
_GLO_GM, _GLO_AE, _GLO_J2, _GLO_OMEGA = 398600.4418e9, 6378136.0, 1082625.75e-9, 7.292115e-5
_GLO_STEP = 60.0
#: Offset (s) added to SP3 epochs in each time system to get GPS time (UTC-based: leap seconds).
_SP3_TIME_SYSTEMS = {"GPS": 0, "GAL": 0, "QZS": 0, "BDT": -BDT_MINUS_GPS, "TAI": -19}
_KEPLER_FIELDS = (
    "iode crs delta_n m0 cuc e cus sqrt_a toe_sow cic omega0 cis i0 crc omega omega_dot idot "
    "codes week l2p_flag accuracy health"
).split()
_GLONASS_FIELDS = "x vx ax health y vy ay freq z vz az".split()
_GLONASS_STATE = "x y z vx vy vz ax ay az".split()
#: The ephemeris parameters the propagators use.
_PARAMETERS = set(_KEPLER_FIELDS) | set(_GLONASS_STATE)


class OrbitSpanError(InputError):
    """Positions were asked for outside the time span the orbit files cover."""


def _where(path, line_no: int | None = None) -> str:
    return str(path) if line_no is None else f"{path}, line {line_no}"


def _garbled(path, line_no: int, text: str, why: str) -> InputError:
    return InputError(
        f"{why}: {text.rstrip()[:80]!r}",
        where=_where(path, line_no),
        fix="the file is garbled or truncated: download it again",
    )


def _read_lines(path: Path, first_only: bool = False):
    """The lines of a text file (gzip too), or only its first line."""
    path = input_file(path, "orbit file")
    if path.suffix == ".Z":
        raise InputError(
            "Unix-compressed (.Z) files are not read", where=str(path), fix="run `gzip -d` first"
        )
    opener = gzip.open if path.suffix == ".gz" else open
    try:
        with opener(path, "rt", encoding="ascii", errors="replace") as f:
            return f.readline() if first_only else f.read().splitlines()
    except (OSError, EOFError) as exc:
        raise InputError(f"cannot read the file ({exc})", where=str(path)) from exc


def _float(text: str, path, line_no: int) -> float:
    """A Fortran number (``D`` or ``E`` exponent); blank is NaN. No file writes "nan" or
    "inf": they are garbled numbers, as any other word."""
    text = text.strip()
    if not text:
        return np.nan
    try:
        value = float(text.replace("D", "E").replace("d", "e"))
    except ValueError:
        value = np.nan
    if not np.isfinite(value):
        raise _garbled(path, line_no, text, "unreadable number")
    return value


def _epoch(text: str, path, line_no: int, line: str, two_digit_year: bool = False):
    """The epoch of a record (year, month, day, hour, minute as integers, then seconds), as
    ``datetime64[ns]``; a date that does not exist or lies outside 1980-2099 is garbled."""
    parts = text.split()
    try:
        y, mo, d, h, mi = (int(p) for p in parts[:5])
        sec = float(parts[5])
        if len(parts) != 6:
            raise ValueError
        if two_digit_year:
            y += 2000 if y < 80 else 1900
        day = datetime.date(y, mo, d)
    except (ValueError, IndexError, OverflowError):
        raise _garbled(path, line_no, line, "unreadable epoch") from None
    if not (1980 <= y < 2100 and 0 <= h <= 24 and 0 <= mi < 60 and 0 <= sec < 61):
        raise _garbled(path, line_no, line, "impossible epoch")
    return np.datetime64(day, "ns") + np.timedelta64(round((h * 3600 + mi * 60 + sec) * _NS), "ns")


# --------------------------------------------------------------------------------------- SP3


def read_sp3(path) -> pd.DataFrame:
    """Read an SP3-c or SP3-d orbit file (optionally ``.gz``).

    Parameters
    ----------
    path
        The SP3 file.

    Returns
    -------
    pandas.DataFrame
        One row per satellite and epoch: ``time_gps`` (naive ``datetime64[ns]`` in GPS time,
        whatever the file's time system), ``constellation`` (RINEX letter), ``svid``, ``x``,
        ``y``, ``z`` (ECEF, m; NaN where the file marks the position missing) and ``clock``
        (microseconds; NaN for 999999.999999). ``attrs`` holds ``version`` and ``time_system``.

    Raises
    ------
    InputError
        Not an SP3-c/d file, an unknown time system, or a garbled line (with file and line).
    """
    lines = _read_lines(path)
    if not lines or not lines[0].startswith("#") or lines[0][1:2] not in ("c", "d"):
        raise InputError(
            "not an SP3-c or SP3-d orbit file (the first line must start with #c or #d)",
            where=_where(path, 1),
            fix="give an SP3-c/d file (e.g. an IGS or MGEX *_ORB.SP3 product)",
        )
    version = lines[0][1]
    time_system = "GPS"
    for line in lines:
        if line.startswith("%c"):
            time_system = line[9:12].strip()
            break
    if time_system in ("", "ccc"):
        time_system = "GPS"
    if time_system not in _SP3_TIME_SYSTEMS and time_system not in ("UTC", "GLO"):
        raise InputError(
            f"unsupported SP3 time system {time_system!r}",
            where=str(path),
            fix="use a product in GPS, GAL, QZS, BDT, TAI, UTC or GLO time",
        )
    times, cons, svids, values = [], [], [], []
    epoch = None
    for no, line in enumerate(lines, start=1):
        tag = line[:1]
        if tag == "*":
            epoch = _epoch(line[1:], path, no, line)
        elif tag == "P":
            if epoch is None:
                raise _garbled(path, no, line, "position record before the first epoch line")
            if len(line) < 60:
                raise _garbled(path, no, line, "truncated position record")
            try:
                svid = int(line[2:4])
            except ValueError:
                raise _garbled(path, no, line, "unreadable satellite id") from None
            times.append(epoch)
            cons.append(line[1] if line[1] != " " else "G")
            svids.append(svid)
            values.append([_float(line[k : k + 14], path, no) for k in (4, 18, 32, 46)])
        elif epoch is not None and tag not in ("E", "V", "") and not line.startswith("EOF"):
            raise _garbled(path, no, line, "unknown SP3 record")
    if not times:
        raise InputError("the SP3 file has no position records", where=str(path))
    xyzc = np.array(values)
    xyz = xyzc[:, :3] * 1000.0
    xyz[np.all(xyzc[:, :3] == 0.0, axis=1)] = np.nan
    clock = np.where(xyzc[:, 3] >= 999999.0, np.nan, xyzc[:, 3])
    table = pd.DataFrame(
        {
            "time_gps": _to_gps_time(np.array(times), time_system),
            "constellation": cons,
            "svid": np.array(svids, dtype=np.int64),
            "x": xyz[:, 0],
            "y": xyz[:, 1],
            "z": xyz[:, 2],
            "clock": clock,
        }
    )
    table.attrs.update(version=version, time_system=time_system)
    return table


def _to_gps_time(times: np.ndarray, time_system: str) -> np.ndarray:
    if time_system == "GLO":  # UTC(SU) + 3 h
        times = times - np.timedelta64(3, "h")
    if time_system in ("UTC", "GLO"):
        return utc_to_gps(times)
    return times + np.timedelta64(_SP3_TIME_SYSTEMS[time_system], "s")


# ---------------------------------------------------------------------------- RINEX navigation


def read_nav(path) -> pd.DataFrame:
    """Read a RINEX 2 GPS or RINEX 3 (mixed) navigation file (optionally ``.gz``).

    Parameters
    ----------
    path
        The navigation file (``brdcDDD0.YYn``, ``*_MN.rnx``, ...).

    Returns
    -------
    pandas.DataFrame
        One row per ephemeris: ``constellation``, ``svid``, ``toe`` (naive ``datetime64[ns]``
        in GPS time: the time of ephemeris, or tb for GLONASS), ``healthy`` (bool) and the
        model's parameters (Keplerian: ``sqrt_a``, ``e``, ``i0``, ``omega0``, ``omega``,
        ``m0``, ``delta_n``, ``idot``, ``omega_dot``, ``cuc`` ... ``cis``, ``toe_sow``;
        GLONASS: ``x``, ``vx``, ``ax``, ... in m, m/s, m/s^2). ``attrs["skipped"]`` counts
        the records of systems that are not read (SBAS, NavIC).

    Raises
    ------
    InputError
        Not a navigation file, an unsupported version, or a garbled line (with file and line).
    """
    lines = _read_lines(path)
    version, header_end = _nav_header(lines, path)
    records = _rinex2_records if version < 3 else _rinex3_records
    rows, skipped = [], {}
    for no, system, svid, epoch, values in records(lines, header_end, path, version):
        if system in _KEPLER_CONSTANTS:
            toe_sow = values[3 + _KEPLER_FIELDS.index("toe_sow")]
            if not 0.0 <= toe_sow <= _WEEK:  # NaN too
                raise _garbled(path, no, lines[no - 1], f"time of ephemeris {toe_sow:g} s")
            rows.append(_kepler_row(system, svid, epoch, values))
        elif system == "R":
            rows.append(_glonass_row(svid, epoch, values))
        else:
            skipped[system] = skipped.get(system, 0) + 1
    if not rows:
        raise InputError(
            "no GPS, GLONASS, Galileo, BeiDou or QZSS ephemerides in the file",
            where=str(path),
            fix="give a navigation file with ephemerides of these systems",
        )
    table = pd.DataFrame(rows)
    table["svid"] = table["svid"].astype(np.int64)
    table.attrs["skipped"] = skipped
    return table


def _nav_header(lines: list[str], path) -> tuple[float, int]:
    first = lines[0] if lines else ""
    if "RINEX VERSION / TYPE" not in first:
        raise InputError(
            "not a RINEX file (no RINEX VERSION / TYPE on the first line)",
            where=_where(path, 1),
            fix="give a RINEX navigation file or an SP3 orbit file",
        )
    version = _float(first[:9], path, 1)
    kind = first[20:21]
    if kind != "N" or not 2 <= version < 4:
        raise InputError(
            f"unsupported RINEX file: version {version:g}, type {kind!r}",
            where=_where(path, 1),
            fix="give a RINEX 2 GPS (.n) or RINEX 3 navigation file, or an SP3 file",
        )
    for no, line in enumerate(lines):
        if "END OF HEADER" in line[60:]:
            return version, no + 1
    raise InputError("no END OF HEADER line", where=str(path), fix="the file is truncated")


def _record_values(group: list[tuple[int, str]], first_at: int, rest_at: int, path) -> list:
    """The D19.12 numbers of a record: 3 on its first line, 4 on each continuation line."""
    values = []
    for k, (no, line) in enumerate(group):
        starts = range(first_at, first_at + 57, 19) if k == 0 else range(rest_at, rest_at + 76, 19)
        values.extend(_float(line[i : i + 19], path, no) for i in starts)
    return values


def _rinex2_records(lines, header_end, path, version):
    body = [(no + 1, line) for no, line in enumerate(lines) if no >= header_end and line.strip()]
    for k in range(0, len(body), 8):
        group = body[k : k + 8]
        no, line = group[0]
        if len(group) < 8:
            raise _garbled(path, no, line, "truncated record")
        for cont_no, cont in group[1:]:
            if cont[:3].strip():
                raise _garbled(path, cont_no, cont, "expected a continuation line")
        try:
            svid = int(line[:2])
        except ValueError:
            raise _garbled(path, no, line, "unreadable satellite number") from None
        epoch = _epoch(line[2:22], path, no, line, two_digit_year=True)
        yield no, "G", svid, epoch, _record_values(group, 22, 3, path)


def _rinex3_records(lines, header_end, path, version):
    glonass_lines = 5 if version >= 3.05 else 4
    sizes = {"G": 8, "E": 8, "C": 8, "J": 8, "I": 8, "R": glonass_lines, "S": 4}
    no = header_end
    while no < len(lines):
        line = lines[no]
        if not line.strip():
            no += 1
            continue
        system = line[0]
        if system not in sizes:
            raise _garbled(path, no + 1, line, "expected the first line of a record")
        group = [(no + 1 + k, text) for k, text in enumerate(lines[no : no + sizes[system]])]
        if len(group) < sizes[system]:
            raise _garbled(path, no + 1, line, "truncated record")
        for cont_no, cont in group[1:]:
            if cont[:4].strip():
                raise _garbled(path, cont_no, cont, "expected a continuation line")
        try:
            svid = int(line[1:3])
        except ValueError:
            raise _garbled(path, no + 1, line, "unreadable satellite number") from None
        epoch = _epoch(line[4:23], path, no + 1, line)
        yield no + 1, system, svid, epoch, _record_values(group, 23, 4, path)
        no += sizes[system]


def _kepler_row(system: str, svid: int, epoch: np.datetime64, values: list) -> dict:
    row = dict(zip(_KEPLER_FIELDS, values[3:], strict=False))
    # toc is in the system's own time; the week is found from toc, not from the week field.
    toc = (epoch - GPS_EPOCH).astype(np.int64) / _NS
    toe = toc + (row["toe_sow"] - toc % _WEEK + _WEEK / 2) % _WEEK - _WEEK / 2
    if system == "C":
        toe -= BDT_MINUS_GPS
    row.update(
        constellation=system,
        svid=svid,
        toe=GPS_EPOCH + np.timedelta64(round(toe * _NS), "ns"),
        healthy=row["health"] == 0,
    )
    return row


def _glonass_row(svid: int, epoch: np.datetime64, values: list) -> dict:
    fields = dict(zip(_GLONASS_FIELDS, values[3:14], strict=True))
    row = {k: fields[k] * 1000.0 for k in _GLONASS_STATE}  # km -> m
    row.update(
        constellation="R",
        svid=svid,
        toe=utc_to_gps(epoch)[0],  # tb is in UTC
        healthy=fields["health"] == 0,
    )
    return row


# ------------------------------------------------------------------------------- propagation


def _lagrange(nodes_t: np.ndarray, nodes_xyz: np.ndarray, t: np.ndarray, step: float):
    """10-point Lagrange interpolation; NaN where no window of nodes without a gap holds t.

    The window is centred on t when it can be; near the ends of the series or next to a gap it
    is shifted (t stays between its first and last node: never extrapolation).
    """
    n, m = _LAGRANGE_POINTS, nodes_t.size
    out = np.full((t.size, 3), np.nan)
    if m < n or t.size == 0:
        return out
    centred = np.searchsorted(nodes_t, t) - n // 2
    start = np.full(t.size, -1)
    for shift in sorted(range(1 - n // 2, n // 2), key=abs):  # 0, -1, 1, ... : centred first
        first = np.clip(centred + shift, 0, m - n)
        last = first + n - 1
        fits = (nodes_t[first] <= t) & (t <= nodes_t[last]) & (start < 0)
        fits &= nodes_t[last] - nodes_t[first] <= (n - 1 + _MAX_MISSING_EPOCHS + 1e-6) * step
        start[fits] = first[fits]
    ok = start >= 0
    idx = start[ok, None] + np.arange(n)
    x = (nodes_t[idx] - t[ok, None]) / step
    eye = np.eye(n, dtype=bool)
    num = np.where(eye, 1.0, -x[:, None, :]).prod(axis=2)
    den = np.where(eye, 1.0, x[:, :, None] - x[:, None, :]).prod(axis=2)
    out[ok] = np.einsum("mj,mjc->mc", num / den, nodes_xyz[idx])
    return out


def _kepler(eph: dict[str, np.ndarray], tk: np.ndarray) -> np.ndarray:
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


def _glonass(eph: dict[str, np.ndarray], dt: np.ndarray) -> np.ndarray:
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


# ------------------------------------------------------------------------------------ Orbits


def _merge(starts: np.ndarray, ends: np.ndarray) -> np.ndarray:
    """Union of closed intervals as an (n, 2) array of disjoint, sorted intervals."""
    order = np.argsort(starts)
    starts, ends = starts[order], np.maximum.accumulate(ends[order])
    new = np.concatenate([[True], starts[1:] > ends[:-1]])
    last = np.concatenate([np.flatnonzero(new)[1:] - 1, [starts.size - 1]])
    return np.column_stack([starts[new], ends[last]])


def _names(paths: Iterable) -> str:
    return ", ".join(Path(p).name for p in paths)


def _utc_text(t_gps: float) -> str:
    gps = GPS_EPOCH + np.timedelta64(round(t_gps * _NS), "ns")
    return str(pd.Timestamp(gps_to_utc(gps)[0]).round("ms")) + " UTC"


class Orbits(ABC):
    """Satellite positions from one orbit source; see :func:`load_orbits`.

    Attributes
    ----------
    source
        ``"sp3"`` or ``"broadcast"``.
    paths
        The files the positions come from.
    notes
        What was left out and why (ignored files, skipped systems), for the user.
    """

    source = ""

    def __init__(self, paths: Iterable, coverage: np.ndarray, notes: Iterable[str] = ()):
        self.paths = tuple(Path(p) for p in paths)
        self.notes = list(notes)
        self._coverage = coverage  # disjoint GPS-second intervals with data

    @property
    def satellites(self) -> list[tuple[str, int]]:
        """The satellites of the source as sorted ``(constellation, svid)`` pairs."""
        return sorted(self._satellites())

    @property
    def span(self) -> tuple[pd.Timestamp, pd.Timestamp]:
        """First and last time (UTC) positions can be computed for."""
        first, last = self._coverage[0, 0], self._coverage[-1, 1]
        utc = gps_to_utc(GPS_EPOCH + (np.array([first, last]) * _NS).astype("timedelta64[ns]"))
        return pd.Timestamp(utc[0], tz="UTC"), pd.Timestamp(utc[1], tz="UTC")

    def positions(self, times_utc, constellation, svid) -> np.ndarray:
        """ECEF positions (m) of satellites at UTC times.

        Parameters
        ----------
        times_utc
            Times (``datetime64``, pandas; naive times are UTC).
        constellation, svid
            The satellite(s): one for all times or one per time (RINEX letter, number).

        Returns
        -------
        numpy.ndarray
            ``(n, 3)`` ECEF x, y, z; NaN rows where the source has no data for the satellite.

        Raises
        ------
        OrbitSpanError
            Some times are outside the span of the orbit files.
        """
        times = to_datetime64(times_utc)
        t = self._gps_seconds(times)
        letters = np.asarray(constellation, dtype=str)
        if letters.size and np.char.str_len(letters).max() != 1:
            raise InputError(
                f"constellation {letters.flat[0]!r} is not a RINEX letter",
                fix="use G (GPS), R (GLONASS), E (Galileo), C (BeiDou) or J (QZSS)",
            )
        cons = np.broadcast_to(letters.astype("U1"), t.shape)
        nums = np.broadcast_to(np.asarray(svid, dtype=np.int64), t.shape)
        # One integer per satellite: the letter's code point and the number.
        keys, inverse = np.unique(cons.view(np.int32) * 1000 + nums, return_inverse=True)
        order = np.argsort(inverse, kind="stable")
        bounds = np.searchsorted(inverse[order], np.arange(keys.size + 1))
        out = np.full((t.size, 3), np.nan)
        known = self._satellites()
        for k, key in enumerate(keys):
            sat = (chr(key // 1000), int(key % 1000))
            if sat in known:
                rows = order[bounds[k] : bounds[k + 1]]
                out[rows] = self._plausible_positions(sat, t[rows], healthy_only=False)
        return out

    def positions_all(
        self, times_utc, constellations: str | None = None, healthy_only: bool = True
    ) -> pd.DataFrame:
        """Positions of every satellite of the source at each of the given times.

        Parameters
        ----------
        times_utc
            Epochs (``datetime64``, pandas; naive times are UTC).
        constellations
            Only these systems, e.g. ``"GE"`` (default: all).
        healthy_only
            Leave out satellites whose broadcast ephemeris says unhealthy: a receiver does not
            track them, so their absence is no sign of a blocked signal. SP3 files carry no
            health flags: all their satellites are kept.

        Returns
        -------
        pandas.DataFrame
            ``time_utc`` (``datetime64[ns, UTC]``), ``constellation``, ``svid``, ``x``, ``y``,
            ``z`` (ECEF, m), time-major; satellites without data at a time have no row.

        Raises
        ------
        OrbitSpanError
            Some times are outside the span of the orbit files.
        """
        times = to_datetime64(times_utc)
        t = self._gps_seconds(times)
        sats = [s for s in self.satellites if constellations is None or s[0] in constellations]
        xyz = np.full((t.size, len(sats), 3), np.nan)
        for k, sat in enumerate(sats):
            xyz[:, k] = self._plausible_positions(sat, t, healthy_only)
        table = pd.DataFrame(
            {
                "time_utc": pd.DatetimeIndex(np.repeat(times, len(sats))).tz_localize("UTC"),
                "constellation": np.tile([s[0] for s in sats], t.size),
                "svid": np.tile(np.array([s[1] for s in sats], dtype=np.int64), t.size),
                "x": xyz[..., 0].ravel(),
                "y": xyz[..., 1].ravel(),
                "z": xyz[..., 2].ravel(),
            }
        )
        return table[np.isfinite(xyz[..., 0].ravel())].reset_index(drop=True)

    def _gps_seconds(self, times: np.ndarray) -> np.ndarray:
        """GPS seconds of UTC times, after checking that the orbits cover them all."""
        t = gps_seconds(utc_to_gps(times))
        cov = self._coverage
        k = np.searchsorted(cov[:, 0], t, side="right") - 1
        inside = (k >= 0) & (t <= cov[np.maximum(k, 0), 1])
        if not inside.all():
            spans = "; ".join(f"{_utc_text(a)} to {_utc_text(b)}" for a, b in cov[:5])
            if len(cov) > 5:
                spans += f" (and {len(cov) - 5} more pieces)"
            bad = t[~inside]
            raise OrbitSpanError(
                f"the orbits cover {spans} but positions were requested from "
                f"{_utc_text(t.min())} to {_utc_text(t.max())} ({bad.size} of {t.size} times "
                f"outside, first {_utc_text(bad.min())})",
                where=_names(self.paths),
                fix="give orbit files (SP3 or RINEX navigation) that cover the requested times",
            )
        return t

    def _plausible_positions(self, sat: tuple[str, int], t: np.ndarray, healthy_only: bool):
        """:meth:`_sat_positions`, NaN where no GNSS orbit goes (from a garbled ephemeris or
        SP3 record): the arithmetic on such numbers may overflow, quietly."""
        with np.errstate(all="ignore"):
            xyz = self._sat_positions(sat, t, healthy_only)
            radius = np.sqrt((xyz**2).sum(axis=1))
        xyz[~((radius >= _ORBIT_RADIUS[0]) & (radius <= _ORBIT_RADIUS[1]))] = np.nan
        return xyz

    @abstractmethod
    def _satellites(self) -> Iterable[tuple[str, int]]:
        """The satellites with data."""

    @abstractmethod
    def _sat_positions(self, sat: tuple[str, int], t: np.ndarray, healthy_only: bool):
        """(n, 3) positions of one satellite at GPS seconds ``t``, NaN where unknown."""


class Sp3Orbits(Orbits):
    """Positions interpolated from SP3 precise orbits (10-point Lagrange).

    Parameters
    ----------
    table
        Rows of :func:`read_sp3` (one or more files, concatenated).
    paths
        The files the table came from.
    notes
        Remarks to pass on to the user.
    """

    source = "sp3"

    def __init__(self, table: pd.DataFrame, paths: Iterable = (), notes: Iterable[str] = ()):
        t = gps_seconds(table["time_gps"])
        epochs = np.unique(t)
        if epochs.size < _LAGRANGE_POINTS:
            raise InputError(
                f"{epochs.size} SP3 epochs: interpolation needs at least {_LAGRANGE_POINTS}",
                where=_names(paths),
                fix="give the SP3 files of the whole day (and the neighbouring days)",
            )
        step = np.diff(epochs)
        self.step = float(np.median(step))
        joined = step <= (1 + _MAX_MISSING_EPOCHS) * self.step + 1e-6
        coverage = _merge(epochs[:-1][joined], epochs[1:][joined])
        super().__init__(paths, coverage, notes)
        good = table.assign(t=t).dropna(subset=["x", "y", "z"])
        good = good.drop_duplicates(["constellation", "svid", "t"]).sort_values("t")
        self._series = {}
        for (cons, svid), rows in good.groupby(["constellation", "svid"]):
            if len(rows) >= _LAGRANGE_POINTS:
                self._series[(cons, int(svid))] = (
                    rows["t"].to_numpy(),
                    rows[["x", "y", "z"]].to_numpy(),
                )
            else:
                self.notes.append(f"{cons}{svid:02d} left out: fewer than 10 SP3 positions")

    def _satellites(self):
        return self._series.keys()

    def _sat_positions(self, sat, t, healthy_only):
        nodes_t, nodes_xyz = self._series[sat]
        return _lagrange(nodes_t, nodes_xyz, t, self.step)


class BroadcastOrbits(Orbits):
    """Positions propagated from broadcast ephemerides (Keplerian, GLONASS Runge-Kutta).

    Parameters
    ----------
    table
        Rows of :func:`read_nav` (one or more files, concatenated).
    paths
        The files the table came from.
    notes
        Remarks to pass on to the user.
    """

    source = "broadcast"

    def __init__(self, table: pd.DataFrame, paths: Iterable = (), notes: Iterable[str] = ()):
        if table.empty:
            raise InputError("no ephemerides", where=_names(paths), fix="give navigation files")
        table = table.drop_duplicates(["constellation", "svid", "toe"]).reset_index(drop=True)
        toe = gps_seconds(table["toe"])
        age = table["constellation"].map(MAX_AGE).to_numpy()
        super().__init__(paths, _merge(toe - age, toe + age), notes)
        cons = table["constellation"].to_numpy()
        consts = np.array([_KEPLER_CONSTANTS.get(c, (np.nan, np.nan)) for c in cons])
        self._eph = {c: table[c].to_numpy(dtype=float) for c in table.columns if c in _PARAMETERS}
        self._eph.update(
            toe=toe,
            age=age,
            healthy=table["healthy"].to_numpy(dtype=bool),
            gm=consts[:, 0],
            omega_e=consts[:, 1],
            geo=(cons == "C") & ((table["svid"] <= 5) | (table["svid"] >= 59)).to_numpy(),
        )
        self._rows = {
            (c, int(s)): rows.to_numpy()
            for (c, s), rows in table.groupby(["constellation", "svid"]).groups.items()
        }

    def _satellites(self):
        return self._rows.keys()

    def _sat_positions(self, sat, t, healthy_only):
        rows = self._rows[sat]
        dt = np.abs(t[:, None] - self._eph["toe"][rows])
        healthy = self._eph["healthy"][rows]
        # Nearest ephemeris in time, a healthy one if any is within the maximum age.
        usable = (dt <= self._eph["age"][rows]) & (healthy | (not healthy_only))
        rank = np.where(healthy, dt, dt + 1e9)
        pick = np.argmin(np.where(usable, rank, np.inf), axis=1)
        ok = usable[np.arange(t.size), pick]
        out = np.full((t.size, 3), np.nan)
        if not ok.any():
            return out
        eph = {k: v[rows[pick[ok]]] for k, v in self._eph.items()}
        tk = t[ok] - eph["toe"]
        out[ok] = _glonass(eph, tk) if sat[0] == "R" else _kepler(eph, tk)
        return out


def _kind(path: Path) -> str:
    first = _read_lines(path, first_only=True)
    if first[:2] in ("#c", "#d"):
        return "sp3"
    if "RINEX VERSION / TYPE" in first:
        return "nav"
    raise InputError(
        "neither an SP3 orbit file nor a RINEX navigation file",
        where=_where(path, 1),
        fix="give SP3-c/d (*.sp3, *_ORB.SP3) or RINEX navigation (*.YYn, *_MN.rnx) files",
    )


def load_orbits(paths) -> Orbits:
    """Read orbit files into one source of satellite positions.

    Parameters
    ----------
    paths
        One path or several: SP3-c/d files and/or RINEX 2/3 navigation files (``.gz`` is
        fine). Several files of one kind are merged (e.g. consecutive days). When SP3 files are
        given, navigation files are ignored (listed in :attr:`Orbits.notes`).

    Returns
    -------
    Orbits
        A :class:`Sp3Orbits` or a :class:`BroadcastOrbits`.

    Raises
    ------
    InputError
        A missing, unreadable or garbled file.
    """
    paths = [Path(paths)] if isinstance(paths, str | Path) else [Path(p) for p in paths]
    if not paths:
        raise InputError("no orbit files given", fix="give SP3 or RINEX navigation files")
    kinds = {p: _kind(p) for p in paths}
    sp3 = [p for p in paths if kinds[p] == "sp3"]
    nav = [p for p in paths if kinds[p] == "nav"]
    if sp3:
        notes = [f"{p.name} ignored: SP3 precise orbits were given" for p in nav]
        return Sp3Orbits(pd.concat([read_sp3(p) for p in sp3], ignore_index=True), sp3, notes)
    tables = [read_nav(p) for p in nav]
    notes = [
        f"{p.name}: {n} {system} records skipped (system not supported)"
        for p, table in zip(nav, tables, strict=True)
        for system, n in table.attrs["skipped"].items()
    ]
    return BroadcastOrbits(pd.concat(tables, ignore_index=True), nav, notes)
