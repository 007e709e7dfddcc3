"""GPS time and UTC: the leap-second table shared by the log reader and the orbit readers.

GPS time (GPST) started at 1980-01-06 00:00:00 UTC and has no leap seconds, so it runs ahead
of UTC by the number of leap seconds inserted since then: 17 s during 2016, 18 s since
2017-01-01. Galileo (GST) and QZSS time follow GPS time; BeiDou time (BDT) is 14 s behind it.

Times are numpy ``datetime64[ns]`` arrays. A GPS-time array is *naive* (it is not UTC, so it
must not carry a UTC time zone); UTC inputs may be naive (taken as UTC) or time-zone aware
(converted to UTC).

The table ends with the leap second of 2017-01-01. When the IERS announces a new one, add a
row to :data:`LEAP_SECONDS`.
"""

from __future__ import annotations

import datetime
from typing import TypeAlias

import numpy as np
import numpy.typing as npt
import pandas as pd

from gnss_citygml.errors import InputError

__all__ = [
    "BDT_MINUS_GPS",
    "GPS_EPOCH",
    "LEAP_SECONDS",
    "NAT_NS",
    "NS_PER_S",
    "Times",
    "gps_minus_utc",
    "gps_seconds",
    "gps_to_utc",
    "to_datetime64",
    "utc_ns",
    "utc_to_gps",
]

#: Times as the functions here take them: a scalar (``datetime64``, ``pandas.Timestamp``, a
#: string pandas parses), a list, a numpy array, a pandas Series or Index.
Times: TypeAlias = npt.ArrayLike | datetime.datetime

#: Nanoseconds per second: the unit of the ``datetime64[ns]`` times.
NS_PER_S = 1_000_000_000

#: Start of GPS time (GPST = UTC at that instant).
GPS_EPOCH = np.datetime64("1980-01-06T00:00:00", "ns")

#: BeiDou time minus GPS time, s.
BDT_MINUS_GPS = -14

#: (UTC date from which the offset holds, GPS - UTC in s), IERS Bulletin C up to 2017.
LEAP_SECONDS: tuple[tuple[str, int], ...] = (
    ("1980-01-06", 0),
    ("1981-07-01", 1),
    ("1982-07-01", 2),
    ("1983-07-01", 3),
    ("1985-07-01", 4),
    ("1988-01-01", 5),
    ("1990-01-01", 6),
    ("1991-01-01", 7),
    ("1992-07-01", 8),
    ("1993-07-01", 9),
    ("1994-07-01", 10),
    ("1996-01-01", 11),
    ("1997-07-01", 12),
    ("1999-01-01", 13),
    ("2006-01-01", 14),
    ("2009-01-01", 15),
    ("2012-07-01", 16),
    ("2015-07-01", 17),
    ("2017-01-01", 18),
)

_STARTS_UTC = np.array([d for d, _ in LEAP_SECONDS], dtype="datetime64[ns]")
_OFFSETS = np.array([s for _, s in LEAP_SECONDS], dtype=np.int64)
#: The same instants in GPS time (a step happens at UTC midnight + the new offset).
_STARTS_GPS = _STARTS_UTC + _OFFSETS.astype("timedelta64[s]")


def to_datetime64(times: Times) -> np.ndarray:
    """Times as a naive ``datetime64[ns]`` array; time-zone aware input is converted to UTC.

    Accepts a scalar, a list, a numpy ``datetime64`` array or a pandas Series / Index /
    Timestamp. Strings are parsed by pandas.

    Examples
    --------
    >>> to_datetime64(pd.Timestamp("2021-04-29 22:35", tz="Europe/London"))
    array(['2021-04-29T21:35:00.000000000'], dtype='datetime64[ns]')
    """
    if isinstance(times, datetime.datetime) or np.ndim(times) == 0:
        times = [times]
    dtype = times.dtype if hasattr(times, "dtype") else np.asarray(times).dtype
    if dtype.kind in "iufb":
        raise InputError(
            "times are numbers, not dates", fix="pass datetime64 values or pandas Timestamps"
        )
    index = pd.DatetimeIndex(times)  # type: ignore[arg-type]  # pandas-stubs: not any array
    if index.tz is not None:
        index = index.tz_convert("UTC").tz_localize(None)
    return index.as_unit("ns").to_numpy()


#: What :func:`utc_ns` gives for a missing time (NaT): the smallest int64.
NAT_NS = np.iinfo(np.int64).min


def utc_ns(times: Times) -> np.ndarray:
    """UTC times -> int64 ns since 1970 (:data:`NAT_NS` for NaT).

    The log reader and the receiver positions compare and search times as these integers.

    Examples
    --------
    >>> utc_ns(pd.to_datetime(["1970-01-01 00:00:01", None], utc=True)).tolist()
    [1000000000, -9223372036854775808]
    """
    return pd.DatetimeIndex(times).as_unit("ns").asi8  # type: ignore[arg-type]  # as above


def _table_index(times: np.ndarray, starts: np.ndarray, scale: str) -> np.ndarray:
    if np.any(np.isnat(times)):
        raise InputError(f"missing (NaT) {scale} time", fix="drop rows without a time first")
    if times.size and times.min() < starts[0]:
        raise InputError(
            f"{scale} time {times.min()} is before the start of GPS time (1980-01-06)",
            fix="check the time column and its unit",
        )
    return np.searchsorted(starts, times, side="right") - 1


def gps_minus_utc(times_utc: Times) -> np.ndarray:
    """GPS - UTC (leap seconds, s) at UTC times.

    Examples
    --------
    >>> gps_minus_utc(["2016-06-30", "2016-12-31T23:59:59", "2017-01-01", "2025-11-16"])
    array([17, 17, 18, 18])
    """
    times = to_datetime64(times_utc)
    return _OFFSETS[_table_index(times, _STARTS_UTC, "UTC")]


def utc_to_gps(times_utc: Times) -> np.ndarray:
    """UTC times as GPS times (naive ``datetime64[ns]``).

    Examples
    --------
    >>> utc_to_gps("2021-04-29T22:35:26")
    array(['2021-04-29T22:35:44.000000000'], dtype='datetime64[ns]')
    """
    times = to_datetime64(times_utc)
    return times + (gps_minus_utc(times) * NS_PER_S).astype("timedelta64[ns]")


def gps_to_utc(times_gps: Times) -> np.ndarray:
    """GPS times (naive ``datetime64[ns]``, or int nanoseconds since :data:`GPS_EPOCH`) as UTC.

    Integer input is what Android reports: ``TimeNanos - (FullBiasNanos + BiasNanos)``.

    Examples
    --------
    >>> gps_to_utc(np.array([1303770943928203644]))
    array(['2021-04-29T22:35:25.928203644'], dtype='datetime64[ns]')
    >>> gps_to_utc("2017-01-01T00:00:18")
    array(['2017-01-01T00:00:00.000000000'], dtype='datetime64[ns]')
    """
    arr = np.asarray(times_gps)
    if arr.dtype.kind in "iu":
        times = GPS_EPOCH + np.atleast_1d(arr).astype("timedelta64[ns]")
    else:
        times = to_datetime64(times_gps)
    offsets = _OFFSETS[_table_index(times, _STARTS_GPS, "GPS")]
    return times - (offsets * NS_PER_S).astype("timedelta64[ns]")


def gps_seconds(times_gps: Times) -> np.ndarray:
    """GPS times (naive ``datetime64``) as float seconds since :data:`GPS_EPOCH`.

    Float64 seconds resolve about 0.2 microseconds today: sub-millimetre for a satellite.

    Examples
    --------
    >>> gps_seconds("1980-01-13T00:00:01.5")
    array([604801.5])
    """
    times = to_datetime64(times_gps)
    return (times - GPS_EPOCH).astype(np.int64) / NS_PER_S
