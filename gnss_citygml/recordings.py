"""Recordings, their stretches and time windows: which rows share one receiver position error.

A recording is one ``receiver``'s rows of the observations table. A position error (a point
placed by hand, a phone's fix biased by the street around it) is shared by the rows of a
stay at one point, of one stretch of a moving recording, or of one time window of it. The
self-calibrated offsets (:func:`gnss_citygml.calibrate.calibrate_receivers`) group rows by
:func:`recording_windows`; the modelled position errors
(:func:`gnss_citygml.pipeline.intersections`) by :func:`position_groups`, which tells a receiver
standing still from one moving from the data.

A recording's windows start at its own first epoch: they cut a recording the same way whichever
other recordings are in the run (adding a second phone's log, or one that started earlier, does
not move this one's windows), and a recording's first window is a whole window long rather than
what remains of a window that began with some other receiver.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from .errors import InputError

__all__ = ["STILL", "position_groups", "recording_windows", "window_walks"]

#: Seconds a receiver's reported position must stay exactly the same for it to be standing at
#: one point (placed by hand, surveyed): a phone's own fixes move a little every epoch.
STILL = 30.0


def recording_windows(rows: pd.DataFrame, window: float | None = None) -> np.ndarray:
    """Which recording, or window of a recording, each row belongs to.

    Parameters
    ----------
    rows
        A table with ``receiver`` (and ``time_utc`` with ``window``), e.g. the observations.
    window
        Seconds: rows of one receiver within one window of this length, counted from that
        receiver's first epoch, share a code. ``None``: a whole recording shares one.

    Returns
    -------
    numpy.ndarray
        One code (intp) per row, ``0 .. n - 1`` in order of first appearance.

    Examples
    --------
    >>> t = pd.to_datetime(["2020-01-01T10:00:00", "2020-01-01T10:00:40", "2020-01-01T10:00:20"])
    >>> rows = pd.DataFrame({"receiver": ["a", "a", "b"], "time_utc": t})
    >>> recording_windows(rows, 30.0)
    array([0, 1, 2])
    >>> recording_windows(rows)
    array([0, 0, 1])
    """
    if window is None:
        return pd.factorize(rows["receiver"])[0].astype(np.intp)
    if "time_utc" not in rows.columns:
        raise InputError(
            "a time window of each recording needs the observations' time_utc",
            fix="give every observation its time, or leave out the window",
        )
    ns = _nanoseconds(rows).to_numpy()
    receiver = pd.factorize(rows["receiver"])[0]
    start = np.full(receiver.max(initial=-1) + 1, np.iinfo(np.int64).max)
    np.minimum.at(start, receiver, ns)
    slot = (ns - start[receiver]) // max(round(window * 1e9), 1)
    # one int64 key per (receiver, slot): both codes are below the number of rows
    return pd.factorize(receiver * (int(slot.max(initial=0)) + 1) + slot)[0].astype(np.intp)


def window_walks(rows: pd.DataFrame, unit: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per window of :func:`recording_windows` (``unit``, one code a row): its recording (a
    number) and its rows' mean time (s from the first row's, whatever their time zone), the
    walks along which :func:`~gnss_citygml.calibrate.walks.walk_offsets` carries shifts."""
    n_units = int(unit.max(initial=-1)) + 1
    ns = _nanoseconds(rows).to_numpy()
    seconds = (ns - (ns.min() if ns.size else 0)) / 1e9
    recording = np.zeros(n_units, dtype=np.intp)
    recording[unit] = pd.factorize(rows["receiver"])[0]
    count = np.maximum(np.bincount(unit, minlength=n_units), 1)
    return recording, np.bincount(unit, seconds, minlength=n_units) / count


def position_groups(
    rows: pd.DataFrame, window: float | None = None, distance: float | None = None
) -> np.ndarray:
    """Which rows share one position error: a stay at one point, or a stretch of a recording.

    A receiver whose reported position (``e``, ``n``) stays exactly the same for at least
    :data:`STILL` seconds is standing at a point placed by hand or surveyed: that point's one
    error lasts as long as the stay, and the next point placed has its own. The other rows of
    a recording (a walker's traced path, a phone's fixes, which move a little every epoch even
    on a phone lying still) share one error while the reported position stays within
    ``distance`` metres of where that error began (a walker's next stretch of street has its
    own; a phone lying still keeps one), or one per ``window`` seconds of the recording
    (:func:`recording_windows`), or, with neither, one over the whole recording.

    Parameters
    ----------
    rows
        A table with ``receiver``, ``time_utc``, ``e`` and ``n`` (m), e.g. the receivers.
    window
        Seconds one error of a moving receiver lasts (it wins over ``distance``).
    distance
        Metres a moving receiver goes with one error.

    Returns
    -------
    numpy.ndarray
        One code (intp) per row, ``0 .. n - 1`` in order of first appearance.

    Examples
    --------
    >>> t = pd.to_datetime([f"2020-01-01T10:00:{s:02d}" for s in (0, 20, 40, 0, 20, 40)])
    >>> rows = pd.DataFrame({"receiver": ["still"] * 3 + ["walker"] * 3, "time_utc": t,
    ...                      "e": [5.0, 5.0, 5.0, 0.0, 30.0, 60.0], "n": 0.0})
    >>> position_groups(rows)
    array([0, 0, 0, 1, 1, 1])
    >>> position_groups(rows, 30.0)
    array([0, 0, 0, 1, 1, 2])
    >>> position_groups(rows, distance=50.0)
    array([0, 0, 0, 1, 1, 2])
    """
    if "time_utc" not in rows.columns:
        raise InputError(
            "the receivers' position errors need the observations' time_utc (which rows share "
            "one error)",
            fix="give every observation its time, or take the positions as exact (--position-sd 0)",
        )
    t = _nanoseconds(rows).to_numpy()
    receiver = pd.factorize(rows["receiver"])[0]
    e, n = rows["e"].to_numpy(dtype=float), rows["n"].to_numpy(dtype=float)
    by_time = np.lexsort((t, receiver))
    r, e, n, t = receiver[by_time], e[by_time], n[by_time], t[by_time]
    if window is None and distance is not None:
        moving = _stretches(r, e, n, distance)
    else:
        moving = recording_windows(rows, window)[by_time]
    moved = np.r_[True, (r[1:] != r[:-1]) | (e[1:] != e[:-1]) | (n[1:] != n[:-1])]
    stay = np.cumsum(moved) - 1
    first = np.flatnonzero(moved)
    last = np.r_[first[1:], r.size] - 1
    still = (t[last] - t[first] >= round(STILL * 1e9))[stay]
    key = np.empty(r.size, dtype=np.int64)
    key[by_time] = np.where(still, stay, -1 - moving)
    return pd.factorize(key)[0].astype(np.intp)


#: Rows looked ahead at once by :func:`_stretches`.
_AHEAD = 1024


def _stretches(r: np.ndarray, e: np.ndarray, n: np.ndarray, distance: float) -> np.ndarray:
    """Each row's stretch (rows sorted by receiver ``r``, then time): a stretch begins at a
    receiver's first row, and again at the first row more than ``distance`` from where the
    stretch began. One step of Python per stretch, the rows looked at in blocks; a position
    unknown (NaN) is never far."""
    begins = np.zeros(r.size, dtype=bool)
    i = 0
    while i < r.size:
        begins[i] = True
        j = i + 1
        while j < r.size:
            end = min(j + _AHEAD, r.size)
            far = (r[j:end] != r[i]) | (np.hypot(e[j:end] - e[i], n[j:end] - n[i]) > distance)
            if far.any():
                j += int(np.argmax(far))
                break
            j = end
        i = j
    return np.cumsum(begins) - 1


def _nanoseconds(rows: pd.DataFrame) -> pd.Series:
    """Each row's ``time_utc`` as nanoseconds since 1970 (int64), whatever its time zone."""
    utc = pd.to_datetime(rows["time_utc"], utc=True).dt.tz_convert(None)
    return utc.astype("datetime64[ns]").astype(np.int64)
