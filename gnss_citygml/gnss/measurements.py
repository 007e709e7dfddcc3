"""What the fields of GnssLogger's records mean: epoch times, signals, and which rows are kept.

:func:`~gnss_citygml.gnss.gnsslogger.read_gnsslogger` gets the records of a log as typed
columns (:mod:`.logrecords`); this module turns them into the rows of
:class:`~gnss_citygml.gnss.gnsslogger.GnssLog`: one per received signal (``Raw``), fix
(``Fix``) and satellite status (``Status``), following these rules.

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
frequency is in no GNSS band. Dropped rows are kept in
:attr:`~gnss_citygml.gnss.gnsslogger.GnssLog.dropped` with a ``reason``, for counting and
inspection.

**Signals.** ``constellation`` is the RINEX letter (G GPS, R GLONASS, E Galileo, C BeiDou,
J QZSS, S SBAS, I NavIC); ``svid`` the RINEX satellite number (QZSS ``Svid`` 193-202 becomes
1-10, SBAS 120-158 becomes 20-58). ``band`` comes from ``CarrierFrequencyHz`` with RINEX band
numbers: ``L1`` (1559-1610 MHz: GPS/QZSS L1, Galileo E1, BeiDou B1, GLONASS G1), ``L5``
(1164-1189 MHz: GPS L5, Galileo E5a, BeiDou B2a), ``L2``, ``L6``, ``L7`` (E5b/B2I/G3); no
frequency (logs before dual-frequency phones) means ``L1``.
"""

from __future__ import annotations

import re

import numpy as np
import pandas as pd

from gnss_citygml.gnss.gpstime import GPS_EPOCH, NAT_NS, gps_to_utc
from gnss_citygml.gnss.logrecords import INT_PATTERN

__all__ = ["cut_line_epoch", "fix_table", "raw_signals", "status_table"]

#: Android's raw GNSS measurements began in 2016: an epoch outside these dates is a wrong
#: clock field.
_EARLIEST, _LATEST = "2015-07-01", "2100-01-01"
_EARLIEST_GPS_NS, _LATEST_GPS_NS = (
    int((np.datetime64(day, "ns") - GPS_EPOCH) / np.timedelta64(1, "ns"))
    for day in (_EARLIEST, _LATEST)
)
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


def raw_signals(
    table: pd.DataFrame, numbers: np.ndarray
) -> tuple[pd.DataFrame, list[tuple[int, str]]]:
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
    utc_ns = np.full(time_nanos.shape, NAT_NS, dtype=np.int64)
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


def cut_line_epoch(text: str, names: list[str]) -> int | None:
    """The epoch (int64 UTC ns) of a cut-off Raw line, when its clock fields are complete."""
    fields = text.rstrip("\r").split(",")[:-1]  # the last field may be cut short
    values = {}
    for name in ("TimeNanos", "FullBiasNanos", "BiasNanos"):
        k = names.index(name) + 1 if name in names else len(fields)
        values[name] = fields[k].strip() if k < len(fields) else ""
    if not all(re.fullmatch(INT_PATTERN, values[name]) for name in ("TimeNanos", "FullBiasNanos")):
        return None
    bias = pd.to_numeric(values["BiasNanos"], errors="coerce") if values["BiasNanos"] else 0.0
    gps_ns = int(values["TimeNanos"]) - int(values["FullBiasNanos"]) - round(np.nan_to_num(bias))
    if not _EARLIEST_GPS_NS <= gps_ns < _LATEST_GPS_NS:
        return None
    return int(gps_to_utc(np.array([gps_ns]))[0].astype(np.int64))


def _utc(ns: np.ndarray) -> pd.DatetimeIndex:
    """int64 ns since 1970 (``NAT_NS`` for none) -> datetime64[ns, UTC]."""
    return pd.DatetimeIndex(ns.astype("datetime64[ns]")).tz_localize("UTC")


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


def fix_table(table: pd.DataFrame) -> pd.DataFrame:
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


def status_table(table: pd.DataFrame) -> pd.DataFrame:
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
