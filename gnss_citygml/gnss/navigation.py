"""RINEX navigation files: the broadcast ephemerides, read into a table.

RINEX 2 GPS (``.n``) and RINEX 3 mixed files (``*_MN.rnx``) hold one record per ephemeris: a
first line with the satellite and its epoch (toc, or tb for GLONASS), then continuation lines
of D19.12 numbers. GPS, QZSS, Galileo and BeiDou records carry Keplerian parameters, GLONASS
records a state vector (position, velocity, luni-solar acceleration) in PZ-90; SBAS and
NavIC/IRNSS records are skipped and counted. Each row's ``toe`` is put in GPS time (the GPS
week found from toc, BeiDou's 14 s and GLONASS's UTC tb converted), so that
:class:`~gnss_citygml.gnss.orbits.BroadcastOrbits` can pick the ephemeris nearest in time and
propagate it with :mod:`.propagation`.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from gnss_citygml.errors import InputError
from gnss_citygml.files.paths import StrPath
from gnss_citygml.gnss.gpstime import BDT_MINUS_GPS, GPS_EPOCH, NS_PER_S, utc_to_gps
from gnss_citygml.gnss.orbitfile import (
    fortran_float,
    garbled,
    location,
    read_lines,
    record_epoch,
)
from gnss_citygml.gnss.propagation import KEPLER_CONSTANTS

__all__ = ["EPHEMERIS_PARAMETERS", "read_nav"]

_WEEK = 604800.0
_KEPLER_FIELDS = (
    "iode crs delta_n m0 cuc e cus sqrt_a toe_sow cic omega0 cis i0 crc omega omega_dot idot "
    "codes week l2p_flag accuracy health"
).split()
_GLONASS_FIELDS = "x vx ax health y vy ay freq z vz az".split()
_GLONASS_STATE = "x y z vx vy vz ax ay az".split()
#: The ephemeris parameters the propagators use.
EPHEMERIS_PARAMETERS = set(_KEPLER_FIELDS) | set(_GLONASS_STATE)


def read_nav(path: StrPath) -> pd.DataFrame:
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
    lines = read_lines(path)
    version, header_end = _nav_header(lines, path)
    records = _rinex2_records if version < 3 else _rinex3_records
    rows: list[dict] = []
    skipped: dict[str, int] = {}
    for no, system, svid, epoch, values in records(lines, header_end, path, version):
        if system in KEPLER_CONSTANTS:
            toe_sow = values[3 + _KEPLER_FIELDS.index("toe_sow")]
            if not 0.0 <= toe_sow <= _WEEK:  # NaN too
                raise garbled(path, no, lines[no - 1], f"time of ephemeris {toe_sow:g} s")
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
            where=location(path, 1),
            fix="give a RINEX navigation file or an SP3 orbit file",
        )
    version = fortran_float(first[:9], path, 1)
    kind = first[20:21]
    if kind != "N" or not 2 <= version < 4:
        raise InputError(
            f"unsupported RINEX file: version {version:g}, type {kind!r}",
            where=location(path, 1),
            fix="give a RINEX 2 GPS (.n) or RINEX 3 navigation file, or an SP3 file",
        )
    for no, line in enumerate(lines):
        if "END OF HEADER" in line[60:]:
            return version, no + 1
    raise InputError("no END OF HEADER line", where=str(path), fix="the file is truncated")


def _record_values(group: list[tuple[int, str]], first_at: int, rest_at: int, path) -> list:
    """The D19.12 numbers of a record: 3 on its first line, 4 on each continuation line."""
    values: list[float] = []
    for k, (no, line) in enumerate(group):
        starts = range(first_at, first_at + 57, 19) if k == 0 else range(rest_at, rest_at + 76, 19)
        values.extend(fortran_float(line[i : i + 19], path, no) for i in starts)
    return values


def _rinex2_records(lines, header_end, path, version):
    body = [(no + 1, line) for no, line in enumerate(lines) if no >= header_end and line.strip()]
    for k in range(0, len(body), 8):
        group = body[k : k + 8]
        no, line = group[0]
        if len(group) < 8:
            raise garbled(path, no, line, "truncated record")
        for cont_no, cont in group[1:]:
            if cont[:3].strip():
                raise garbled(path, cont_no, cont, "expected a continuation line")
        try:
            svid = int(line[:2])
        except ValueError:
            raise garbled(path, no, line, "unreadable satellite number") from None
        epoch = record_epoch(line[2:22], path, no, line, two_digit_year=True)
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
            raise garbled(path, no + 1, line, "expected the first line of a record")
        group = [(no + 1 + k, text) for k, text in enumerate(lines[no : no + sizes[system]])]
        if len(group) < sizes[system]:
            raise garbled(path, no + 1, line, "truncated record")
        for cont_no, cont in group[1:]:
            if cont[:4].strip():
                raise garbled(path, cont_no, cont, "expected a continuation line")
        try:
            svid = int(line[1:3])
        except ValueError:
            raise garbled(path, no + 1, line, "unreadable satellite number") from None
        epoch = record_epoch(line[4:23], path, no + 1, line)
        yield no + 1, system, svid, epoch, _record_values(group, 23, 4, path)
        no += sizes[system]


def _kepler_row(system: str, svid: int, epoch: np.datetime64, values: list) -> dict:
    row = dict(zip(_KEPLER_FIELDS, values[3:], strict=False))
    # toc is in the system's own time; the week is found from toc, not from the week field.
    toc = (epoch - GPS_EPOCH).astype(np.int64) / NS_PER_S
    toe = toc + (row["toe_sow"] - toc % _WEEK + _WEEK / 2) % _WEEK - _WEEK / 2
    if system == "C":
        toe -= BDT_MINUS_GPS
    row.update(
        constellation=system,
        svid=svid,
        toe=GPS_EPOCH + np.timedelta64(round(toe * NS_PER_S), "ns"),
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
