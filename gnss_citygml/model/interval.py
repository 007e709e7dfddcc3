"""The likelihood-ratio interval of a 4PL fit's inflection point ``c``: how far the data leave
the roof line open (:func:`c_interval`)."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from .fourpl import LR_DROP, FourPLFit, _Samples, _samples, _to_theta
from .group_threads import by_groups
from .likelihood import evaluate

__all__ = ["c_interval"]


def c_interval(
    fit: FourPLFit,
    x: npt.ArrayLike,
    y: npt.ArrayLike,
    groups: npt.ArrayLike,
    *,
    weights: npt.ArrayLike | None = None,
    sd: npt.ArrayLike | None = None,
    reach: float = 12.0,
    drop: float = LR_DROP,
) -> tuple[np.ndarray, np.ndarray]:
    """Likelihood-ratio interval of each group's inflection point ``c``, the other parameters
    held at their fit: the ``c`` whose log-likelihood is within ``drop`` of the fit's.

    A fit says where its data put the transition only as far as the data reach: samples on
    one side of a gap in ``x`` (a building seen at a few heights by a few satellites) are fitted
    as well by any ``c`` in the gap, and a separable fit (``b`` on its bound) chooses one at
    random. The interval spans that gap. ``c`` is tried on a grid of offsets out to ``reach``
    (finer near the fit); an end that is still within ``drop`` at ``reach`` is returned there,
    so an interval as wide as the grid means "at least that wide". ``weights`` say how much
    each sample counts as evidence (4PL-B counts each look once: samples that repeat one
    another are not independent, and counted one by one they make the interval too narrow).

    Returns
    -------
    (numpy.ndarray, numpy.ndarray)
        Lower and upper ends per group (NaN for a group without a fit).
    """
    x, y, w, g, v, n_groups = _samples(x, y, weights, groups, fit.c.size, sd)
    theta = np.nan_to_num(_to_theta(fit.params))
    steps = _offsets(reach)

    def interval(rows: slice, own: slice) -> tuple[np.ndarray, ...]:
        samples = (x[rows], y[rows], w[rows], g[rows] - own.start, v[rows])
        return _c_ends(theta[own], fit.c[own], samples, steps, drop)

    lower, upper = by_groups(g, n_groups, interval)
    return lower, upper


def _c_ends(theta, c, samples: _Samples, steps, drop) -> tuple[np.ndarray, np.ndarray]:
    """:func:`c_interval`'s ends of the groups of sorted ``samples`` (x, y, w, g, v), their
    parameters ``theta`` and inflection points ``c``, trying the offsets ``steps``."""
    n_groups = c.size
    everyone = np.ones(n_groups, dtype=bool)
    best = evaluate(theta, *samples, n_groups, everyone, ll_only=True)[0]
    lower, upper = c.copy(), c.copy()
    for sign, end in ((-1.0, lower), (1.0, upper)):
        for step in steps:
            shifted = theta.copy()
            shifted[:, 2] += sign * step
            ll = evaluate(shifted, *samples, n_groups, everyone, ll_only=True)[0]
            inside = ll >= best - drop
            end[inside] = c[inside] + sign * step
    return lower, upper


def _offsets(reach: float) -> np.ndarray:
    """The offsets of ``c`` that :func:`c_interval` tries, out to ``reach``: 0.1 m steps to
    1 m, 0.25 m to 3 m, 0.5 m to 12 m (beyond a converged range's 10 m), then 5 % longer each,
    so that a long reach costs a few dozen passes over the data, not thousands."""
    fine = np.r_[np.arange(0.1, 1.0, 0.1), np.arange(1.0, 3.0, 0.25), np.arange(3.0, 12.01, 0.5)]
    n_far = int(np.ceil(np.log(max(reach, 12.0) / 12.0) / np.log(1.05)))
    steps = np.r_[fine, 12.0 * 1.05 ** np.arange(1, n_far + 1)]
    return np.r_[steps[steps < reach], reach]
