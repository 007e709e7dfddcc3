"""The lines of a GnssLogger log, split by record type and read into typed columns.

One pass over the text (:func:`split_lines`) finds the ``# Version:`` line, the
``# <Type>,...`` header lines and the records the reader uses (``Raw``, ``Fix``, ``Status``);
:func:`parse_records` then reads the columns each record type needs, found by their header
names, as integers, floats or text, each checked against the range its values can have. Lines
that break the rules ("Bad input" in :mod:`.gnsslogger`) come back as ``(line, reason)``
pairs, and a last line without line end that stops short as a cut-off line: what becomes of
them is for :func:`~gnss_citygml.gnss.gnsslogger.read_gnsslogger` to decide. What the values
mean is in :mod:`.measurements`.
"""

from __future__ import annotations

import csv
import io
import re
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import NamedTuple

import numpy as np
import pandas as pd

from gnss_citygml.errors import InputError, MissingColumnError
from gnss_citygml.files.paths import StrPath

__all__ = ["INT_PATTERN", "RECORDS", "parse_records", "split_lines"]

#: Unix times in ms that are still datetime64[ns] (before 2262).
_MS = (0.0, np.iinfo(np.int64).max // 10**6)
#: Larger clock biases (ns, 11.6 days) are no bias but a wrong field.
_BIAS = (-1e15, 1e15)
_CN0 = (0.0, 100.0)
#: Heights (m) above the ellipsoid a phone can be at: 100 km from the Earth's surface.
_HEIGHT = (-1e5, 1e5)
_KNOWN_MAJOR_VERSIONS = ("1", "2", "3")
_VERSION = re.compile(r"v?(\d+)(\.\d+)+")
_RECORD_TYPE = re.compile(r"[A-Za-z]+")
#: A whole number that fits int64 (a regular expression).
INT_PATTERN = r"[+-]?(\d{1,18}|[1-8]\d{18})"


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
#: The records the reader uses, and the columns it needs of each.
RECORDS = {"Raw": _RAW, "Fix": _FIX, "Status": _STATUS}


class _Lines(NamedTuple):
    """What one pass over the lines of a log finds (:func:`split_lines`)."""

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


def split_lines(text: str, path: Path, lenient: bool) -> _Lines:
    """One pass over the lines: the version, the headers, the records this reader uses.

    ``records`` holds only lines with the field count of their header; the others are ``bad``,
    except a last line without line end that has fewer fields, or is the start of a record
    type's name ("Ra"): that is ``cut``, a log closed while being written.
    """
    version = version_line = None
    headers: dict[str, tuple[int, list[str]]] = {}
    records: dict[str, tuple[list[int], list[str]]] = {kind: ([], []) for kind in RECORDS}
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
    cut, cut_raw = _drop_miscounted(records, headers, open_last, cut, cut_raw, bad, garbled)
    return _Lines(
        version, headers, records, bad, garbled, cut, cut_raw, open_last, last_record, lines
    )


def _drop_miscounted(records, headers, open_last, cut, cut_raw, bad, garbled):
    """Leave out of ``records`` (in place) the rows whose field count is not their header's,
    each one added to ``bad`` (and a Raw one to ``garbled``), except a short last line without
    line end: that is ``cut``. Returns ``cut`` and whether it is a Raw row."""
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
    return cut, cut_raw


def _check_version(text: str, path: Path, line: int | None, lenient: bool) -> str:
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


def parse_records(
    kind: str,
    header: tuple[int, list[str]] | None,
    numbers: Sequence[int],
    lines: list[str],
    columns: dict[str, _Column],
    path: StrPath,
) -> tuple[pd.DataFrame, list[tuple[int, str]]]:
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
        good = text.str.fullmatch(INT_PATTERN).to_numpy(dtype=bool)
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
    if col.kind == "int" and not re.fullmatch(INT_PATTERN, value.strip()):
        too_long = re.fullmatch(r"[+-]?\d+", value.strip())
        return "beyond a 64-bit integer" if too_long else "not an integer"
    if pd.isna(number):
        return "not a number"
    lo, hi = col.limits
    return f"outside {lo:g}..{hi:g}" if np.isfinite(number) else "not a finite number"
