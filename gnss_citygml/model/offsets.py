"""Each phone's C/N0 offset, learnt from its open sky.

Phones differ: one model's antenna and front end give open signals a few dB-Hz more than
another's, a phone in a pocket loses a few more (issue 27). A threshold or a mixture shared by
every recording blurs the split between open and blocked signals by that spread. The rays that
cross no footprint are open as far as the map knows, and every recording has some: their C/N0
against elevation says how strong each phone receives an open signal. Each phone's offset is
the median of its open signals' C/N0 less the others' at the same elevation (a line in
:func:`~.mixture.elevation_units` fitted to all of them), shrunk towards 0 by its count (a few
signals say little); the offsets are centred, so the common level stays the data's own. A
median, because the open sky of a map holds what the map misses (trees, unmapped buildings).

The open signals are counted in bins (:class:`SkyCounts`: a phone, an elevation, a C/N0), so
that a run in tiles adds its tiles' counts up, and takes those of the signals that cross a
footprint from those of all its signals, in whole numbers: the offsets are then those of a
run in one process, bit for bit.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
import pandas as pd

from ..errors import MissingColumnError
from .mixture import elevation_units

__all__ = ["CN0_BIN", "ELEVATION_BINS", "SkyCounts", "cn0_offsets", "levelled", "sky_counts"]

#: Open signals that weigh as much as the prior offset 0: a phone with this many has half its
#: median's offset. A phone's open C/N0 scatters by a few dB-Hz (fading, body), so 20 signals
#: put its median within about 1 dB-Hz.
PRIOR_SIGNALS = 20.0

#: Alternations of (offsets | line): the line moves little once the offsets are out.
ROUNDS = 3

#: Width of a C/N0 bin (dB-Hz): a tenth of the smallest device offset worth finding (2-3 dB),
#: and at most half of it moves a median.
CN0_BIN = 0.25

#: Elevation bins over 0-90 degrees: one a degree (the line of C/N0 against elevation changes
#: by about 0.1 dB-Hz a degree).
ELEVATION_BINS = 90


@dataclass(frozen=True)
class SkyCounts:
    """Received signals counted by phone (``key``), elevation bin and C/N0 bin: what
    :meth:`offsets` needs. Counts add up and subtract exactly (parts of a run, or a run's
    signals less those that cross a footprint: its open sky)."""

    counts: pd.Series

    @classmethod
    def of(cls, key: npt.ArrayLike, cn0: npt.ArrayLike, e: npt.ArrayLike) -> SkyCounts:
        """The counts of signals of phones ``key`` with C/N0 ``cn0`` (NaN: not received, left
        out) and elevations ``e`` in the mixture's units (:func:`~.mixture.elevation_units`;
        NaN: unknown, left out)."""
        s = np.asarray(cn0, dtype=float)
        e = np.asarray(e, dtype=float)
        code, names = pd.factorize(np.asarray(key, dtype=object))  # each name once
        ok = np.isfinite(s) & np.isfinite(e) & (code >= 0)  # (-1: no phone named)
        bins = pd.DataFrame(
            {
                "key": code[ok],
                "e": np.rint(e[ok] * ELEVATION_BINS).astype(np.int64),
                "cn0": np.rint(s[ok] / CN0_BIN).astype(np.int64),
            }
        )
        counts = bins.value_counts(sort=False).reset_index(name="n")
        named = np.asarray(names, dtype=object).astype(str).astype(object)
        counts["key"] = named[counts["key"].to_numpy()]
        return cls(counts.set_index(["key", "e", "cn0"])["n"].sort_index())

    @classmethod
    def empty(cls) -> SkyCounts:
        """No signals."""
        return cls.of([], [], [])

    def __add__(self, other: SkyCounts) -> SkyCounts:
        """Both sets of signals together."""
        return SkyCounts(_tidy(self.counts.add(other.counts, fill_value=0)))

    def __sub__(self, other: SkyCounts) -> SkyCounts:
        """These signals less ``other``, some of them."""
        return SkyCounts(_tidy(self.counts.sub(other.counts, fill_value=0)))

    def offsets(self) -> pd.Series:
        """Each phone's C/N0 offset (dB-Hz, indexed by ``key``) against the others': subtract
        it from every C/N0 of that phone to put it on the others' level. A phone without
        counts has none (0 when looked up)."""
        counts = self.counts[self.counts > 0]
        key = counts.index.get_level_values("key")
        names, code = pd.Index(key.unique()), key.factorize()[0]
        cn0 = counts.index.get_level_values("cn0").to_numpy() * CN0_BIN
        e = counts.index.get_level_values("e").to_numpy() / ELEVATION_BINS
        offsets = _fitted(cn0, e, counts.to_numpy(dtype=float), code, len(names))
        return pd.Series(offsets, index=names.rename("key"), name="cn0_offset")


def cn0_offsets(open_sky: pd.DataFrame, key: str = "receiver") -> pd.Series:
    """Each phone's C/N0 offset (dB-Hz, one per value of ``key``) against the others'.

    Parameters
    ----------
    open_sky
        The signals whose rays cross no footprint (:func:`gnss_citygml.stages.open_sky`),
        with ``cn0`` (NaN: not received, left out), ``elevation`` (deg; NaN: left out) and
        ``key``.
    key
        The column naming each signal's phone (or recording).

    Returns
    -------
    pandas.Series
        The offset of each phone (indexed by ``key``'s values, as text): subtract it from
        every C/N0 of that phone to put it on the others' level. 0 for a phone without open
        signals.
    """
    offsets = sky_counts(open_sky, key).offsets()
    names = pd.Index(np.unique(open_sky[key].astype(str)), name="key")
    return offsets.reindex(names, fill_value=0.0)


def sky_counts(signals: pd.DataFrame, key: str = "receiver") -> SkyCounts:
    """The :class:`SkyCounts` of a table of signals (``key``, ``cn0``, ``elevation`` in deg)."""
    missing = [c for c in (key, "cn0", "elevation") if c not in signals.columns]
    if missing:
        raise MissingColumnError(missing, where="open-sky signals", have=list(signals.columns))
    cn0 = pd.to_numeric(signals["cn0"], errors="coerce").to_numpy(dtype=float)
    elevation = pd.to_numeric(signals["elevation"], errors="coerce").to_numpy(dtype=float)
    e = np.where(np.isfinite(elevation), elevation_units(elevation), np.nan)
    return SkyCounts.of(signals[key].to_numpy(), cn0, e)


def levelled(signals: pd.DataFrame, offsets: pd.Series, key: str = "receiver") -> pd.DataFrame:
    """``signals`` with each one's ``cn0`` less its phone's offset (0 for a phone without
    one: a received signal never becomes a blocked one; and for a signal of unknown
    ``elevation``, which the counts leave out too)."""
    code, names = pd.factorize(signals[key])  # each name looked up once
    level = offsets.reindex(np.asarray(names, dtype=object).astype(str), fill_value=0.0)
    shift = np.append(level.to_numpy(), 0.0)[code]  # (code -1: no name)
    known = np.isfinite(pd.to_numeric(signals["elevation"], errors="coerce").to_numpy(float))
    out = signals.copy(deep=False)  # the other columns shared, not copied
    out["cn0"] = pd.to_numeric(signals["cn0"], errors="coerce").to_numpy(float) - shift * known
    return out


def _tidy(counts: pd.Series) -> pd.Series:
    return counts[counts != 0].astype(np.int64).sort_index()


def _fitted(
    cn0: npt.NDArray[np.float64],
    e: npt.NDArray[np.float64],
    count: npt.NDArray[np.float64],
    code: np.ndarray,
    n: int,
) -> npt.NDArray[np.float64]:
    """The offsets of ``n`` phones from binned signals: ``count`` signals of phone ``code`` at
    C/N0 ``cn0`` and elevation ``e`` each."""
    offsets = np.zeros(n)
    if count.sum() < 2:
        return offsets
    total = np.bincount(code, count, minlength=n)
    shrink = total / (total + PRIOR_SIGNALS)
    weight = np.sqrt(count)  # polyfit weighs residuals: a bin of k signals counts k times
    for _ in range(ROUNDS):
        y = cn0 - offsets[code]
        line = (
            np.polyfit(e, y, 1, w=weight) if np.ptp(e) > 0 else [0.0, np.average(y, weights=count)]
        )
        median = _weighted_medians(cn0 - np.polyval(line, e), count, code, n)
        offsets = shrink * (median - np.average(median, weights=total))
    return offsets


def _weighted_medians(
    value: np.ndarray, count: np.ndarray, code: np.ndarray, n: int
) -> npt.NDArray[np.float64]:
    """Each group's median of ``value`` repeated ``count`` times (the lower of the two middle
    ones for an even count)."""
    order = np.lexsort((value, code))
    value, count, code = value[order], count[order], code[order]
    below = np.cumsum(count) - count  # signals before each bin, over all groups
    start = np.searchsorted(code, np.arange(n))
    half = (np.bincount(code, count, minlength=n) + 1) // 2  # the middle signal's rank, 1-based
    before_group = below[np.minimum(start, code.size - 1)]
    rank = below - before_group[code] + count  # signals of the group up to this bin
    reached = rank >= half[code]
    first = np.full(n, -1)
    hit = np.flatnonzero(reached)
    first[code[hit[::-1]]] = hit[::-1]  # the first bin reaching the middle of each group
    median = np.zeros(n)
    median[first >= 0] = value[first[first >= 0]]
    return median
