"""The observations table: one row per (epoch, receiver, satellite above the mask).

This is the toolkit's interchange format (DESIGN.md): ``time_utc``, ``receiver``, ``lat``,
``lon`` (deg, ETRS89/WGS84), ``h`` (ellipsoidal height, m; may be empty when the DEM gives
the receiver height), ``constellation`` (RINEX letter), ``svid``, ``azimuth`` (deg from TRUE
north), ``elevation`` (deg), ``cn0`` (dB-Hz; empty = above the horizon but not received,
i.e. blocked) and ``position_sd`` (m per axis: how far the reported position may be off; may be
empty when unknown). :func:`check_observations` turns any table a user hands in into that schema or
says exactly which row is wrong and why.

A table holds each signal once: the same receiver, satellite and time (within a millisecond)
twice with different values is refused, naming both lines, and exact repeats are counted once
with a warning, within a file and across the files read together
(:func:`read_observation_files`). A column whose whole range says it is in other units
(azimuths all within 2 pi: radians) draws a warning.

The columns, which of them are required, their types, the constellation letters and the ranges
come from the published JSON Schema of a row (``schemas/observations.schema.json``, see
:mod:`gnss_citygml.contracts`); the checks themselves run on whole columns at once.
"""

from __future__ import annotations

import csv
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from .contracts import OBSERVATIONS, load, types
from .errors import InputError, MissingColumnError
from .files.paths import StrPath
from .files.tables import read_table, write_table

__all__ = [
    "CONSTELLATIONS",
    "OBSERVATION_COLUMNS",
    "check_observations",
    "satellites",
    "read_observation_files",
    "read_observations",
    "repeated_signals",
    "write_observations",
]

_SCHEMA = load(OBSERVATIONS)
_PROPERTIES = _SCHEMA["properties"]

#: Column order of the observations table (the schema's properties).
OBSERVATION_COLUMNS = list(_PROPERTIES)

#: RINEX system letters: GPS, GLONASS, Galileo, BeiDou, QZSS, SBAS, NavIC.
CONSTELLATIONS = tuple(_PROPERTIES["constellation"]["enum"])

_REQUIRED = list(_SCHEMA["required"])
#: Columns a table may leave out (h, position_sd): added empty.
_OPTIONAL = [c for c in OBSERVATION_COLUMNS if c not in _REQUIRED]
#: Columns of numbers, in column order (lat, lon, h, azimuth, elevation, cn0, position_sd); those
#: that may be empty (null in the schema: h, cn0, position_sd).
_NUMBERS = [c for c, spec in _PROPERTIES.items() if "number" in types(spec)]
_MAY_BE_EMPTY = [c for c in _NUMBERS if "null" in types(_PROPERTIES[c])]
#: The satellite numbers RINEX has (larger ones are no satellite and would overflow int64).
_SVIDS = (_PROPERTIES["svid"]["minimum"], _PROPERTIES["svid"]["maximum"])
#: (lowest, highest, whether the highest is excluded) of each column of numbers with a range.
_RANGES = {
    c: (
        float(spec.get("minimum", -np.inf)),
        float(spec.get("maximum", spec.get("exclusiveMaximum", np.inf))),
        "exclusiveMaximum" in spec,
    )
    for c, spec in _PROPERTIES.items()
    if c in _NUMBERS and {"minimum", "maximum", "exclusiveMaximum"} & spec.keys()
}


def read_observations(path: StrPath) -> pd.DataFrame:
    """Read an observations table (CSV or Parquet) and check it (:func:`check_observations`).

    Errors name the file and, for bad values, the line of the CSV file (or the Parquet row).
    """
    return read_observation_files([path])


def read_observation_files(paths: Sequence[StrPath]) -> pd.DataFrame:
    """Read observations tables (CSV or Parquet) as one, checked (:func:`check_observations`):
    a signal in two of the files is a repeat too, and its lines are named in their files."""
    if not paths:
        raise InputError("no observations file", fix="give one or more observations tables")
    tables, places = [], []
    for path in paths:
        is_csv = Path(path).suffix.lower() == ".csv"
        line_of = (lambda row, path=path: _csv_line(path, row)) if is_csv else None
        places.append(_locator(str(path), line_of))
        tables.append(_normalised(read_table(path), str(path), places[-1]))
    starts = np.cumsum([0] + [len(t) for t in tables])

    def locate(row: int) -> str:
        k = int(np.searchsorted(starts, row, side="right")) - 1
        return places[k](row - int(starts[k]))

    where = ", ".join(str(p) for p in paths)
    out = tables[0] if len(tables) == 1 else pd.concat(tables, ignore_index=True)
    return _checked(out, where, locate)


def _csv_line(path, row: int) -> int | None:
    """The line of a CSV file where data row ``row`` (0-based, as pandas reads it) starts.

    Found only when an error needs it: records are counted as pandas counts them (blank and
    whitespace-only lines skipped, a quoted field may span lines). None if the file cannot be
    followed that far (a field beyond the csv module's size limit)."""
    with open(path, encoding="utf-8", errors="replace", newline="") as file:
        reader = csv.reader(file)
        end, data_row = 0, -1  # lines read; the header is row -1
        try:
            for record in reader:
                start, end = end + 1, reader.line_num
                if not record or (len(record) == 1 and not record[0].strip()):
                    continue
                if data_row == row:
                    return start
                data_row += 1
        except csv.Error:
            return None
    return None


def satellites(table: pd.DataFrame) -> pd.Categorical:
    """Each row's satellite as ``G05``, ``E21``...: its ``constellation`` letter and ``svid``.

    One satellite seen by one recording is one *track*: its rows look at a building from
    nearly the same place, so the height fits count them as one look per height
    (:func:`~gnss_citygml.model.fourplb.height_weights`).
    """
    letter, letters = pd.factorize(table["constellation"].astype(str), use_na_sentinel=False)
    number = table["svid"].astype(int).to_numpy()
    low = number.min(initial=0)
    span = number.max(initial=0) - low + 1
    # one integer per (letter, number) pair, factorized: the pairs in order of first appearance
    codes, first = pd.factorize(letter * span + (number - low))
    names = [f"{letters[i // span]}{i % span + low:02d}" for i in first]
    return pd.Categorical.from_codes(codes, categories=pd.Index(names, dtype=object))


def write_observations(table: pd.DataFrame, path: StrPath, *, overwrite: bool = True) -> None:
    """Write an observations table (CSV or Parquet by suffix), atomically."""
    write_table(check_observations(table, where="observations to write"), path, overwrite=overwrite)


def check_observations(
    table: pd.DataFrame,
    *,
    where: str = "observations",
    line_of: Callable[[int], int | None] | None = None,
) -> pd.DataFrame:
    """The table in the observations schema, or an :class:`InputError` naming the first bad row.

    Parameters
    ----------
    table
        A table with at least the columns of :data:`OBSERVATION_COLUMNS` except the optional
        ``h`` and ``position_sd``.
    where
        What to call the table in error messages (a file name).
    line_of
        The file line of a 0-based row (of a CSV file), to name lines in errors; None (or a
        None line) names the row instead.

    Returns
    -------
    DataFrame
        The columns of :data:`OBSERVATION_COLUMNS` first (``h`` and ``position_sd`` added as
        NaN when absent),
        other columns after them untouched; ``time_utc`` as UTC timestamps, numbers as float,
        ``svid`` as int, ``receiver`` and ``constellation`` as str.

    Examples
    --------
    >>> t = pd.DataFrame({"time_utc": ["2020-02-11T08:50:00Z"], "receiver": ["s10"],
    ...     "lat": [51.5247], "lon": [-0.1343], "constellation": ["G"], "svid": [5],
    ...     "azimuth": [120.5], "elevation": [33.0], "cn0": [float("nan")]})
    >>> check_observations(t).dtypes["time_utc"]
    datetime64[ns, UTC]
    >>> t.loc[0, "elevation"] = 95.0
    >>> check_observations(t)
    Traceback (most recent call last):
    ...
    gnss_citygml.errors.InputError: elevation 95 outside -90..90 (observations, row 0): ...
    """
    locate = _locator(where, line_of)
    return _checked(_normalised(table, where, locate), where, locate)


def _locator(where: str, line_of: Callable[[int], int | None] | None) -> Callable[[int], str]:
    """Where a 0-based row is, for a message: its file line when ``line_of`` knows it."""

    def locate(row: int) -> str:
        line = None if line_of is None else line_of(row)
        return f"{where}, row {row}" if line is None else f"{where}, line {line}"

    return locate


def _checked(out: pd.DataFrame, where: str, locate: Callable[[int], str]) -> pd.DataFrame:
    """A normalised table with each signal once (:func:`_single_signals`), numbered from 0, and
    warned about once if a column looks like other units (a table checked before is not)."""
    if not out.attrs.get(_CHECKED):
        _unit_warnings(out, where)
    out = _single_signals(out, where, locate).reset_index(drop=True)
    out.attrs[_CHECKED] = True
    return out


#: Marks a table :func:`check_observations` made, so that checking it again (the pipeline checks
#: what it is given) does not warn twice.
_CHECKED = "gnss_citygml.observations.checked"


def _normalised(table: pd.DataFrame, where: str, locate: Callable[[int], str]) -> pd.DataFrame:
    """The table in the schema's columns and types, its rows as they were, or the first bad
    row's error."""
    twice = sorted({_name(c) for c in table.columns[table.columns.duplicated()]})
    if twice:
        raise InputError(
            "column(s) " + ", ".join(f"'{c}'" for c in twice) + " more than once",
            where=where,
            fix="keep one column of each name",
        )
    missing = [c for c in _REQUIRED if c not in table.columns]
    if missing:
        raise MissingColumnError(missing, where=where, have=[_name(c) for c in table.columns])
    out = table.copy()
    for column in _OPTIONAL:
        if column not in out.columns:
            out[column] = np.nan
    out["time_utc"] = _times(out["time_utc"], locate)
    for column in _NUMBERS:
        out[column] = _numbers(out[column], column, locate)
    for column in _NUMBERS:
        if column not in _MAY_BE_EMPTY:  # lat, lon, azimuth, elevation
            _no_gaps(out[column], column, locate)
    out["svid"] = _svids(out["svid"], locate)
    out["receiver"] = _labels(out["receiver"], "receiver", locate)
    out["constellation"] = _labels(out["constellation"], "constellation", locate).str.upper()
    bad = ~out["constellation"].isin(CONSTELLATIONS)
    if bad.any():
        row = _first_bad(bad.to_numpy())
        raise InputError(
            f"unknown constellation {out['constellation'].iloc[row]!r}",
            where=locate(row),
            fix="use a RINEX letter: " + ", ".join(CONSTELLATIONS),
        )
    for column, (lo, hi, below_hi) in _RANGES.items():
        values = out[column].to_numpy()
        bad = (values < lo) | (values >= hi if below_hi else values > hi)  # azimuth 360 is 0
        if bad.any():
            row = _first_bad(bad)
            raise InputError(
                f"{column} {values[row]:g} outside {lo:g}..{hi:g}",
                where=locate(row),
                fix=_RANGE_FIX[column],
            )
    others = [c for c in out.columns if c not in OBSERVATION_COLUMNS]
    return out[OBSERVATION_COLUMNS + others].reset_index(drop=True)


#: Observations of one satellite by one receiver closer in time than this (ns) are one signal
#: (a time written twice, rounded or in another zone): no receiver logs 1000 epochs a second.
_SAME_TIME = 1_000_000


def repeated_signals(table: pd.DataFrame) -> tuple[np.ndarray, np.ndarray]:
    """Pairs of rows (positions, the earlier first in time) of a checked observations table
    that are one signal: the same receiver and satellite within :data:`_SAME_TIME` of each
    other. Vectorised: one sort, then neighbouring rows compared."""
    n = len(table)
    time = np.asarray(table["time_utc"].array.asi8)
    receiver = pd.factorize(table["receiver"])[0]
    satellite = pd.factorize(pd.MultiIndex.from_arrays([table["constellation"], table["svid"]]))[0]
    order = np.lexsort((np.arange(n), time, satellite, receiver))
    r, s, t = receiver[order], satellite[order], time[order]
    same = (r[1:] == r[:-1]) & (s[1:] == s[:-1]) & (np.diff(t) < _SAME_TIME)
    return order[:-1][same], order[1:][same]


def _single_signals(out: pd.DataFrame, where: str, locate: Callable[[int], str]) -> pd.DataFrame:
    """The table with each signal (receiver, satellite, time) once.

    A signal given twice with different values (received and blocked, another azimuth) is an
    :class:`InputError` naming both lines: which one is right cannot be told, and counting both
    would pull the heights towards nothing. Exact repeats (a file given twice, a log merged
    twice) are dropped with a warning that counts them: they would count twice in the fits.
    """
    n = len(out)
    first, second = repeated_signals(out)
    if not first.size:
        return out
    values = out[_NUMBERS].to_numpy(dtype=float)
    a, b = values[first], values[second]
    differ = ~((a == b) | (np.isnan(a) & np.isnan(b)))
    clash = differ.any(axis=1)
    if clash.any():
        later = np.maximum(first, second)
        k = int(np.flatnonzero(clash)[np.argmin(later[clash])])
        i, j = sorted((int(first[k]), int(second[k])))
        column = _NUMBERS[int(np.flatnonzero(differ[k])[0])]
        row = out.iloc[i]
        shown = [_cell(out[column].iloc[x]) for x in (i, j)]
        raise InputError(
            f"the same signal twice with different values: receiver {_show(row['receiver'])}, "
            f"satellite {row['constellation']}{row['svid']:02d} at "
            f"{row['time_utc']:%Y-%m-%dT%H:%M:%S.%f}Z, {column} {shown[0]} and {shown[1]}"
            + (f" ({int(clash.sum())} such pairs)" if clash.sum() > 1 else ""),
            where=f"{locate(i)} and {locate(j)}",
            fix="keep one row per receiver, satellite and time (were two recordings given the "
            "same receiver name, or a file merged with an edited copy?)",
        )
    repeats = np.unique(second)
    i, j = sorted((int(first[0]), int(second[0])))
    warnings.warn(
        f"{repeats.size} repeated observation(s) (the same receiver, satellite, time and values) "
        f"counted once ({where}; first: {locate(j)} repeats {locate(i)})",
        UserWarning,
        stacklevel=4,
    )
    keep = np.ones(n, dtype=bool)
    keep[repeats] = False
    return out[keep]


def _cell(value: float) -> str:
    return "empty" if np.isnan(value) else f"{value:g}"


#: Whole-range evidence of other units: a column warned about only with at least this many rows
#: of at least this many satellites (a few rows of one satellite may lie anywhere).
_EVIDENCE_ROWS, _EVIDENCE_SATELLITES = 20, 5
#: C/N0s (dB-Hz) a GNSS receiver tracks on the ground: none above, and none can track below.
_CN0_TRACKED = (10.0, 60.0)
#: Position errors (m per axis) beyond any fix a recording's every row can have.
_POSITION_SD_MOST = 100.0


def _unit_warnings(out: pd.DataFrame, where: str) -> None:
    """Warn, one line each, where a column's whole range says it is in other units than the
    schema's: azimuths all within 2 pi or elevations within pi/2 over many rows of many
    satellites (radians), latitudes and longitudes within pi/2 and pi (radians: in degrees,
    the sea off West Africa), every C/N0 below or above what receivers track (another scale),
    every position_sd over 100 m (not metres). A warning, not an error: such values are
    possible, only not all of them together."""
    many = len(out) >= _EVIDENCE_ROWS and (
        len(out[["constellation", "svid"]].drop_duplicates()) >= _EVIDENCE_SATELLITES
    )
    said = []
    if many and out["azimuth"].max() <= 2 * np.pi:
        said.append(
            f"every azimuth is within 0..{2 * np.pi:.2f}: radians? (give azimuths in degrees)"
        )
    if many and out["elevation"].abs().max() <= np.pi / 2:
        said.append(
            f"every elevation is within +-{np.pi / 2:.2f}: radians? (give elevations in degrees)"
        )
    if len(out) and out["lat"].abs().max() <= np.pi / 2 and out["lon"].abs().max() <= np.pi:
        said.append(
            f"every lat is within +-{np.pi / 2:.2f} and lon within +-{np.pi:.2f}: radians? "
            "(give latitudes and longitudes in degrees)"
        )
    cn0 = out["cn0"].dropna()
    lo, hi = _CN0_TRACKED
    if len(cn0) >= _EVIDENCE_ROWS and (cn0.max() < lo or cn0.min() > hi):
        said.append(
            f"every C/N0 is {'below' if cn0.max() < lo else 'above'} "
            f"{lo if cn0.max() < lo else hi:g} dB-Hz (receivers track from about {lo:g} to "
            f"{hi:g}): another scale? (give C/N0 in dB-Hz)"
        )
    sd = out["position_sd"].dropna()
    if len(sd) >= _EVIDENCE_ROWS and sd.min() > _POSITION_SD_MOST:
        said.append(
            f"every position_sd is over {_POSITION_SD_MOST:g} m: not metres? (give the "
            "position error in metres per axis, or leave it empty)"
        )
    for text in said:
        warnings.warn(f"{text} ({where})", UserWarning, stacklevel=4)


_RANGE_FIX = {
    "lat": "give latitudes in degrees (ETRS89/WGS84), not projected coordinates",
    "lon": "give longitudes in degrees (ETRS89/WGS84), not projected coordinates",
    "azimuth": "give azimuths in degrees clockwise from true north, 0 <= azimuth < 360",
    "elevation": "give elevations in degrees above the horizon",
    "cn0": "give C/N0 in dB-Hz, leaving it empty for satellites not received",
    "position_sd": "give the position error in metres per axis, or leave it empty when unknown",
}


def _show(value) -> str:
    """A cell as the user wrote it: strings quoted, numbers plain, anything else (a list, a
    mapping from a nested Parquet column) as Python shows it; cut to 40 characters."""
    if isinstance(value, pd.Timestamp):
        value = value.asm8  # shown by numpy even beyond the years Python's datetime has
    if isinstance(value, np.generic | np.ndarray):
        value = value if isinstance(value, np.datetime64) else value.tolist()
    try:
        text = repr(value) if isinstance(value, str) else str(value)
    except ValueError:  # an int of more digits than Python converts
        text = f"<{type(value).__name__}>"
    return text if len(text) <= 40 else text[:37] + "..."


def _name(column) -> str:
    """A column name for a one-line message: control characters escaped, cut to 40."""
    text = repr(str(column))[1:-1]
    return text if len(text) <= 40 else text[:37] + "..."


def _first_bad(bad: np.ndarray) -> int:
    return int(np.flatnonzero(bad)[0])


def _times(column: pd.Series, locate) -> pd.Series:
    """UTC times from text or datetimes. Numbers are no times: read as nanoseconds since 1970
    they would be silently wrong (seconds or milliseconds since 1970 are as likely)."""
    if column.dtype.kind in "biufc":
        times = pd.Series(pd.NaT, index=column.index, dtype="datetime64[ns, UTC]")
    else:
        times = pd.to_datetime(column, utc=True, errors="coerce", format="mixed")
    within = (times >= pd.Timestamp.min.tz_localize("UTC")) & (
        times <= pd.Timestamp.max.tz_localize("UTC")
    )
    times = times.where(within).astype("datetime64[ns, UTC]")
    bad = times.isna().to_numpy()
    if bad.any():
        row = _first_bad(bad)
        raise InputError(
            f"time_utc {_show(column.iloc[row])} is not a time",
            where=locate(row),
            fix="write times as ISO 8601, e.g. 2020-02-11T08:49:29.000Z",
        )
    return times


def _numbers(column: pd.Series, name: str, locate) -> pd.Series:
    """Finite numbers, or NaN where the cell is empty."""
    numbers = _to_numeric(column)
    bad = ((numbers.isna() & column.notna()) | np.isinf(numbers)).to_numpy()
    if bad.any():
        row = _first_bad(bad)
        raise InputError(
            f"{name} {_show(column.iloc[row])} is not a "
            + ("finite number" if np.isinf(numbers.iloc[row]) else "number"),
            where=locate(row),
            fix=f"give {name} as a number"
            + (" or leave it empty" if name in _MAY_BE_EMPTY else ""),
        )
    return numbers


def _to_numeric(column: pd.Series) -> pd.Series:
    """Numbers as float; NaN for what is not a number (text, a list, a date, a boolean)."""
    if column.dtype.kind in "bcmM" or isinstance(column.dtype, pd.DatetimeTZDtype):
        return pd.Series(np.nan, index=column.index)
    try:
        numbers = pd.to_numeric(column, errors="coerce")
    except OverflowError:  # a Python int beyond float: one value at a time
        numbers = column.map(_float_or_nan)
    if column.dtype == object:  # True would be 1.0
        numbers = numbers.where(~column.map(lambda v: isinstance(v, bool | np.bool_)))
    return numbers.astype(float)


def _float_or_nan(value) -> float:
    """A number as float (infinite beyond the float range), NaN for anything else."""
    if isinstance(value, bool | np.bool_):
        return np.nan
    try:
        return float(value)
    except OverflowError:
        return np.inf if value > 0 else -np.inf
    except (TypeError, ValueError):
        return np.nan


def _no_gaps(column: pd.Series, name: str, locate) -> None:
    bad = column.isna().to_numpy()
    if bad.any():
        raise InputError(f"{name} is empty", where=locate(_first_bad(bad)), fix=f"give {name}")


def _svids(column: pd.Series, locate) -> pd.Series:
    numbers = _to_numeric(column)
    lo, hi = _SVIDS
    bad = (numbers.isna() | (numbers % 1 != 0) | (numbers < lo) | (numbers > hi)).to_numpy()
    if bad.any():
        row = _first_bad(bad)
        raise InputError(
            f"svid {_show(column.iloc[row])} is not a satellite number",
            where=locate(row),
            fix="give the satellite's PRN / slot number as a whole number",
        )
    return numbers.astype(np.int64)


def _labels(column: pd.Series, name: str, locate) -> pd.Series:
    bad = column.isna().to_numpy()
    if bad.any():
        raise InputError(f"{name} is empty", where=locate(_first_bad(bad)), fix=f"give {name}")
    return column.astype(str).str.strip()
