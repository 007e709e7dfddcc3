"""Receiver positions: where the phone was at each epoch of a GnssLogger log.

The sky stage needs a position per epoch. It comes either from the log itself or from a
survey:

* :func:`positions` takes it from the ``Fix`` rows of one provider (``gps``, ``flp``, ...) of a
  log read by :func:`~gnss_citygml.gnss.gnsslogger.read_gnsslogger`: the fix nearest in time,
  or interpolated between the fixes around the epoch;
* :func:`read_surveyed_positions` reads a CSV file of manually surveyed positions, one per
  receiver and time span, and :func:`surveyed_positions` gives a receiver's position at given
  times from it.

Both return the same table: ``time_utc``, ``lat``, ``lon`` (deg, WGS84 / ETRS89), ``h``
(m above the ellipsoid; NaN where unknown, for the terrain model to fill in) and
``position_sd`` (m per axis: how far the position may be off; NaN where unknown, for the
estimator's default). A fix's is its accuracy (Android's ``AccuracyMeters``, the radius of 68 %
confidence) over :data:`ACCURACY_PER_SD`; a surveyed position's is the file's ``sd``.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pandas as pd

from gnss_citygml.errors import InputError, MissingColumnError
from gnss_citygml.files.paths import StrPath
from gnss_citygml.gnss.gnsslogger import GnssLog
from gnss_citygml.gnss.gpstime import Times, utc_ns

__all__ = ["ACCURACY_PER_SD", "positions", "read_surveyed_positions", "surveyed_positions"]

#: Android's horizontal accuracy (``AccuracyMeters``) is the radius holding the position with
#: 68 % probability. For an error of standard deviation ``s`` along each axis, the radius holds
#: ``1 - exp(-r^2 / 2 s^2)``, so that radius is ``s * sqrt(-2 ln 0.32)``, 1.51 s.
ACCURACY_PER_SD = float(np.sqrt(-2.0 * np.log(1.0 - 0.68)))


def positions(
    log: GnssLog, *, provider: str = "gps", method: str = "nearest", max_gap: float = 2.0
) -> pd.DataFrame:
    """The receiver position at each epoch of ``log``, from its ``Fix`` rows.

    Parameters
    ----------
    log
        A log from :func:`~gnss_citygml.gnss.gnsslogger.read_gnsslogger`.
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
        where the fix had no altitude), ``position_sd`` (m per axis, the fix's accuracy over
        :data:`ACCURACY_PER_SD`; NaN where the fix had none), one row per epoch in
        :attr:`~gnss_citygml.gnss.gnsslogger.GnssLog.epochs`.

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
    t = utc_ns(epochs)
    lo, hi, weight, ok = _fix_weights(utc_ns(fixes["time_utc"]), t, method, max_gap)
    if not ok.all():
        raise InputError(
            f"{np.count_nonzero(~ok)} of {len(t)} epochs have no {provider!r} fix within "
            f"{max_gap:g} s ({method})",
            where=f"{log.path}, first at {epochs[~ok][0]}",
            fix="raise max_gap, choose another provider or method, or give surveyed positions",
        )
    lat, h = fixes["lat"].to_numpy(), fixes["altitude"].to_numpy()
    sd = fixes["accuracy"].to_numpy(dtype=float) / ACCURACY_PER_SD
    lon = np.degrees(np.unwrap(np.radians(fixes["lon"].to_numpy())))  # no jump at 180 deg
    lon = lon[lo] + weight * (lon[hi] - lon[lo])
    return pd.DataFrame(
        {
            "time_utc": epochs,
            "lat": lat[lo] + weight * (lat[hi] - lat[lo]),
            "lon": (lon + 180.0) % 360.0 - 180.0,
            "h": h[lo] + weight * (h[hi] - h[lo]),
            "position_sd": sd[lo] + weight * (sd[hi] - sd[lo]),
        }
    )


def _fix_weights(fix_ns, t, method: str, max_gap: float):
    """For each epoch ``t`` (ns): the fixes its position is taken from (``lo``, ``hi``), the
    weight of ``hi`` (0 for the nearest fix) and whether a fix is within ``max_gap`` s."""
    # the fixes at or just before and at or just after each epoch (clipped to the ends)
    before = np.searchsorted(fix_ns, t, side="right").clip(1, len(fix_ns)) - 1
    after = np.searchsorted(fix_ns, t, side="left").clip(0, len(fix_ns) - 1)
    d_before, d_after = t - fix_ns[before], fix_ns[after] - t
    nearest = np.where(np.abs(d_after) < np.abs(d_before), after, before)
    ok = np.abs(t - fix_ns[nearest]) <= round(max_gap * 1e9)
    if method == "nearest":
        return nearest, nearest, np.zeros(len(t)), ok
    # before the first or after the last fix: lo == hi, the end fix
    span = (fix_ns[after] - fix_ns[before]).astype(float)
    return before, after, np.divide(d_before, span, out=np.zeros(len(t)), where=span > 0), ok


def read_surveyed_positions(path: StrPath) -> pd.DataFrame:
    """Read a CSV file of manually surveyed receiver positions.

    The file has a header line and one row per receiver and time span::

        receiver,start_utc,end_utc,lat,lon,h
        london_ucl_2020-02-11_SM-G973F_gnss_log,2020-02-11T08:49:00Z,2020-02-11T08:55:00Z,51.524700,-0.134140,
        # lines starting with '#' and blank lines are ignored

    ``receiver`` names a log (its file name without suffix,
    :attr:`~gnss_citygml.gnss.gnsslogger.GnssLog.receiver`).
    ``start_utc`` and ``end_utc`` are ISO 8601 times, UTC unless they carry an offset; the
    span includes both ends (where one span ends as the next one starts, the later span
    wins). ``lat``, ``lon`` are WGS84 / ETRS89 degrees and ``h`` the ellipsoidal height in
    metres, empty when the height should come from the terrain model. An optional column
    ``sd`` says how far the position may be off (m per axis, e.g. 0.5 for a point measured
    on a large-scale map, 0.02 for a surveyed mark); empty (or no column) leaves it to the
    estimator's default. Spans of one receiver must not overlap.

    Parameters
    ----------
    path
        The CSV file.

    Returns
    -------
    pd.DataFrame
        ``receiver``, ``start_utc``, ``end_utc`` (datetime64[ns, UTC]), ``lat``, ``lon``,
        ``h``, ``position_sd`` (the file's ``sd``, NaN where empty), sorted by receiver and
        start; the file name is in ``attrs["path"]``.

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
    table = pd.DataFrame(rows, columns=[*wanted, "position_sd", "line"]).astype(
        {"receiver": str, "lat": float, "lon": float, "h": float, "position_sd": float}
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


def surveyed_positions(surveyed: pd.DataFrame, receiver: str, times: Times) -> pd.DataFrame:
    """The surveyed position of ``receiver`` at each of ``times``.

    Parameters
    ----------
    surveyed
        A table from :func:`read_surveyed_positions`.
    receiver
        The receiver name (e.g. :attr:`~gnss_citygml.gnss.gnsslogger.GnssLog.receiver`).
    times
        Times (datetime64 UTC, e.g. :attr:`~gnss_citygml.gnss.gnsslogger.GnssLog.epochs`).

    Returns
    -------
    pd.DataFrame
        ``time_utc``, ``lat``, ``lon``, ``h`` and ``position_sd`` (NaN where the file left
        them empty), one row per time, in the given order.

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
    ...     "lat": [51.5247], "lon": [-0.1341], "h": [np.nan], "position_sd": [0.5]})
    >>> surveyed_positions(surveyed, "phone", [pd.Timestamp("2020-02-11 08:50", tz="UTC")])
                       time_utc      lat     lon   h  position_sd
    0 2020-02-11 08:50:00+00:00  51.5247 -0.1341 NaN          0.5
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
    # pandas-stubs: pd.to_datetime takes no array-like that is not a list or a pandas object
    times = pd.DatetimeIndex(pd.to_datetime(times, utc=True)).as_unit("ns")  # type: ignore[arg-type]
    t, start, end = utc_ns(times), utc_ns(spans["start_utc"]), utc_ns(spans["end_utc"])
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
            "position_sd": spans["position_sd"].to_numpy()[k],
        }
    )


def _surveyed_row(row: dict[str, str], where: str) -> tuple:
    """One row of a surveyed positions file, checked: (receiver, start, end, lat, lon, h, sd)."""
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
    text = row.get("sd", "").strip()  # an optional column
    sd = _number(text, "sd", where) if text else np.nan
    if sd < 0:
        raise InputError(
            f"sd {sd:g} is negative",
            where=where,
            fix="give the position error in metres, 0 or more",
        )
    return receiver, start, end, lat, lon, h, sd


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
