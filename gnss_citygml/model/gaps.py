"""The empty stretches of a fit's samples around its inflection point (:mod:`.fourpl`'s gap
rule): where a gap is wider than the transition as the samples see it, the likelihood hardly
depends on ``c`` inside it."""

from __future__ import annotations

import numpy as np

__all__ = ["blurred_slope", "gap_around"]


def blurred_slope(log_b: np.ndarray, w: np.ndarray, g: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Each group's slope as its samples see it, blurred by their errors in x (their mean
    variance ``v``; the probit approximation of :mod:`.fourpl`): a gap is flat for
    ``c`` only where it is wider than this transition, not only than the curve's own."""
    n = log_b.size
    with np.errstate(invalid="ignore", divide="ignore"):
        var = np.nan_to_num(np.bincount(g, w * v, n) / np.bincount(g, w, n))
    b = np.exp(log_b)
    return b / np.sqrt(1.0 + np.pi * b * b * var / 8.0)


def gap_around(
    x: np.ndarray, w: np.ndarray, g: np.ndarray, c: np.ndarray, groups: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The empty stretch of x around each of ``groups``' ``c`` (a mask): the largest sample at
    or below it and the smallest above it, samples of weight 0 left out (-inf, inf where
    there is none; NaN for the other groups)."""
    lower = np.full(c.size, -np.inf)
    upper = np.full(c.size, np.inf)
    rows = (w > 0) & groups[g]
    xr, gr = x[rows], g[rows]
    under = xr <= c[gr]
    np.maximum.at(lower, gr[under], xr[under])
    np.minimum.at(upper, gr[~under], xr[~under])
    lower[~groups] = upper[~groups] = np.nan
    return lower, upper
