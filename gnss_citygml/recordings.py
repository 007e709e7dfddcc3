"""Recordings and their time windows: which rows share one receiver position error.

A recording is one ``receiver``'s rows of the observations table. A position error (a point
placed by hand, a phone's fix biased by the street around it) is shared by the rows of a
recording, or, when it drifts, by the rows of one time window of it. Both the modelled position
errors (:func:`gnss_citygml.pipeline.intersections`) and the self-calibrated offsets
(:func:`gnss_citygml.calibrate.calibrate_receivers`) group rows by :func:`recording_windows`.

A recording's windows start at its own first epoch: they cut a recording the same way whichever
other recordings are in the run (adding a second phone's log, or one that started earlier, does
not move this one's windows), and a recording's first window is a whole window long rather than
what remains of a window that began with some other receiver.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from .errors import InputError

__all__ = ["recording_windows"]


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
    utc = pd.to_datetime(rows["time_utc"], utc=True).dt.tz_convert(None)
    ns = utc.astype("datetime64[ns]").astype(np.int64)
    receiver = rows["receiver"].to_numpy()
    since_start = (ns - ns.groupby(receiver).transform("min")).to_numpy()
    slot = since_start // max(round(window * 1e9), 1)
    return pd.factorize(pd.MultiIndex.from_arrays([receiver, slot]))[0].astype(np.intp)
