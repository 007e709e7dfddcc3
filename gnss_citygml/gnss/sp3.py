"""SP3 precise orbits: reading SP3-c/d files, and interpolating their positions.

**Reading** (versions c and d, GPS/GLONASS/Galileo/BeiDou/QZSS): positions (km in the file,
m here) and clocks of each satellite at each epoch. The header's epoch count is not trusted
(real files are often cut). A position of 0.000000 is a missing value. Epochs are read in the
file's time system (the ``%c`` line: GPS, GAL, QZS, BDT, TAI, UTC or GLO) and returned in GPS
time.

**Interpolation**: positions between the epochs come from a 10-point Lagrange polynomial
centred on each requested time (millimetres; within two epochs of either end of the data the
window is one-sided and the error grows to centimetres: give the neighbouring days' files too).
A window may bridge one missing epoch, larger gaps give NaN.

:class:`~gnss_citygml.gnss.orbits.Sp3Orbits` puts the two together behind the
:class:`~gnss_citygml.gnss.orbits.Orbits` front.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from gnss_citygml.errors import InputError
from gnss_citygml.files.paths import StrPath
from gnss_citygml.gnss.gpstime import BDT_MINUS_GPS, utc_to_gps
from gnss_citygml.gnss.orbitfile import (
    fortran_float,
    garbled,
    location,
    read_lines,
    record_epoch,
)

__all__ = ["LAGRANGE_POINTS", "MAX_MISSING_EPOCHS", "lagrange", "read_sp3"]

#: Nodes of the interpolating polynomial.
LAGRANGE_POINTS = 10
#: Missing epochs a Lagrange window may bridge.
MAX_MISSING_EPOCHS = 1
#: Offset (s) added to SP3 epochs in each time system to get GPS time (UTC-based: leap seconds).
_SP3_TIME_SYSTEMS = {"GPS": 0, "GAL": 0, "QZS": 0, "BDT": -BDT_MINUS_GPS, "TAI": -19}


def read_sp3(path: StrPath) -> pd.DataFrame:
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
    lines = read_lines(path)
    if not lines or not lines[0].startswith("#") or lines[0][1:2] not in ("c", "d"):
        raise InputError(
            "not an SP3-c or SP3-d orbit file (the first line must start with #c or #d)",
            where=location(path, 1),
            fix="give an SP3-c/d file (e.g. an IGS or MGEX *_ORB.SP3 product)",
        )
    version = lines[0][1]
    time_system = _time_system(lines, path)
    times, cons, svids, values = [], [], [], []
    epoch = None
    for no, line in enumerate(lines, start=1):
        tag = line[:1]
        if tag == "*":
            epoch = record_epoch(line[1:], path, no, line)
        elif tag == "P":
            if epoch is None:
                raise garbled(path, no, line, "position record before the first epoch line")
            if len(line) < 60:
                raise garbled(path, no, line, "truncated position record")
            try:
                svid = int(line[2:4])
            except ValueError:
                raise garbled(path, no, line, "unreadable satellite id") from None
            times.append(epoch)
            cons.append(line[1] if line[1] != " " else "G")
            svids.append(svid)
            values.append([fortran_float(line[k : k + 14], path, no) for k in (4, 18, 32, 46)])
        elif epoch is not None and tag not in ("E", "V", "") and not line.startswith("EOF"):
            raise garbled(path, no, line, "unknown SP3 record")
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


def _time_system(lines: list[str], path: StrPath) -> str:
    """The file's time system, from its first ``%c`` line (GPS where it names none)."""
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
    return time_system


def _to_gps_time(times: np.ndarray, time_system: str) -> np.ndarray:
    if time_system == "GLO":  # UTC(SU) + 3 h
        times = times - np.timedelta64(3, "h")
    if time_system in ("UTC", "GLO"):
        return utc_to_gps(times)
    return times + np.timedelta64(_SP3_TIME_SYSTEMS[time_system], "s")


def lagrange(nodes_t: np.ndarray, nodes_xyz: np.ndarray, t: np.ndarray, step: float) -> np.ndarray:
    """10-point Lagrange interpolation; NaN where no window of nodes without a gap holds t.

    The window is centred on t when it can be; near the ends of the series or next to a gap it
    is shifted (t stays between its first and last node: never extrapolation).
    """
    n, m = LAGRANGE_POINTS, nodes_t.size
    out = np.full((t.size, 3), np.nan)
    if m < n or t.size == 0:
        return out
    centred = np.searchsorted(nodes_t, t) - n // 2
    start = np.full(t.size, -1)
    for shift in sorted(range(1 - n // 2, n // 2), key=abs):  # 0, -1, 1, ... : centred first
        first = np.clip(centred + shift, 0, m - n)
        last = first + n - 1
        fits = (nodes_t[first] <= t) & (t <= nodes_t[last]) & (start < 0)
        fits &= nodes_t[last] - nodes_t[first] <= (n - 1 + MAX_MISSING_EPOCHS + 1e-6) * step
        start[fits] = first[fits]
    ok = start >= 0
    idx = start[ok, None] + np.arange(n)
    x = (nodes_t[idx] - t[ok, None]) / step
    eye = np.eye(n, dtype=bool)
    num = np.where(eye, 1.0, -x[:, None, :]).prod(axis=2)
    den = np.where(eye, 1.0, x[:, :, None] - x[:, None, :]).prod(axis=2)
    out[ok] = np.einsum("mj,mjc->mc", num / den, nodes_xyz[idx])
    return out
