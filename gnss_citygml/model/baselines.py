"""The paper's comparison methods, each with the same initial C/N0 classifier as 4PL-B.

* ``4PL``: one pass of 4PL-B without bootstrapping (see :func:`.estimate.fourplb`).
* ``hinge``: after Weissman et al. (2013), the height ``H`` minimising the summed hinge loss of
  the signals the height misclassifies: open signals crossing below ``H`` cost ``H - h``,
  closed signals crossing above it cost ``h - H``.
* ``bayes``: after Irish et al. (2014), applied to a building's whole dataset rather than to
  voxels: the height maximising ``sum_{h <= H} log(1 - p) + sum_{h > H} log p``, where ``p`` is
  the classifier's probability that the signal is open.

Both are exact: the objective is evaluated at every candidate height with cumulative sums over
the signals sorted by building and height, so a city costs one sort. Where the optimum is a
flat interval, the middle of the interval is returned.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from .classifier import SignalClassifier

__all__ = ["bayes_heights", "hinge_heights"]

#: Probability that the sensor model gives a received-or-blocked signal its less likely class
#: at least: a blocked signal is taken as open with this probability (the paper's classifier
#: returns 0, which would make a single blocked signal above the roof veto a height).
BAYES_FLOOR = 0.01


def hinge_heights(
    groups: npt.ArrayLike,
    height: npt.ArrayLike,
    cn0: npt.ArrayLike,
    n_groups: int,
    *,
    init_threshold: float = 30.0,
) -> np.ndarray:
    """Weissman's hinge-loss height of every building (NaN where a building has no rows)."""
    is_open = SignalClassifier.initial(init_threshold).label(cn0)
    order, gs, hs, starts, ends = _sorted(groups, height, n_groups)
    op = is_open[order].astype(float)
    cl = 1.0 - op
    # f(H = h_i) = H * O_below - S_open_below + S_closed_above - H * C_above, inclusive sums
    # are fine because a signal at exactly H costs nothing.
    o_below, so_below = _segment_cumsum(op, gs, starts), _segment_cumsum(op * hs, gs, starts)
    c_upto, sc_upto = _segment_cumsum(cl, gs, starts), _segment_cumsum(cl * hs, gs, starts)
    c_tot, sc_tot = _segment_total(cl, starts, ends), _segment_total(cl * hs, starts, ends)
    c_above = c_tot[gs] - c_upto
    sc_above = sc_tot[gs] - sc_upto
    cost = hs * o_below - so_below + sc_above - hs * c_above
    return _arg_best(cost, hs, gs, n_groups, span_to_next=False)


def bayes_heights(
    groups: npt.ArrayLike,
    height: npt.ArrayLike,
    cn0: npt.ArrayLike,
    n_groups: int,
    *,
    init_threshold: float = 30.0,
    floor: float = BAYES_FLOOR,
) -> np.ndarray:
    """The maximum-likelihood height of every building under the C/N0 sensor model."""
    p = np.clip(SignalClassifier.initial(init_threshold).prob(cn0), floor, 1.0 - floor)
    order, gs, hs, starts, ends = _sorted(groups, height, n_groups)
    log_closed, log_open = np.log1p(-p[order]), np.log(p[order])
    # Candidate H just above sorted height i: rows up to i are closed, the rest open.
    closed_upto = _segment_cumsum(log_closed, gs, starts)
    open_upto = _segment_cumsum(log_open, gs, starts)
    open_tot = _segment_total(log_open, starts, ends)
    loglik = closed_upto + open_tot[gs] - open_upto
    result = _arg_best(-loglik, hs, gs, n_groups, span_to_next=True)
    # The remaining candidate, H below every row (all open), wins only outright.
    best = np.full(n_groups, -np.inf)
    np.maximum.at(best, gs, loglik)
    lowest = np.full(n_groups, np.nan)
    has = ends > starts
    lowest[has] = hs[starts[has]]
    return np.where(has & (open_tot > best), lowest, result)


def _sorted(groups, height, n_groups):
    groups = np.asarray(groups, dtype=np.intp)
    height = np.asarray(height, dtype=float)
    order = np.lexsort((height, groups))
    gs, hs = groups[order], height[order]
    starts = np.searchsorted(gs, np.arange(n_groups))
    ends = np.searchsorted(gs, np.arange(n_groups), side="right")
    return order, gs, hs, starts, ends


def _segment_cumsum(values, gs, starts):
    """Inclusive cumulative sum of ``values`` within each group of the sorted rows."""
    total = np.cumsum(values)
    before = np.concatenate([[0.0], total])[starts]
    return total - before[gs]


def _segment_total(values, starts, ends):
    padded = np.concatenate([[0.0], np.cumsum(values)])
    return padded[ends] - padded[starts]


def _arg_best(cost, hs, gs, n_groups, *, span_to_next):
    """Per group, the middle of the span of heights where ``cost`` is minimal.

    When the minimum is reached at sorted rows ``i..j``, the span is ``hs[i]..hs[j]`` if
    ``cost[k]`` is the objective at ``H = hs[k]`` (``span_to_next=False``), and
    ``hs[i]..hs[j + 1]`` if it is the objective just above ``hs[k]`` (``span_to_next=True``).
    """
    out = np.full(n_groups, np.nan)
    if cost.size == 0:
        return out
    best = np.full(n_groups, np.inf)
    np.minimum.at(best, gs, cost)
    tol = 1e-9 * (1.0 + np.abs(best))
    hit = cost <= (best + tol)[gs]
    idx = np.arange(cost.size)
    first = np.full(n_groups, cost.size)
    last = np.full(n_groups, -1)
    np.minimum.at(first, gs[hit], idx[hit])
    np.maximum.at(last, gs[hit], idx[hit])
    has = last >= 0
    end_of_group = np.searchsorted(gs, np.arange(n_groups), side="right") - 1
    upper_idx = np.minimum(last + 1, end_of_group) if span_to_next else last
    out[has] = 0.5 * (hs[first[has]] + hs[upper_idx[has]])
    return out
