"""Each recording's C/N0 offset, learnt from its open sky.

Phones differ: one model's antenna and front end give open signals a few dB-Hz more than
another's, a phone in a pocket loses a few more (issue 27). A threshold or a mixture shared by
every recording blurs the split between open and blocked signals by that spread. The rays that
cross no footprint are open as far as the map knows, and every recording has some: their C/N0
against elevation says how strong each phone receives an open signal. Each recording's offset is
the median of its open signals' C/N0 less the others' at the same elevation (a line in
:func:`~.mixture.elevation_units` fitted to all of them), shrunk towards 0 by its count (a few
signals say little); the offsets are centred, so the common level stays the data's own. A
median, because the open sky of a map holds what the map misses (trees, unmapped buildings).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
import pandas as pd

from ..errors import MissingColumnError
from .mixture import elevation_units

__all__ = ["cn0_offsets"]

#: Open signals that weigh as much as the prior offset 0: a recording with this many has half
#: its median's offset. A phone's open C/N0 scatters by a few dB-Hz (fading, body), so 20
#: signals put its median within about 1 dB-Hz.
PRIOR_SIGNALS = 20.0

#: Alternations of (offsets | line): the line moves little once the offsets are out.
ROUNDS = 3


def cn0_offsets(open_sky: pd.DataFrame, key: str = "receiver") -> pd.Series:
    """Each recording's C/N0 offset (dB-Hz, one per value of ``key``) against the others'.

    Parameters
    ----------
    open_sky
        The signals whose rays cross no footprint (:func:`gnss_citygml.pipeline.open_sky`),
        with ``cn0`` (NaN: not received, left out), ``elevation`` (deg) and ``key``.
    key
        The column naming each signal's recording.

    Returns
    -------
    pandas.Series
        The offset of each recording (indexed by ``key``'s values): subtract it from every
        C/N0 of that recording to put it on the others' level. 0 for a recording without open
        signals.
    """
    missing = [c for c in (key, "cn0", "elevation") if c not in open_sky.columns]
    if missing:
        raise MissingColumnError(missing, where="open-sky signals", have=list(open_sky.columns))
    names, code = _codes(open_sky[key])
    cn0 = pd.to_numeric(open_sky["cn0"], errors="coerce").to_numpy(dtype=float)
    elevation = pd.to_numeric(open_sky["elevation"], errors="coerce").to_numpy(dtype=float)
    ok = np.isfinite(cn0) & np.isfinite(elevation)  # an unknown elevation is left out, not 0
    offsets = _fitted(cn0[ok], elevation_units(elevation[ok]), code[ok], len(names))
    return pd.Series(offsets, index=names, name="cn0_offset")


def _codes(values: pd.Series) -> tuple[pd.Index, np.ndarray]:
    code, names = pd.factorize(values, sort=True)
    return pd.Index(names, name=values.name), code


def _fitted(
    cn0: npt.NDArray[np.float64], e: npt.NDArray[np.float64], code: np.ndarray, n: int
) -> npt.NDArray[np.float64]:
    offsets = np.zeros(n)
    if cn0.size < 2:
        return offsets
    count = np.bincount(code, minlength=n).astype(float)
    shrink = count / (count + PRIOR_SIGNALS)
    for _ in range(ROUNDS):
        line = np.polyfit(e, cn0 - offsets[code], 1) if np.ptp(e) > 0 else [0.0, cn0.mean()]
        residual = cn0 - np.polyval(line, e)
        median = np.zeros(n)
        by = pd.Series(residual).groupby(code).median()
        median[by.index.to_numpy()] = by.to_numpy()
        offsets = shrink * (median - np.average(median, weights=count))
    return offsets
