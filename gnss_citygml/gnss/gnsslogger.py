"""Android GnssLogger logs: C/N0 per received signal, UTC epoch times, receiver positions.

GnssLogger (Google's logging app, versions 1.4 of 2016 to 3.x) writes a text file of
comma-separated records, each line starting with its record type (``Raw``, ``Fix``,
``Status``, ``Agc``, sensor records, ...). ``#`` lines form the header: a ``# Version:`` line
and one ``# <Type>,<column>,...`` line per record type. Columns are found by these header
names, never by position: old logs say ``ElapsedRealtimeMillis`` and ``Latitude`` /
``(UTC)TimeInMs`` where newer ones say ``utcTimeMillis`` and ``LatitudeDegrees`` /
``UnixTimeMillis``; the London log of 2020 even repeats ``CarrierFrequencyHz`` (the first
one is used).

**Epoch time.** GPS time (ns since 1980-01-06) = ``TimeNanos - (FullBiasNanos +
BiasNanos)``, in int64: ``FullBiasNanos`` (~1.3e18) has more digits than a float64 holds.
Each row uses its own ``FullBiasNanos``: all rows of an epoch share one clock, and the bias
follows the clock drift and any hardware clock reset, where a single bias for the whole log
would drift (15 microseconds over the 5 minutes of the London log) or jump. UTC = GPS -
leap seconds (17 s from 2015-07-01, 18 s from 2017-01-01). ``TimeOffsetNanos``
(sub-microsecond) is left out so that the rows of an epoch share one time.

**Which measurements are kept.** This project needs the C/N0 of each received signal, not
pseudoranges, so a row is kept when the receiver is *tracking* the signal: its ``State`` has
primary code lock, ``STATE_CODE_LOCK`` (0x1) or, for Galileo E1, ``STATE_GAL_E1BC_CODE_LOCK``
(0x400). Time-of-week decoding is not required: it resolves the pseudorange ambiguity, not
the C/N0, and requiring it would drop strong signals (e.g. 282 Galileo rows at 35 dB-Hz in the
2016-08-22 demo log). Flags without primary code lock are not enough ("time known" 0x4000 /
0x8000 alone, or the secondary-code pair 0x10000 | 0x800 the Galaxy S10 keeps on lost Galileo
channels): in every staged log such rows have ``ReceivedSvTimeUncertaintyNanos`` = 1 s
("unknown") and mostly noise-level C/N0 (London: median 13.5 dB-Hz against 32 dB-Hz for the
kept rows), while every row with primary code lock has an uncertainty below 1 microsecond.
Rows are also dropped when their clock has no ``FullBiasNanos`` (no GPS time), their
constellation is unknown, the GLONASS slot is unknown (``Svid`` 93-106 is a frequency
channel + 100, not a satellite: all GLONASS rows of the 2016-08-22 demo log) or the carrier
frequency is in no GNSS band. Dropped rows are kept in :attr:`GnssLog.dropped` with a
``reason``, for counting and inspection.

**Signals.** ``constellation`` is the RINEX letter (G GPS, R GLONASS, E Galileo, C BeiDou,
J QZSS, S SBAS, I NavIC); ``svid`` the RINEX satellite number (QZSS ``Svid`` 193-202 becomes
1-10, SBAS 120-158 becomes 20-58). ``band`` comes from ``CarrierFrequencyHz`` with RINEX band
numbers: ``L1`` (1559-1610 MHz: GPS/QZSS L1, Galileo E1, BeiDou B1, GLONASS G1), ``L5``
(1164-1189 MHz: GPS L5, Galileo E5a, BeiDou B2a), ``L2``, ``L6``, ``L7`` (E5b/B2I/G3); no
frequency (logs before dual-frequency phones) means ``L1``.

**Bad input.** Only the records this reader uses (``Raw``, ``Fix``, ``Status``) are checked:
a field count different from their header, an empty required field or a value that is not a
number is a bad line; so is any line that is not a record (a first field that is not a word).
A bad line raises :class:`~gnss_citygml.errors.InputError` naming the file and line; with
``lenient=True`` bad lines are skipped, counted in :attr:`GnssLog.skipped_lines` and reported
with a warning. The last line of a file that has no line end and is incomplete (fewer fields
than its header, a bad value, or only the start of a record name such as ``Ra``) is a log cut
off while being written (the London log of 2020 ends so): it is skipped with a warning in both
modes. A missing ``# Version:`` line or ``# <Type>,...`` header raises in both modes; an
unknown version raises, or warns with ``lenient=True`` (columns are read from the header
anyway).

**Incomplete epochs.** A satellite missing from an epoch reads as a blocked signal, so an epoch
whose ``Raw`` rows are not all there is dropped whole: its rows move to
:attr:`GnssLog.dropped` (reason ``incomplete epoch ...``) and the warning names the log, the
epoch and why. The rows of an epoch are written together and share their clock
(``TimeNanos``, ``FullBiasNanos``), so a skipped line (the cut-off last line, or a bad line
with ``lenient=True``) between two rows of one epoch is a row of that epoch; between two
epochs, it is placed by the clock fields it still has: the readable ones of a row with a bad
value elsewhere, the complete ones and the start of the last one of a cut-off line.
Where they cannot tell (a garbled line, a line cut before its clock), it may be a row of the
epoch before it or of the epoch after it, and both are dropped. A log cut exactly at a line end
leaves no cut-off line; it is recognised when it ends with an epoch whose signals are the first
ones of the epoch before, in the same order, and fewer (consecutive epochs of the staged logs
list their signals in one order): that last epoch is dropped. A complete last epoch that lost
the satellites at the end of the list is dropped with it: one epoch, with a warning.

**Receiver positions.** :func:`positions` takes them from the ``Fix`` rows of one provider
(nearest in time or interpolated); :func:`read_surveyed_positions` and
:func:`surveyed_positions` take them from a file of manually surveyed positions (see
:func:`read_surveyed_positions` for its format).
"""

from __future__ import annotations

import csv
import io
import re
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np
import pandas as pd

from gnss_citygml.errors import InputError, MissingColumnError
from gnss_citygml.gnss.gpstime import GPS_EPOCH, gps_to_utc

__all__ = [
    "GnssLog",
    "positions",
    "read_gnsslogger",
    "read_surveyed_positions",
    "surveyed_positions",
]

#: Android's raw GNSS measurements began in 2016: an epoch outside these dates is a wrong
#: clock field.
_EARLIEST, _LATEST = "2015-07-01", "2100-01-01"
_EARLIEST_GPS_NS, _LATEST_GPS_NS = (
    int((np.datetime64(day, "ns") - GPS_EPOCH) / np.timedelta64(1, "ns"))
    for day in (_EARLIEST, _LATEST)
)
#: Unix times in ms that are still datetime64[ns] (before 2262).
_MS = (0.0, np.iinfo(np.int64).max // 10**6)
#: Larger clock biases (ns, 11.6 days) are no bias but a wrong field.
_BIAS = (-1e15, 1e15)
_CN0 = (0.0, 100.0)
#: Heights (m) above the ellipsoid a phone can be at: 100 km from the Earth's surface.
_HEIGHT = (-1e5, 1e5)
#: Android ``GnssStatus.CONSTELLATION_*`` (index) -> RINEX letter; "?" = unknown.
_LETTERS = np.array(["?", "G", "S", "R", "J", "C", "E", "I"])
_STATE_CODE_LOCK = 0x1
_STATE_GAL_E1BC_CODE_LOCK = 0x400
#: RINEX band name, lowest and highest carrier frequency (MHz).
_BANDS = (
    ("L1", 1559.0, 1610.0),
    ("L2", 1215.0, 1256.0),
    ("L5", 1164.0, 1189.0),
    ("L6", 1258.0, 1300.0),
    ("L7", 1189.0, 1215.0),
)
_KNOWN_MAJOR_VERSIONS = ("1", "2", "3")
_VERSION = re.compile(r"v?(\d+)(\.\d+)+")
_RECORD_TYPE = re.compile(r"[A-Za-z]+")
_INT = r"[+-]?(\d{1,18}|[1-8]\d{18})"  # fits int64
_NAT = np.iinfo(np.int64).min  # numpy's NaT
_INCOMPLETE = "incomplete epoch (a row of it is bad, cut off or missing)"
_FIX_HINT = "repair or delete the line, or read the log leniently (lenient=True, --lenient)"


class _Column(NamedTuple):
    """A column the reader needs: its possible header names, how to convert it, and the range
    of its values (numbers outside it, and infinite ones, make a bad line)."""

    names: tuple[str, ...]
    kind: str  # "int", "float" or "str"
    may_be_empty: bool = False
    required: bool = True
    limits: tuple[float, float] = (-np.inf, np.inf)


_RAW = {
    "time_nanos": _Column(("TimeNanos",), "int"),
    "full_bias": _Column(("FullBiasNanos",), "int", may_be_empty=True),
    "bias": _Column(("BiasNanos",), "float", may_be_empty=True, limits=_BIAS),
    "svid": _Column(("Svid",), "int"),
    "constellation": _Column(("ConstellationType",), "int"),
    "cn0": _Column(("Cn0DbHz",), "float", limits=_CN0),
    "state": _Column(("State",), "int"),
    "frequency": _Column(("CarrierFrequencyHz",), "float", may_be_empty=True, required=False),
}
_FIX = {
    "provider": _Column(("Provider",), "str"),
    "lat": _Column(("LatitudeDegrees", "Latitude"), "float", limits=(-90.0, 90.0)),
    "lon": _Column(("LongitudeDegrees", "Longitude"), "float", limits=(-180.0, 180.0)),
    "altitude": _Column(("AltitudeMeters", "Altitude"), "float", may_be_empty=True, limits=_HEIGHT),
    "accuracy": _Column(("AccuracyMeters", "Accuracy"), "float", may_be_empty=True),
    "time_ms": _Column(("UnixTimeMillis", "(UTC)TimeInMs"), "int", limits=_MS),
}
_STATUS = {
    "time_ms": _Column(("UnixTimeMillis",), "int", may_be_empty=True, limits=_MS),
    "constellation": _Column(("ConstellationType",), "int"),
    "svid": _Column(("Svid",), "int"),
    "frequency": _Column(("CarrierFrequencyHz",), "float", may_be_empty=True, required=False),
    "cn0": _Column(("Cn0DbHz",), "float", limits=_CN0),
    "azimuth": _Column(("AzimuthDegrees",), "float", limits=(0.0, 360.0)),
    "elevation": _Column(("ElevationDegrees",), "float", limits=(-90.0, 90.0)),
}
_RECORDS = {"Raw": _RAW, "Fix": _FIX, "Status": _STATUS}


@dataclass(frozen=True, eq=False, repr=False)
class GnssLog:
    """One GnssLogger log, read by :func:`read_gnsslogger`.

    Attributes
    ----------
    path
        The log file.
    version
        GnssLogger version from the header (e.g. ``"2.0.0.1"``, or ``"Not Available"``).
    raw
        One row per kept measurement (a received signal at an epoch): ``time_utc``
        (datetime64[ns, UTC], the epoch), ``constellation`` (RINEX letter), ``svid`` (RINEX
        number), ``band`` (``"L1"``, ``"L5"``, ...), ``cn0`` (dB-Hz), ``state`` (Android
        ``GnssMeasurement`` state bits).
    fixes
        One row per ``Fix`` record: ``time_utc``, ``provider`` (lower case: ``gps``, ``flp``,
        ``nlp``, ...), ``lat``, ``lon`` (deg, WGS84), ``altitude`` (m above the WGS84
        ellipsoid, as Android reports it), ``accuracy`` (m; NaN if not logged).
    status
        One row per ``Status`` record with a time: ``time_utc``, ``constellation``,
        ``svid``, ``band``, ``azimuth``, ``elevation`` (deg, as the phone computed them),
        ``cn0``.
    dropped
        The ``Raw`` rows that were not kept: the columns of ``raw`` (``time_utc`` NaT when the
        clock had no GPS time) and ``reason``.
    skipped_lines
        Number of bad lines skipped (``lenient=True``, or a cut-off last line).
    """

    path: Path
    version: str
    raw: pd.DataFrame
    fixes: pd.DataFrame
    status: pd.DataFrame
    dropped: pd.DataFrame
    skipped_lines: int = 0

    @property
    def receiver(self) -> str:
        """The receiver name: the log's file name without suffix."""
        return self.path.stem

    @property
    def epochs(self) -> pd.DatetimeIndex:
        """The sorted, distinct epoch times of the kept measurements."""
        return pd.DatetimeIndex(self.raw["time_utc"].unique()).sort_values()

    def __repr__(self) -> str:
        return (
            f"GnssLog({self.path.name!r}, version={self.version!r}, raw={len(self.raw)}, "
            f"dropped={len(self.dropped)}, fixes={len(self.fixes)}, status={len(self.status)}, "
            f"skipped_lines={self.skipped_lines})"
        )


def read_gnsslogger(path: str | Path, *, lenient: bool = False) -> GnssLog:
    """Read an Android GnssLogger text log (version 1.4 to 3.x).

    Parameters
    ----------
    path
        The log file (``gnss_log_*.txt``).
    lenient
        Skip bad lines (counted in :attr:`GnssLog.skipped_lines`, with a warning) instead of
        raising.

    Returns
    -------
    GnssLog
        The kept measurements, dropped measurements, fixes and status rows (see the module
        documentation for the rules).

    Raises
    ------
    InputError
        The file cannot be read, has no ``# Version:`` line or no header for records it
        contains, an unknown version (unless lenient), or a bad line (unless lenient), naming
        the file and line.

    Warns
    -----
    UserWarning
        One line per cause: bad lines skipped (lenient), a cut-off last line, a log cut at a
        line end inside its last epoch; each names the epochs dropped whole with it.
    """
    path = Path(path)
    try:
        text = path.read_bytes().decode("utf-8", errors="replace")
    except OSError as exc:
        raise InputError(f"cannot read the log: {exc.strerror or exc}", where=str(path)) from exc
    split = _split_lines(text, path, lenient)
    bad = list(split.bad)
    suspects = dict.fromkeys(split.garbled, "garbled")  # damaged lines that may be Raw rows
    value_bad = set()
    tables = {}
    for kind, columns in _RECORDS.items():
        numbers, lines = split.records[kind]
        if numbers and kind not in split.headers:
            raise InputError(
                f"{kind} records but no '# {kind},...' header line",
                where=f"{path}, line {numbers[0]}",
                fix=f"restore the log's header (its '# {kind},' line names the columns)",
            )
        header = split.headers.get(kind)
        table, bad_rows = _parse_records(kind, header, numbers, lines, columns, path)
        bad += bad_rows
        value_bad.update(n for n, _ in bad_rows)
        if kind == "Raw":
            suspects.update(dict.fromkeys((n for n, _ in bad_rows), "row"))
        tables[kind] = (table, np.asarray(numbers, dtype=np.int64))
    raw_table, raw_numbers = tables["Raw"]
    signals, bad_time = _measurements(raw_table, raw_numbers)
    bad += bad_time
    value_bad.update(n for n, _ in bad_time)
    suspects.update(dict.fromkeys((n for n, _ in bad_time), "garbled"))
    cut, cut_raw = split.cut, split.cut_raw
    if cut is None and split.open_last in value_bad:  # cut inside its last field
        cut, cut_raw = split.open_last, split.open_last in split.records["Raw"][0]
    if cut is not None:
        bad = [(n, reason) for n, reason in bad if n != cut]
        suspects.pop(cut, None)
        if cut_raw:
            suspects[cut] = "cut"
    if bad and not lenient:
        line, reason = min(bad)
        raise InputError(f"bad line: {reason}", where=f"{path}, line {line}", fix=_FIX_HINT)
    bad_lines = np.array([line for line, _ in bad] + [cut or 0], dtype=np.int64)
    good = ~np.isin(raw_numbers, bad_lines)
    by_line, trailing = _incomplete_epochs(
        signals,
        raw_table,
        raw_numbers,
        good,
        suspects,
        split.lines,
        split.headers.get("Raw"),
        split.last_record,
    )
    incomplete = set().union(*by_line.values(), [trailing[0]] if trailing else [])
    reason = signals["reason"].to_numpy(dtype=object, copy=True)
    reason[good & np.isin(_ns(signals["time_utc"]), list(incomplete)) & (reason == "")] = (
        _INCOMPLETE
    )
    _warn_skipped(path, bad, cut, by_line, split, trailing)
    kept = good & (reason == "")
    return GnssLog(
        path=path,
        version=split.version,
        raw=signals[kept].drop(columns="reason").reset_index(drop=True),
        dropped=signals[good & ~kept].assign(reason=reason[good & ~kept]).reset_index(drop=True),
        fixes=_fixes(_without(*tables["Fix"], bad_lines)),
        status=_status(_without(*tables["Status"], bad_lines)),
        skipped_lines=len(bad) + (cut is not None),
    )


def positions(
    log: GnssLog, *, provider: str = "gps", method: str = "nearest", max_gap: float = 2.0
) -> pd.DataFrame:
    """The receiver position at each epoch of ``log``, from its ``Fix`` rows.

    Parameters
    ----------
    log
        A log from :func:`read_gnsslogger`.
    provider
        Fix provider (case-insensitive): ``gps`` (the chipset), ``flp`` (fused), ``nlp``
        (network), ...
    method
        ``"nearest"``: the fix nearest in time; ``"interpolate"``: linear in time between the
        fixes just before and just after the epoch (the end fix before the first or after the
        last fix).
    max_gap
        Largest time (s) between an epoch and its nearest fix: epochs further from every fix
        have no position.

    Returns
    -------
    pd.DataFrame
        ``time_utc``, ``lat``, ``lon`` (deg, WGS84), ``h`` (m above the WGS84 ellipsoid; NaN
        where the fix had no altitude), one row per epoch in :attr:`GnssLog.epochs`.

    Raises
    ------
    InputError
        Unknown method or provider, or epochs without a usable fix (with their count and
        the first of them).
    """
    if method not in ("nearest", "interpolate"):
        raise InputError(
            f"unknown position method {method!r}", fix="use 'nearest' or 'interpolate'"
        )
    fixes = log.fixes[log.fixes["provider"] == provider.lower()]
    if fixes.empty:
        have = sorted(log.fixes["provider"].unique())
        raise InputError(
            f"no Fix rows from provider {provider!r}",
            where=str(log.path),
            fix=f"choose one of {have}" if have else "give surveyed positions instead",
        )
    fixes = fixes.sort_values("time_utc").drop_duplicates("time_utc", keep="last")
    epochs = log.epochs
    fix_ns, t = _ns(fixes["time_utc"]), _ns(epochs)
    gap = round(max_gap * 1e9)
    # the fixes at or just before and at or just after each epoch (clipped to the ends)
    before = np.searchsorted(fix_ns, t, side="right").clip(1, len(fix_ns)) - 1
    after = np.searchsorted(fix_ns, t, side="left").clip(0, len(fix_ns) - 1)
    d_before, d_after = t - fix_ns[before], fix_ns[after] - t
    nearest = np.where(np.abs(d_after) < np.abs(d_before), after, before)
    ok = np.abs(t - fix_ns[nearest]) <= gap
    if method == "nearest":
        lo = hi = nearest
        weight = np.zeros(len(t))
    else:  # before the first or after the last fix: lo == hi, the end fix
        lo, hi = before, after
        span = (fix_ns[hi] - fix_ns[lo]).astype(float)
        weight = np.divide(d_before, span, out=np.zeros(len(t)), where=span > 0)
    if not ok.all():
        raise InputError(
            f"{np.count_nonzero(~ok)} of {len(t)} epochs have no {provider!r} fix within "
            f"{max_gap:g} s ({method})",
            where=f"{log.path}, first at {epochs[~ok][0]}",
            fix="raise max_gap, choose another provider or method, or give surveyed positions",
        )
    lat, h = fixes["lat"].to_numpy(), fixes["altitude"].to_numpy()
    lon = np.degrees(np.unwrap(np.radians(fixes["lon"].to_numpy())))  # no jump at 180 deg
    lon = lon[lo] + weight * (lon[hi] - lon[lo])
    return pd.DataFrame(
        {
            "time_utc": epochs,
            "lat": lat[lo] + weight * (lat[hi] - lat[lo]),
            "lon": (lon + 180.0) % 360.0 - 180.0,
            "h": h[lo] + weight * (h[hi] - h[lo]),
        }
    )


def read_surveyed_positions(path: str | Path) -> pd.DataFrame:
    """Read a CSV file of manually surveyed receiver positions.

    The file has a header line and one row per receiver and time span::

        receiver,start_utc,end_utc,lat,lon,h
        london_ucl_2020-02-11_SM-G973F_gnss_log,2020-02-11T08:49:00Z,2020-02-11T08:55:00Z,51.524700,-0.134140,
        # lines starting with '#' and blank lines are ignored

    ``receiver`` names a log (its file name without suffix, :attr:`GnssLog.receiver`).
    ``start_utc`` and ``end_utc`` are ISO 8601 times, UTC unless they carry an offset; the
    span includes both ends (where one span ends as the next one starts, the later span
    wins). ``lat``, ``lon`` are WGS84 / ETRS89 degrees and ``h`` the ellipsoidal height in
    metres, empty when the height should come from the terrain model. Spans of one receiver
    must not overlap.

    Parameters
    ----------
    path
        The CSV file.

    Returns
    -------
    pd.DataFrame
        ``receiver``, ``start_utc``, ``end_utc`` (datetime64[ns, UTC]), ``lat``, ``lon``,
        ``h``, sorted by receiver and start; the file name is in ``attrs["path"]``.

    Raises
    ------
    InputError
        Missing columns, a value that cannot be read, a position out of range, a span that
        ends before it starts or overlapping spans, naming the file and line.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read the positions file: {exc}", where=str(path)) from exc
    lines = [
        (n, line)
        for n, line in enumerate(text.splitlines(), 1)
        if line.strip() and not line.lstrip().startswith("#")
    ]
    wanted = ["receiver", "start_utc", "end_utc", "lat", "lon", "h"]
    if not lines:
        raise MissingColumnError(wanted, where=str(path), have=[])
    header = [name.strip() for name in next(csv.reader([lines[0][1]]))]
    missing = [name for name in wanted if name not in header]
    if missing:
        raise MissingColumnError(missing, where=f"{path}, line {lines[0][0]}", have=header)
    rows = []
    for n, line in lines[1:]:
        fields = next(csv.reader([line]))
        where = f"{path}, line {n}"
        if len(fields) != len(header):
            raise InputError(f"{len(fields)} fields, the header has {len(header)}", where=where)
        rows.append(_surveyed_row(dict(zip(header, fields, strict=True)), where) + (n,))
    table = pd.DataFrame(rows, columns=[*wanted, "line"]).astype(
        {"receiver": str, "lat": float, "lon": float, "h": float}
    )
    table["start_utc"] = pd.to_datetime(table["start_utc"], utc=True).astype("datetime64[ns, UTC]")
    table["end_utc"] = pd.to_datetime(table["end_utc"], utc=True).astype("datetime64[ns, UTC]")
    table = table.sort_values(["receiver", "start_utc"], kind="stable").reset_index(drop=True)
    same = table["receiver"].eq(table["receiver"].shift())
    overlap = same & (table["start_utc"] < table["end_utc"].shift())
    if overlap.any():
        k = int(np.flatnonzero(overlap)[0])
        raise InputError(
            f"the span of receiver {table['receiver'][k]!r} overlaps the span on line "
            f"{table['line'][k - 1]}",
            where=f"{path}, line {table['line'][k]}",
            fix="make the spans of one receiver disjoint",
        )
    table = table.drop(columns="line")
    table.attrs["path"] = str(path)
    return table


def surveyed_positions(surveyed: pd.DataFrame, receiver: str, times) -> pd.DataFrame:
    """The surveyed position of ``receiver`` at each of ``times``.

    Parameters
    ----------
    surveyed
        A table from :func:`read_surveyed_positions`.
    receiver
        The receiver name (e.g. :attr:`GnssLog.receiver`).
    times
        Times (datetime64 UTC, e.g. :attr:`GnssLog.epochs`).

    Returns
    -------
    pd.DataFrame
        ``time_utc``, ``lat``, ``lon``, ``h`` (NaN where the file left it empty), one row per
        time, in the given order.

    Raises
    ------
    InputError
        The receiver is not in the table, or some times are in none of its spans.

    Examples
    --------
    >>> surveyed = pd.DataFrame({
    ...     "receiver": ["phone"],
    ...     "start_utc": [pd.Timestamp("2020-02-11 08:49", tz="UTC")],
    ...     "end_utc": [pd.Timestamp("2020-02-11 08:55", tz="UTC")],
    ...     "lat": [51.5247], "lon": [-0.1341], "h": [np.nan]})
    >>> surveyed_positions(surveyed, "phone", [pd.Timestamp("2020-02-11 08:50", tz="UTC")])
                       time_utc      lat     lon   h
    0 2020-02-11 08:50:00+00:00  51.5247 -0.1341 NaN
    """
    where = surveyed.attrs.get("path", "surveyed positions")
    spans = surveyed[surveyed["receiver"] == receiver].sort_values("start_utc")
    if spans.empty:
        have = sorted(surveyed["receiver"].unique())
        raise InputError(
            f"receiver {receiver!r} has no surveyed position",
            where=where,
            fix=f"add rows for it (the file has: {', '.join(have) or 'no rows'})",
        )
    times = pd.DatetimeIndex(pd.to_datetime(times, utc=True)).as_unit("ns")
    t, start, end = _ns(times), _ns(spans["start_utc"]), _ns(spans["end_utc"])
    k = np.searchsorted(start, t, side="right") - 1
    ok = (k >= 0) & (t <= end[k.clip(0)])
    if not ok.all():
        raise InputError(
            f"{np.count_nonzero(~ok)} of {len(t)} epochs of receiver {receiver!r} are in none "
            "of its surveyed spans",
            where=f"{where}, first at {times[~ok][0]}",
            fix="add or widen a span for these times",
        )
    return pd.DataFrame(
        {
            "time_utc": times,
            "lat": spans["lat"].to_numpy()[k],
            "lon": spans["lon"].to_numpy()[k],
            "h": spans["h"].to_numpy()[k],
        }
    )


def _surveyed_row(row: dict[str, str], where: str) -> tuple:
    """One row of a surveyed positions file, checked: (receiver, start, end, lat, lon, h)."""
    receiver = row["receiver"].strip()
    if not receiver:
        raise InputError("empty receiver name", where=where)
    start, end = (_utc_time(row[name], name, where) for name in ("start_utc", "end_utc"))
    if end < start:
        raise InputError("the span ends before it starts", where=where)
    lat, lon = (
        _number(row[name], name, where, limit) for name, limit in (("lat", 90), ("lon", 180))
    )
    h = _number(row["h"], "h", where) if row["h"].strip() else np.nan
    return receiver, start, end, lat, lon, h


def _utc_time(text: str, name: str, where: str) -> pd.Timestamp:
    """An ISO 8601 time, UTC unless it has an offset."""
    try:
        stamp = pd.Timestamp(text.strip())
    except ValueError:
        stamp = pd.NaT
    if pd.isna(stamp):
        raise InputError(f"{name} {text!r} is not a time", where=where, fix="use ISO 8601 times")
    return stamp.tz_localize("UTC") if stamp.tz is None else stamp.tz_convert("UTC")


def _number(text: str, name: str, where: str, limit: float = np.inf) -> float:
    """A finite number within +-limit."""
    try:
        value = float(text)
    except ValueError:
        value = np.nan
    if not abs(value) <= limit or not np.isfinite(value):
        within = f" within +-{limit:g}" if np.isfinite(limit) else ""
        raise InputError(f"{name} {text!r} is not a number{within}", where=where)
    return value


class _Lines(NamedTuple):
    """What one pass over the lines of a log finds (:func:`_split_lines`)."""

    version: str
    headers: dict[str, tuple[int, list[str]]]  # kind -> (line, column names)
    records: dict[str, tuple[list[int], list[str]]]  # kind -> (line numbers, lines)
    bad: list[tuple[int, str]]  # (line, reason)
    garbled: list[int]  # bad lines that may be damaged Raw rows, fields unplaceable
    cut: int | None  # a cut-off last line
    cut_raw: bool  # ... that may be a Raw row
    open_last: int | None  # the last line, when the file does not end with a line end
    last_record: int  # the last line that is a record (not a comment or blank)
    lines: list[str]


def _split_lines(text: str, path: Path, lenient: bool) -> _Lines:
    """One pass over the lines: the version, the headers, the records this reader uses.

    ``records`` holds only lines with the field count of their header; the others are ``bad``,
    except a last line without line end that has fewer fields, or is the start of a record
    type's name ("Ra"): that is ``cut``, a log closed while being written.
    """
    version = version_line = None
    headers: dict[str, tuple[int, list[str]]] = {}
    records: dict[str, tuple[list[int], list[str]]] = {kind: ([], []) for kind in _RECORDS}
    raw_numbers, raw_lines = records["Raw"]
    bad: list[tuple[int, str]] = []
    garbled: list[int] = []
    lines = text.split("\n")
    open_last = len(lines) if lines[-1].strip(" ,\t\r") else None
    cut, cut_raw, last_record = None, False, 0
    for n, line in enumerate(lines, 1):
        line = line.rstrip("\r")
        if line.startswith("Raw,"):  # the bulk of a log: keep this path short
            raw_numbers.append(n)
            raw_lines.append(line)
            continue
        if line.startswith("#"):
            body = line[1:].strip()
            if body.startswith("Version:"):
                version, version_line = body[len("Version:") :].strip(), n
            elif _RECORD_TYPE.fullmatch(kind := body.split(",", 1)[0].strip()) and "," in body:
                names = [name.strip() for name in body.split(",")[1:]]
                if headers.get(kind, (n, names))[1] != names:
                    raise InputError(
                        f"a second, different '# {kind},...' header",
                        where=f"{path}, line {n}",
                        fix="split the file into one log per header",
                    )
                headers[kind] = (n, names)
            continue
        if not line.strip(" ,\t"):
            continue  # blank lines, and the lone "," lines some versions write
        last_record = n
        kind = line.split(",", 1)[0]
        if kind in records:
            records[kind][0].append(n)
            records[kind][1].append(line)
        elif n == open_last and (prefix := [k for k in records if k.startswith(line)]):
            cut, cut_raw = n, prefix[0] == "Raw"
        elif not _RECORD_TYPE.fullmatch(kind):
            bad.append((n, f"not a GnssLogger record: {line[:40]!r}"))
            garbled.append(n)
    last_record = max(last_record, raw_numbers[-1] if raw_numbers else 0)
    if version is None:
        raise InputError(
            "not a GnssLogger log: no '# Version:' header line",
            where=str(path),
            fix="give a log written by Android GnssLogger, with its header",
        )
    version = _check_version(version, path, version_line, lenient)
    for kind, (numbers, texts) in records.items():
        if kind not in headers or not numbers:
            continue
        header_line, names = headers[kind]
        commas = np.fromiter((t.count(",") for t in texts), dtype=np.int64, count=len(texts))
        # a lone CR inside a line would split it in two for the CSV parser
        carriage = np.fromiter(("\r" in t for t in texts), dtype=bool, count=len(texts))
        wrong = np.flatnonzero((commas != len(names)) | carriage)
        if len(wrong) and numbers[wrong[-1]] == open_last and commas[wrong[-1]] < len(names):
            cut, cut_raw = open_last, kind == "Raw"
            wrong = wrong[:-1]
        bad += [
            (
                numbers[i],
                f"{kind} row of {commas[i] + 1} fields where its header (line "
                f"{header_line}) has {len(names) + 1}",
            )
            for i in wrong
        ]
        if kind == "Raw":
            garbled += [numbers[i] for i in wrong]
        keep = np.ones(len(numbers), dtype=bool)
        keep[wrong] = False
        keep[np.asarray(numbers) == cut] = False
        records[kind] = (
            [n for n, k in zip(numbers, keep, strict=True) if k],
            [t for t, k in zip(texts, keep, strict=True) if k],
        )
    return _Lines(
        version, headers, records, bad, garbled, cut, cut_raw, open_last, last_record, lines
    )


def _check_version(text: str, path: Path, line: int, lenient: bool) -> str:
    """The version from the text of the ``# Version:`` line; unknown ones raise or warn."""
    if text.startswith("Not Available"):
        return "Not Available"
    match = _VERSION.match(text)
    version = match.group(0).lstrip("v") if match else text.split()[0] if text else ""
    if match and match.group(1) in _KNOWN_MAJOR_VERSIONS:
        return version
    what = f"unknown GnssLogger version {version!r}"
    if not lenient:
        raise InputError(
            what,
            where=f"{path}, line {line}",
            fix="this reader knows versions 1.x to 3.x; read the log leniently (lenient=True, "
            "--lenient) to try the columns its header names",
        )
    warnings.warn(f"{path}: {what}; reading the columns its header names", stacklevel=4)
    return version


def _parse_records(kind, header, numbers, lines, columns, path):
    """The needed columns of one record type as numbers; returns (table, bad lines)."""
    if header is None:  # no header and no records of this type
        names = [col.names[0] for col in columns.values()]
    else:
        header_line, names = header
    positions = {}
    for key, col in columns.items():
        found = [names.index(name) for name in col.names if name in names]
        if found:
            positions[key] = found[0] + 1  # + 1: field 0 is the record type
    missing = [
        col.names[0] for key, col in columns.items() if col.required and key not in positions
    ]
    if missing and lines:
        shown = [repr(name)[1:-1] for name in names]  # control characters escaped
        raise MissingColumnError(missing, where=f"{path}, line {header_line}", have=shown)
    if lines:
        text = pd.read_csv(
            io.StringIO("\n".join(lines)),
            header=None,
            usecols=sorted(positions.values()),
            dtype=str,
            na_filter=False,
            quoting=csv.QUOTE_NONE,
        )
    else:
        text = pd.DataFrame({pos: pd.Series(dtype=str) for pos in positions.values()})
    table = {}
    bad = np.zeros(len(lines), dtype=bool)
    reasons = np.full(len(lines), "", dtype=object)
    for key, col in columns.items():
        if key not in positions:  # an optional column, or no rows
            table[key] = _convert(pd.Series([""] * len(lines), dtype=str), col)[0]
            continue
        values, wrong = _convert(text[positions[key]], col)
        table[key] = values
        name = names[positions[key] - 1]
        new = wrong & ~bad
        reasons[new] = [
            f"{kind} {name} is {v!r}, {_why_bad(v, col)}"
            if v.strip()
            else f"{kind} {name} is empty"
            for v in text[positions[key]].to_numpy()[new]
        ]
        bad |= wrong
    numbers = np.asarray(numbers, dtype=np.int64)
    return pd.DataFrame(table), list(zip(numbers[bad].tolist(), reasons[bad], strict=True))


def _convert(text: pd.Series, col: _Column) -> tuple[np.ndarray, np.ndarray]:
    """Values of one text column and the mask of bad ones. Missing ints are 0, floats NaN."""
    text = text.str.strip()
    empty = (text == "").to_numpy(dtype=bool)
    if col.kind == "str":
        return text.to_numpy(dtype=object), empty & (not col.may_be_empty)
    if col.kind == "int":
        good = text.str.fullmatch(_INT).to_numpy(dtype=bool)
        values = np.where(good, text.to_numpy(dtype=object), "0").astype(np.int64)
    else:
        values = pd.to_numeric(text, errors="coerce").to_numpy(dtype=float)
        empty = empty | text.str.lower().eq("nan").to_numpy()  # Java writes "NaN" for none
        good = np.isfinite(values)
    lo, hi = col.limits
    good = good & (values >= lo) & (values <= hi)
    return values, ~good & ~(empty & col.may_be_empty)


def _why_bad(value: str, col: _Column) -> str:
    """Why a value :func:`_convert` found bad is bad: not a number, or outside its range."""
    number = pd.to_numeric(value.strip(), errors="coerce")
    if col.kind == "int" and not re.fullmatch(_INT, value.strip()):
        too_long = re.fullmatch(r"[+-]?\d+", value.strip())
        return "beyond a 64-bit integer" if too_long else "not an integer"
    if pd.isna(number):
        return "not a number"
    lo, hi = col.limits
    return f"outside {lo:g}..{hi:g}" if np.isfinite(number) else "not a finite number"


def _measurements(table: pd.DataFrame, numbers: np.ndarray):
    """Raw rows -> (signals with the ``reason`` to drop them, "" to keep; bad lines with
    impossible times)."""
    time_nanos, full_bias = table["time_nanos"].to_numpy(), table["full_bias"].to_numpy()
    bias = np.nan_to_num(table["bias"].to_numpy())
    # first in float, which cannot overflow: the exact int64 sum only for plausible times
    approx = time_nanos.astype(float) - full_bias.astype(float) - bias
    has_time = full_bias != 0
    impossible = has_time & ~((approx >= _EARLIEST_GPS_NS) & (approx < _LATEST_GPS_NS))
    timed = has_time & ~impossible
    gps_ns = time_nanos[timed] - full_bias[timed] - np.rint(bias[timed]).astype(np.int64)
    utc_ns = np.full(time_nanos.shape, _NAT, dtype=np.int64)
    utc_ns[timed] = gps_to_utc(gps_ns).astype(np.int64)
    bad = [
        (n, f"Raw GPS time {_gps_text(t)}: TimeNanos or FullBiasNanos is wrong")
        for n, t in zip(numbers[impossible].tolist(), approx[impossible], strict=True)
    ]
    letter = _letters(table["constellation"].to_numpy())
    state = table["state"].to_numpy()
    locked = (state & _STATE_CODE_LOCK > 0) | (
        (letter == "E") & (state & _STATE_GAL_E1BC_CODE_LOCK > 0)
    )
    svid = _rinex_svid(letter, table["svid"].to_numpy())
    band = _band(table["frequency"].to_numpy())
    reason = np.select(
        [letter == "?", ~has_time, ~locked, (letter == "R") & (svid > 24), band == ""],
        [
            "unknown constellation",
            "no GPS time (FullBiasNanos empty)",
            "no code lock (State)",
            "GLONASS slot unknown (Svid is a frequency channel)",
            "carrier frequency in no GNSS band",
        ],
        default="",
    )
    signals = pd.DataFrame(
        {
            "time_utc": _utc(utc_ns),
            "constellation": letter,
            "svid": svid,
            "band": band,
            "cn0": table["cn0"].to_numpy(),
            "state": state,
        }
    )
    return signals.assign(reason=reason.astype(object)), bad


def _gps_text(gps_ns: float) -> str:
    """An impossible GPS time (ns since 1980-01-06), and why it is impossible."""
    when = f"{gps_ns:.4g} ns after 1980-01-06"
    if abs(gps_ns) < 9e18:  # within the range of datetime64[ns]
        when = np.datetime_as_string(GPS_EPOCH + np.timedelta64(int(gps_ns), "ns"), unit="ms")
    return (
        f"{when} is before {_EARLIEST}"
        if gps_ns < _EARLIEST_GPS_NS
        else f"{when} is after {_LATEST}"
    )


def _incomplete_epochs(signals, table, numbers, good, suspects, lines, header, last_record):
    """The epochs whose rows may not all be there (see the module documentation).

    Returns ``(by_line, trailing)``: ``by_line[n]`` the set of epochs (int64 UTC ns) that the
    damaged line ``n`` may belong to: the epoch around it when the good Raw rows before and
    after it share one (the rows of an epoch are written together), else those of these rows
    that its clock fields cannot tell it apart from; ``trailing`` ``(epoch, rows, rows
    before)`` when the log ends with an epoch whose rows are the first ones of the epoch before
    (a log cut at a line end), else None.
    """
    rows = np.flatnonzero(good)
    if not len(rows):
        return {}, None
    utc = _ns(signals["time_utc"])[rows]
    good_numbers = numbers[rows]
    names = header[1]
    clock = [names.index(name) + 1 for name in ("TimeNanos", "FullBiasNanos")]
    by_line = {}
    for n, kind in suspects.items():
        k = int(np.searchsorted(good_numbers, n))
        near = [j for j in (k - 1, k) if 0 <= j < len(rows) and utc[j] != _NAT]
        if len(near) == 2 and utc[near[0]] == utc[near[1]]:  # inside an epoch: one of its rows
            by_line[n] = {int(utc[near[0]])}
            continue
        by_line[n] = {
            int(utc[j])
            for j in near
            if _may_share_epoch(lines[n - 1], kind, lines[good_numbers[j] - 1], clock)
        }
    trailing = None
    if good_numbers[-1] == last_record and utc[-1] != _NAT:
        time_nanos, full_bias = (table[key].to_numpy()[rows] for key in ("time_nanos", "full_bias"))
        starts = np.flatnonzero((np.diff(time_nanos) != 0) | (np.diff(full_bias) != 0)) + 1
        signal = np.column_stack(
            [
                table["constellation"].to_numpy()[rows],
                table["svid"].to_numpy()[rows],
                np.nan_to_num(table["frequency"].to_numpy()[rows], nan=-1.0),
            ]
        )
        if len(starts):
            before = signal[(starts[-2] if len(starts) > 1 else 0) : starts[-1]]
            last = signal[starts[-1] :]
            if len(last) < len(before) and (before[: len(last)] == last).all():
                trailing = (int(utc[-1]), len(last), len(before))
    return by_line, trailing


def _may_share_epoch(text: str, kind: str, other: str, clock: list[int]) -> bool:
    """Whether the damaged line ``text`` may be a row of the epoch of the good Raw row ``other``.

    The rows of an epoch share their clock fields (``clock``: TimeNanos, FullBiasNanos), so a
    line whose clock differs belongs to another epoch. Only trusted fields count: none of a
    ``"garbled"`` line (its fields may have moved), the readable ones of a ``"row"`` with a
    bad value elsewhere, and of a ``"cut"`` line its complete fields and the start of the last.
    """
    if kind == "garbled":
        return True
    mine, theirs = text.rstrip("\r").split(","), other.rstrip("\r").split(",")
    for k in clock:
        if k >= len(mine):
            continue  # cut before this field
        a, b = mine[k].strip(), theirs[k].strip()
        if kind == "cut" and k == len(mine) - 1:
            if not b.startswith(a):
                return False
        elif (a == "" or re.fullmatch(_INT, a)) and (int(a) if a else 0) != (int(b) if b else 0):
            return False
    return True


def _own_epoch(text: str, names: list[str]) -> int | None:
    """The epoch (int64 UTC ns) of a cut-off Raw line, when its clock fields are complete."""
    fields = text.rstrip("\r").split(",")[:-1]  # the last field may be cut short
    values = {}
    for name in ("TimeNanos", "FullBiasNanos", "BiasNanos"):
        k = names.index(name) + 1 if name in names else len(fields)
        values[name] = fields[k].strip() if k < len(fields) else ""
    if not all(re.fullmatch(_INT, values[name]) for name in ("TimeNanos", "FullBiasNanos")):
        return None
    bias = pd.to_numeric(values["BiasNanos"], errors="coerce") if values["BiasNanos"] else 0.0
    gps_ns = int(values["TimeNanos"]) - int(values["FullBiasNanos"]) - round(np.nan_to_num(bias))
    if not _EARLIEST_GPS_NS <= gps_ns < _LATEST_GPS_NS:
        return None
    return int(gps_to_utc(np.array([gps_ns]))[0].astype(np.int64))


def _warn_skipped(path, bad, cut, by_line, split, trailing) -> None:
    """One warning per cause (bad lines skipped, a cut-off last line, a log cut at a line
    end), each naming the epochs dropped with it."""
    if bad:
        line, reason = min(bad)
        lost = set().union(*(by_line.get(n, ()) for n, _ in bad))
        warnings.warn(
            f"{path}: skipped {len(bad)} bad line(s); the first, line {line}: {reason}"
            + _dropping(lost, "they"),
            stacklevel=3,
        )
    if cut is not None:
        lost = by_line.get(cut, set())
        text = (
            f"{path}: the last line ({cut}) is cut off (no line end: the log was closed while "
            "being written); skipped it" + _dropping(lost, "it")
        )
        if not lost and cut in by_line and "Raw" in split.headers:
            own = _own_epoch(split.lines[cut - 1], split.headers["Raw"][1])
            epoch = "a new epoch" if own is None else f"epoch {_time_text(own)}"
            text += f" (it begins {epoch}, of which no other row was written)"
        warnings.warn(text, stacklevel=3)
    if trailing is not None:
        epoch, rows, before = trailing
        warnings.warn(
            f"{path}: the log ends inside epoch {_time_text(epoch)}: its {rows} rows are the "
            f"first of the {before} of the epoch before, in the same order (the log was cut at a "
            "line end); dropped it",
            stacklevel=3,
        )


def _dropping(epochs: set[int], subject: str) -> str:
    """ "; dropped the epoch(s) ..." naming up to three epochs, or "" for none."""
    if not epochs:
        return ""
    times = sorted(epochs)
    shown = ", ".join(_time_text(t) for t in times[:3])
    if len(times) > 3:
        shown += f" and {len(times) - 3} more"
    return (
        f"; dropped the {len(times)} epoch(s) {subject} may belong to, whose rows are not all "
        f"there: {shown}"
    )


def _time_text(ns: int) -> str:
    """int64 UTC ns -> ISO 8601 to the millisecond."""
    return np.datetime_as_string(np.datetime64(ns, "ns"), unit="ms") + "Z"


def _utc(ns: np.ndarray) -> pd.DatetimeIndex:
    """int64 ns since 1970 (``_NAT`` for none) -> datetime64[ns, UTC]."""
    return pd.DatetimeIndex(ns.astype("datetime64[ns]")).tz_localize("UTC")


def _ns(times) -> np.ndarray:
    """UTC times -> int64 ns since 1970."""
    return pd.DatetimeIndex(times).as_unit("ns").asi8


def _letters(constellation_type: np.ndarray) -> np.ndarray:
    """Android ConstellationType -> RINEX letter ("?" for unknown)."""
    known = (constellation_type >= 0) & (constellation_type < len(_LETTERS))
    return _LETTERS[np.where(known, constellation_type, 0)]


def _rinex_svid(letter: np.ndarray, svid: np.ndarray) -> np.ndarray:
    """Android Svid -> RINEX satellite number (QZSS 193-202 -> 1-10, SBAS 120-158 -> 20-58)."""
    svid = svid.copy()
    svid[(letter == "J") & (svid >= 193)] -= 192
    svid[(letter == "S") & (svid >= 120)] -= 100
    return svid


def _band(frequency_hz: np.ndarray) -> np.ndarray:
    """RINEX band name per carrier frequency; missing -> L1, outside every band -> ""."""
    mhz = frequency_hz / 1e6
    band = np.full(mhz.shape, "", dtype=object)
    band[np.isnan(mhz) | (mhz == 0)] = "L1"
    for name, low, high in _BANDS:
        band[(mhz >= low) & (mhz < high)] = name
    return band


def _without(frame: pd.DataFrame, numbers: np.ndarray, bad_lines: np.ndarray) -> pd.DataFrame:
    """``frame`` without the rows from bad lines (its index = position in ``numbers``)."""
    keep = ~np.isin(numbers[frame.index.to_numpy()], bad_lines)
    return frame[keep].reset_index(drop=True)


def _fixes(table: pd.DataFrame) -> pd.DataFrame:
    """Fix records -> the ``fixes`` table."""
    return pd.DataFrame(
        {
            "time_utc": _utc(table["time_ms"].to_numpy() * 10**6),
            "provider": table["provider"].astype(str).str.lower(),
            "lat": table["lat"],
            "lon": table["lon"],
            "altitude": table["altitude"],
            "accuracy": table["accuracy"],
        }
    )


def _status(table: pd.DataFrame) -> pd.DataFrame:
    """Status records with a time (``UnixTimeMillis`` is empty or 0 before a GPS fix)."""
    letter = _letters(table["constellation"].to_numpy())
    band = _band(table["frequency"].to_numpy())
    keep = (table["time_ms"].to_numpy() > 0) & (letter != "?") & (band != "")
    table = table[keep]
    return pd.DataFrame(
        {
            "time_utc": _utc(table["time_ms"].to_numpy() * 10**6),
            "constellation": letter[keep],
            "svid": _rinex_svid(letter[keep], table["svid"].to_numpy()),
            "band": band[keep],
            "azimuth": table["azimuth"].to_numpy(),
            "elevation": table["elevation"].to_numpy(),
            "cn0": table["cn0"].to_numpy(),
        }
    )
