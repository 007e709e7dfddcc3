"""Android GnssLogger logs read into tables: C/N0 per received signal, UTC epoch times, fixes.

GnssLogger (Google's logging app, versions 1.4 of 2016 to 3.x) writes a text file of
comma-separated records, each line starting with its record type (``Raw``, ``Fix``,
``Status``, ``Agc``, sensor records, ...). ``#`` lines form the header: a ``# Version:`` line
and one ``# <Type>,<column>,...`` line per record type. Columns are found by these header
names, never by position: old logs say ``ElapsedRealtimeMillis`` and ``Latitude`` /
``(UTC)TimeInMs`` where newer ones say ``utcTimeMillis`` and ``LatitudeDegrees`` /
``UnixTimeMillis``; the London log of 2020 even repeats ``CarrierFrequencyHz`` (the first
one is used).

:func:`read_gnsslogger` reads a log into a :class:`GnssLog`. The lines are split by record
type and read into typed columns in :mod:`.logrecords`; what the fields mean (epoch times,
signals, which measurements are kept) is in :mod:`.measurements`; this module holds the log
and the rules for damaged logs below. The receiver positions, from the ``Fix`` rows or from
a survey, are in :mod:`.positions`.

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
"""

from __future__ import annotations

import re
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from gnss_citygml.errors import InputError, listing
from gnss_citygml.files.paths import StrPath
from gnss_citygml.gnss.gpstime import NAT_NS, utc_ns
from gnss_citygml.gnss.logrecords import INT_PATTERN, RECORDS, parse_records, split_lines
from gnss_citygml.gnss.measurements import cut_line_epoch, fix_table, raw_signals, status_table

__all__ = ["GnssLog", "read_gnsslogger"]

_INCOMPLETE = "incomplete epoch (a row of it is bad, cut off or missing)"
_FIX_HINT = "repair or delete the line, or read the log leniently (lenient=True, --lenient)"


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


def read_gnsslogger(path: StrPath, *, lenient: bool = False) -> GnssLog:
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
        documentation and :mod:`.measurements` for the rules).

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
    split = split_lines(text, path, lenient)
    bad = list(split.bad)
    suspects = dict.fromkeys(split.garbled, "garbled")  # damaged lines that may be Raw rows
    value_bad: set[int] = set()
    tables = _parse_tables(split, path, bad, value_bad, suspects)
    raw_table, raw_numbers = tables["Raw"]
    signals, bad_time = raw_signals(raw_table, raw_numbers)
    bad += bad_time
    value_bad.update(n for n, _ in bad_time)
    suspects.update(dict.fromkeys((n for n, _ in bad_time), "garbled"))
    cut = _cut_line(split, value_bad, suspects)
    bad = [(n, reason) for n, reason in bad if n != cut]
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
    reason[good & np.isin(utc_ns(signals["time_utc"]), list(incomplete)) & (reason == "")] = (
        _INCOMPLETE
    )
    _warn_skipped(path, bad, cut, by_line, split, trailing)
    kept = good & (reason == "")
    return GnssLog(
        path=path,
        version=split.version,
        raw=signals[kept].drop(columns="reason").reset_index(drop=True),
        dropped=signals[good & ~kept].assign(reason=reason[good & ~kept]).reset_index(drop=True),
        fixes=fix_table(_without(*tables["Fix"], bad_lines)),
        status=status_table(_without(*tables["Status"], bad_lines)),
        skipped_lines=len(bad) + (cut is not None),
    )


def _cut_line(split, value_bad: set[int], suspects: dict[int, str]) -> int | None:
    """The line of a log closed while being written (None: none), also where its last line
    was cut inside its last field (a value that does not parse); a cut Raw row is a suspect
    of its epoch (``cut``), anything else it was suspected of is not."""
    cut, cut_raw = split.cut, split.cut_raw
    if cut is None and split.open_last in value_bad:  # cut inside its last field
        cut, cut_raw = split.open_last, split.open_last in split.records["Raw"][0]
    if cut is not None:
        suspects.pop(cut, None)
        if cut_raw:
            suspects[cut] = "cut"
    return cut


def _parse_tables(
    split, path: Path, bad, value_bad, suspects
) -> dict[str, tuple[pd.DataFrame, np.ndarray]]:
    """Each record type's table and line numbers; its rows with bad values added to ``bad``
    and ``value_bad`` (a Raw one also to ``suspects``, as a damaged row)."""
    tables = {}
    for kind, columns in RECORDS.items():
        numbers, lines = split.records[kind]
        if numbers and kind not in split.headers:
            raise InputError(
                f"{kind} records but no '# {kind},...' header line",
                where=f"{path}, line {numbers[0]}",
                fix=f"restore the log's header (its '# {kind},' line names the columns)",
            )
        header = split.headers.get(kind)
        table, bad_rows = parse_records(kind, header, numbers, lines, columns, path)
        bad += bad_rows
        value_bad.update(n for n, _ in bad_rows)
        if kind == "Raw":
            suspects.update(dict.fromkeys((n for n, _ in bad_rows), "row"))
        tables[kind] = (table, np.asarray(numbers, dtype=np.int64))
    return tables


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
    utc = utc_ns(signals["time_utc"])[rows]
    good_numbers = numbers[rows]
    names = header[1]
    clock = [names.index(name) + 1 for name in ("TimeNanos", "FullBiasNanos")]
    by_line = {}
    for n, kind in suspects.items():
        k = int(np.searchsorted(good_numbers, n))
        near = [j for j in (k - 1, k) if 0 <= j < len(rows) and utc[j] != NAT_NS]
        if len(near) == 2 and utc[near[0]] == utc[near[1]]:  # inside an epoch: one of its rows
            by_line[n] = {int(utc[near[0]])}
            continue
        by_line[n] = {
            int(utc[j])
            for j in near
            if _may_share_epoch(lines[n - 1], kind, lines[good_numbers[j] - 1], clock)
        }
    trailing = None
    if good_numbers[-1] == last_record and utc[-1] != NAT_NS:
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
        elif (a == "" or re.fullmatch(INT_PATTERN, a)) and (int(a) if a else 0) != (
            int(b) if b else 0
        ):
            return False
    return True


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
            own = cut_line_epoch(split.lines[cut - 1], split.headers["Raw"][1])
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
    return (
        f"; dropped the {len(times)} epoch(s) {subject} may belong to, whose rows are not all "
        f"there: {listing(map(_time_text, times), 3)}"
    )


def _time_text(ns: int) -> str:
    """int64 UTC ns -> ISO 8601 to the millisecond."""
    return np.datetime_as_string(np.datetime64(ns, "ns"), unit="ms") + "Z"


def _without(frame: pd.DataFrame, numbers: np.ndarray, bad_lines: np.ndarray) -> pd.DataFrame:
    """``frame`` without the rows from bad lines (its index = position in ``numbers``)."""
    keep = ~np.isin(numbers[frame.index.to_numpy()], bad_lines)
    return frame[keep].reset_index(drop=True)
