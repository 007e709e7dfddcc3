"""Satellite positions from orbit files: the :class:`Orbits` front and the choice of source.

:func:`load_orbits` reads any mix of files and returns an :class:`Orbits`: SP3 files when there
are any (precise, preferred), otherwise the broadcast ephemerides of the navigation files. Both
kinds answer the same questions, with times given in UTC (converted to GPS time inside):

* :meth:`Orbits.positions` -- ECEF positions of given satellites at given times;
* :meth:`Orbits.positions_all` -- every satellite of the source at a set of epochs, the input of
  the sky stage ("all satellites above the mask").

The files are read and the positions computed in the modules of each kind: :mod:`.sp3` reads
SP3 precise orbits and interpolates them (:class:`Sp3Orbits`); :mod:`.navigation` reads RINEX
navigation files and :mod:`.propagation` propagates their ephemerides
(:class:`BroadcastOrbits`). This module holds what the two sources share (their time span, the
checks of the requested times and of the positions) and what chooses between them.

**Broadcast ephemerides.** For each satellite and time the ephemeris nearest in time (toe, or tb
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

import os
from abc import ABC, abstractmethod
from collections.abc import Iterable
from pathlib import Path
from typing import cast

import numpy as np
import numpy.typing as npt
import pandas as pd

from gnss_citygml.errors import InputError, listing
from gnss_citygml.files.paths import StrPath
from gnss_citygml.gnss.gpstime import (
    GPS_EPOCH,
    NS_PER_S,
    Times,
    gps_seconds,
    gps_to_utc,
    to_datetime64,
    utc_to_gps,
)
from gnss_citygml.gnss.navigation import EPHEMERIS_PARAMETERS, read_nav
from gnss_citygml.gnss.orbitfile import location, read_lines
from gnss_citygml.gnss.propagation import KEPLER_CONSTANTS, glonass_positions, kepler_positions
from gnss_citygml.gnss.sp3 import LAGRANGE_POINTS, MAX_MISSING_EPOCHS, lagrange, read_sp3

__all__ = [
    "MAX_AGE",
    "BroadcastOrbits",
    "OrbitSpanError",
    "Orbits",
    "Sp3Orbits",
    "load_orbits",
]

#: Longest time (s) between a requested time and the ephemeris used, per constellation.
MAX_AGE = {"G": 4 * 3600.0, "J": 2 * 3600.0, "E": 4 * 3600.0, "C": 2 * 3600.0, "R": 1800.0}

#: Distance (m) from the Earth's centre of every GNSS satellite, with a margin: GLONASS at
#: 25,500 km to QZSS's inclined geosynchronous orbits at up to 45,300 km.
_ORBIT_RADIUS = (2.0e7, 5.0e7)


class OrbitSpanError(InputError):
    """Positions were asked for outside the time span the orbit files cover."""


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
    gps = GPS_EPOCH + np.timedelta64(round(t_gps * NS_PER_S), "ns")
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
        utc = gps_to_utc(GPS_EPOCH + (np.array([first, last]) * NS_PER_S).astype("timedelta64[ns]"))
        return pd.Timestamp(utc[0], tz="UTC"), pd.Timestamp(utc[1], tz="UTC")

    def positions(
        self, times_utc: Times, constellation: npt.ArrayLike, svid: npt.ArrayLike
    ) -> np.ndarray:
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
        self,
        times_utc: Times,
        constellations: str | None = None,
        healthy_only: bool = True,
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
            spans = listing((f"{_utc_text(a)} to {_utc_text(b)}" for a, b in cov), 5)
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
        Rows of :func:`~gnss_citygml.gnss.sp3.read_sp3` (one or more files, concatenated).
    paths
        The files the table came from.
    notes
        Remarks to pass on to the user.
    """

    source = "sp3"

    def __init__(self, table: pd.DataFrame, paths: Iterable = (), notes: Iterable[str] = ()):
        t = gps_seconds(table["time_gps"])
        epochs = np.unique(t)
        if epochs.size < LAGRANGE_POINTS:
            raise InputError(
                f"{epochs.size} SP3 epochs: interpolation needs at least {LAGRANGE_POINTS}",
                where=_names(paths),
                fix="give the SP3 files of the whole day (and the neighbouring days)",
            )
        step = np.diff(epochs)
        self.step = float(np.median(step))
        joined = step <= (1 + MAX_MISSING_EPOCHS) * self.step + 1e-6
        coverage = _merge(epochs[:-1][joined], epochs[1:][joined])
        super().__init__(paths, coverage, notes)
        good = table.assign(t=t).dropna(subset=["x", "y", "z"])
        good = good.drop_duplicates(["constellation", "svid", "t"]).sort_values("t")
        self._series = {}
        for (cons, svid), rows in good.groupby(["constellation", "svid"]):
            if len(rows) >= LAGRANGE_POINTS:
                # pandas-stubs types the keys of a groupby as Hashable
                self._series[(cons, int(svid))] = (  # type: ignore[call-overload]
                    rows["t"].to_numpy(),
                    rows[["x", "y", "z"]].to_numpy(),
                )
            else:
                self.notes.append(f"{cons}{svid:02d} left out: fewer than 10 SP3 positions")

    def _satellites(self):
        return self._series.keys()

    def _sat_positions(self, sat, t, healthy_only):
        nodes_t, nodes_xyz = self._series[sat]
        return lagrange(nodes_t, nodes_xyz, t, self.step)


class BroadcastOrbits(Orbits):
    """Positions propagated from broadcast ephemerides (Keplerian, GLONASS Runge-Kutta).

    Parameters
    ----------
    table
        Rows of :func:`~gnss_citygml.gnss.navigation.read_nav` (one or more files, concatenated).
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
        consts = np.array([KEPLER_CONSTANTS.get(c, (np.nan, np.nan)) for c in cons])
        self._eph = {
            c: table[c].to_numpy(dtype=float) for c in table.columns if c in EPHEMERIS_PARAMETERS
        }
        self._eph.update(
            toe=toe,
            age=age,
            healthy=table["healthy"].to_numpy(dtype=bool),
            gm=consts[:, 0],
            omega_e=consts[:, 1],
            geo=(cons == "C") & ((table["svid"] <= 5) | (table["svid"] >= 59)).to_numpy(),
        )
        # pandas-stubs types the keys of a groupby as Hashable
        groups = cast(
            dict[tuple[str, int], pd.Index], table.groupby(["constellation", "svid"]).groups
        )
        self._rows = {(c, int(s)): rows.to_numpy() for (c, s), rows in groups.items()}

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
        out[ok] = glonass_positions(eph, tk) if sat[0] == "R" else kepler_positions(eph, tk)
        return out


def _kind(path: Path) -> str:
    first = read_lines(path, first_only=True)
    if first[:2] in ("#c", "#d"):
        return "sp3"
    if "RINEX VERSION / TYPE" in first:
        return "nav"
    raise InputError(
        "neither an SP3 orbit file nor a RINEX navigation file",
        where=location(path, 1),
        fix="give SP3-c/d (*.sp3, *_ORB.SP3) or RINEX navigation (*.YYn, *_MN.rnx) files",
    )


def load_orbits(paths: StrPath | Iterable[StrPath]) -> Orbits:
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
    files = [Path(paths)] if isinstance(paths, str | os.PathLike) else [Path(p) for p in paths]
    if not files:
        raise InputError("no orbit files given", fix="give SP3 or RINEX navigation files")
    kinds = {p: _kind(p) for p in files}
    sp3 = [p for p in files if kinds[p] == "sp3"]
    nav = [p for p in files if kinds[p] == "nav"]
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
