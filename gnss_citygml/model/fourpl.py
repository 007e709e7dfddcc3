"""The four-parameter logistic (4PL) curve, its Bernoulli likelihood and a batched MLE fit.

The 4PL is ``Pr(x) = d + (a - d) / (1 + exp(-b (x - c)))`` with ``0 <= d < a <= 1`` and
``b > 0``: ``a`` and ``d`` are the upper and lower asymptotes, ``c`` the inflection point and
``b`` the slope there. 4PL-B uses it twice: as the map classifier of one building (``x`` is the
intersection height) and as the signal classifier of one device (``x`` is C/N0).

:func:`fit_4pl` fits many independent curves at once (one per *group*, e.g. one per building)
with a damped Fisher-scoring (Levenberg-Marquardt) iteration whose per-group sums are batched
(:mod:`.likelihood`), so a city of buildings costs a few passes over the signals instead of one
optimiser call per building; runs of whole groups are fitted in threads
(:mod:`.group_threads`), each group to the same bits whatever groups surround it. The
constraints are built into the parametrisation

``a = sigmoid(alpha)``, ``d = a * sigmoid(delta)``, ``b = exp(beta)``,

and the unconstrained parameters are kept in a box so that separable data (``b -> inf``,
``a -> 1``, ``d -> 0``) and one-class data end on a finite boundary instead of diverging.

Errors in ``x``: when each sample's ``x`` is known only to a Gaussian standard deviation
``sd`` (an intersection height from a receiver position a metre off), the curve a sample
follows is the 4PL convolved with that error. With the probit approximation of the
logistic-Gaussian integral (MacKay 1992) this is the same 4PL with the slope shrunk per sample,
``b kappa`` with ``kappa = 1 / sqrt(1 + pi b^2 sd^2 / 8)``, so that ``b`` is the slope of the
transition itself and the samples with precise ``x`` pin ``c`` and ``b`` more than the others.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, fields, replace
from typing import cast

import numpy as np
import numpy.typing as npt
import pandas as pd
from scipy.special import expit

from .fit_stops import FitStops, Trace
from .gaps import blurred_slope, gap_around
from .group_threads import by_groups
from .likelihood import EPS, evaluate

__all__ = [
    "B_BOUNDS",
    "FitStops",
    "GAP_AFTER",
    "X_TOL",
    "FourPLFit",
    "fit_4pl",
    "log_likelihood",
    "logistic4",
]

#: Default bounds of the slope b (1/unit of x): the upper bound is where separable data stop
#: (a transition 3/b = 3 cm wide for heights in metres), the lower where a curve is flat.
B_BOUNDS = (1e-3, 1e2)
#: Box for the logits of ``a`` and ``d / a``: a in [1.2e-4, 0.99988].
_LOGIT_BOUND = 9.0
#: Log-likelihood drop of a 95 % likelihood-ratio interval of one parameter: chi2(1, 0.95) / 2.
LR_DROP = 1.92
#: A fit has converged when its last step gained at most the tolerance (relative) *and* moved
#: ``c`` by at most this (in units of x: a millimetre of height, a thousandth of a dB-Hz): what
#: is reported has stopped, not only the likelihood, which is nearly flat along a ``c`` that the
#: data leave free.
X_TOL = 1e-3
#: Iterations between the checks of whether a fit's ``c`` lies in a gap of its samples wider
#: than its transition (3/b): one that has converged there, or that is still there at the next
#: check, has ``c`` fixed at the gap's middle and ``b`` at its upper bound. There the
#: likelihood depends on ``c`` only through the curve's tails, and ``c`` creeps for hundreds of
#: iterations to wherever an iteration cap stops it (and ``b`` up, sharpening the step).
GAP_AFTER = 5


#: A 4PL parameter: one value, or one per sample.
_Param = float | np.ndarray


def logistic4(x: npt.ArrayLike, a: _Param, b: _Param, c: _Param, d: _Param) -> np.ndarray:
    """The 4PL curve ``d + (a - d) / (1 + exp(-b (x - c)))``.

    Examples
    --------
    >>> float(logistic4(30.0, 0.9, 0.2, 30.0, 0.1))
    0.5
    """
    return d + (a - d) * expit(b * (np.asarray(x, dtype=float) - c))


def log_likelihood(
    params: Iterable[float],
    x: npt.ArrayLike,
    y: npt.ArrayLike,
    weights: npt.ArrayLike | None = None,
) -> tuple[float, np.ndarray]:
    """Bernoulli log-likelihood of labels ``y`` (0/1 or fractions) under a 4PL and its gradient.

    Parameters
    ----------
    params
        ``(a, b, c, d)``.
    x, y
        Independent variable and labels (a fraction ``k/n`` with weight ``n`` stands for ``n``
        labels of which ``k`` are 1).
    weights
        Sample weights (default 1).

    Returns
    -------
    (float, numpy.ndarray)
        The log-likelihood and its gradient with respect to ``(a, b, c, d)``.
    """
    a, b, c, d = (float(v) for v in params)
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    w = np.ones_like(x) if weights is None else np.asarray(weights, dtype=float)
    s = expit(b * (x - c))
    p = np.clip(d + (a - d) * s, EPS, 1 - EPS)
    ll = float(np.sum(w * (y * np.log(p) + (1 - y) * np.log1p(-p))))
    r = w * (y - p) / (p * (1 - p))
    ds = s * (1 - s)
    grad = np.array(
        [
            np.sum(r * s),
            np.sum(r * (a - d) * ds * (x - c)),
            np.sum(r * -(a - d) * ds * b),
            np.sum(r * (1 - s)),
        ]
    )
    return ll, grad


@dataclass(frozen=True)
class FourPLFit:
    """Result of :func:`fit_4pl`: one entry per group (arrays of length ``n_groups``)."""

    a: np.ndarray
    b: np.ndarray
    c: np.ndarray
    d: np.ndarray
    loglik: np.ndarray
    converged: np.ndarray
    n_iter: np.ndarray
    #: True where ``b`` ended on its upper bound (the data are separable at the fitted c).
    separable: np.ndarray
    #: The empty stretch of x (no sample) in whose middle ``c`` was fixed, the data leaving it
    #: free there (:data:`GAP_AFTER`); NaN where ``c`` was fitted. An end beyond the samples
    #: is infinite (``c`` is then fixed at its box's end).
    gap_lower: np.ndarray
    gap_upper: np.ndarray
    #: How each fit stopped (:class:`FitStops`), where :func:`fit_4pl` was asked (``stops``).
    stops: FitStops | None = None

    @property
    def params(self) -> np.ndarray:
        """The parameters as an ``(n_groups, 4)`` array of ``(a, b, c, d)``."""
        return np.column_stack([self.a, self.b, self.c, self.d])

    def where(self, mask: np.ndarray, other: FourPLFit) -> FourPLFit:
        """This fit with the groups of ``mask`` taken from ``other`` (how they stopped
        left as this fit's)."""
        kept = {
            f.name: np.where(mask, getattr(other, f.name), getattr(self, f.name))
            for f in fields(self)
            if f.name != "stops"
        }
        return replace(self, **kept)


def fit_4pl(
    x: npt.ArrayLike,
    y: npt.ArrayLike,
    weights: npt.ArrayLike | None = None,
    groups: npt.ArrayLike | None = None,
    n_groups: int | None = None,
    *,
    init: npt.ArrayLike | None = None,
    sd: npt.ArrayLike | None = None,
    b_bounds: tuple[float, float] = B_BOUNDS,
    max_iter: int = 200,
    tol: float = 1e-9,
    stops: bool = False,
) -> FourPLFit:
    """Maximum-likelihood 4PL fit, independently for every group.

    Parameters
    ----------
    x, y
        Independent variable and labels in [0, 1] (1 = "open").
    weights
        Non-negative sample weights (default 1).
    groups
        Integer group of each sample in ``[0, n_groups)`` (default: one group).
    n_groups
        Number of groups (default ``groups.max() + 1``).
    init
        Optional ``(n_groups, 4)`` starting values ``(a, b, c, d)``, e.g. the previous fit in an
        iteration, used where they are likelier than the best increasing step (the b -> inf
        limit of the fit) at three slopes, from which each group starts otherwise.
    sd
        Optional standard deviation of each sample's ``x`` (errors in variables, see above);
        default: ``x`` is exact.
    b_bounds
        Bounds of the slope ``b`` in units of 1/x (default :data:`B_BOUNDS`).
    max_iter, tol
        Iteration cap and relative log-likelihood tolerance (with :data:`X_TOL` on ``c``).
    stops
        Also record how each fit stopped (:class:`FitStops`, the result's ``stops``): the
        same fits, a little slower (a diagnostic: ``benchmarks/fit_settling.py``).

    Returns
    -------
    FourPLFit
        Parameters, log-likelihood and convergence flags per group. A group without samples
        gets NaN parameters and ``converged = False``.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> x = rng.uniform(0, 40, 4000)
    >>> y = rng.random(4000) < logistic4(x, 0.9, 0.5, 20.0, 0.1)
    >>> fit = fit_4pl(x, y)
    >>> bool(abs(fit.c[0] - 20.0) < 1.0)
    True
    """
    x, y, w, g, v, n_groups = _samples(x, y, weights, groups, n_groups, sd)
    init = None if init is None else np.asarray(init, dtype=float)

    def fit(rows: slice, own: slice) -> tuple[np.ndarray, ...]:
        start = None if init is None else init[own]
        n_own = own.stop - own.start
        samples = (x[rows], y[rows], w[rows], g[rows] - own.start, v[rows])
        return _fit(*samples, n_own, start, b_bounds, max_iter, tol, stops)

    a, b, c, d, ll, converged, n_iter, separable, gap_lo, gap_hi, *how = by_groups(g, n_groups, fit)
    record = FitStops(*how) if stops else None
    return FourPLFit(a, b, c, d, ll, converged, n_iter, separable, gap_lo, gap_hi, record)


def _fit(x, y, w, g, v, n_groups, init, b_bounds, max_iter, tol, stops) -> tuple[np.ndarray, ...]:
    """:func:`fit_4pl` of samples sorted by group: its :class:`FourPLFit`'s fields (and, with
    ``stops``, its :class:`FitStops`')."""
    counts = np.bincount(g, weights=(w > 0).astype(float), minlength=n_groups)
    lo, hi = group_range(x, g, n_groups)
    span = np.maximum(hi - lo, 1e-6)
    theta0 = _start(x, y, w, g, v, n_groups, lo, hi, init, b_bounds[1])
    box_lo, box_hi = _box(lo, hi, span, b_bounds, n_groups)
    theta = np.clip(np.nan_to_num(theta0), box_lo, box_hi)
    trace = Trace(theta, max_iter) if stops else None
    data = (x, y, w, g, v)
    fitted = counts > 0
    ll, converged, n_iter = np.zeros(n_groups), np.zeros(n_groups, bool), np.zeros(n_groups, int)
    gap_lo, gap_hi = np.full(n_groups, np.nan), np.full(n_groups, np.nan)
    last_gap = (gap_lo.copy(), gap_hi.copy())
    active, left = fitted.copy(), max_iter
    fit = _LevenbergMarquardt(theta, _ActiveRows(*data, active), active.copy(), box_lo, box_hi)
    while active.any() and left > 0:
        # runs of GAP_AFTER iterations, after each of which a c that lies in a wide gap is
        # fixed at its middle: a converged one's (a defined point of the gap, not where a step
        # happened to stop), and a moving one's that was in the same gap the run before
        fit.data, fit.active = _ActiveRows(*data, active), active.copy()
        ran, ran_rows = active.copy(), fit.data.arrays  # (rows of at least the run's groups)
        fit.fixed[:, 1] = fit.fixed[:, 2] = ~np.isnan(gap_lo)
        before = (theta[:, 2].copy(), ll.copy(), left < max_iter)
        _, t_ll, t_converged, t_iter = fit.run(min(left, GAP_AFTER), tol, trace)
        ll[active], converged[active] = t_ll[active], t_converged[active]
        converged |= active & before[2] & _still(theta[:, 2], ll, *before[:2], GAP_AFTER * tol)
        n_iter += t_iter
        left -= GAP_AFTER
        if left > 0:  # (a group that did not run was checked with the parameters it has)
            free = ran & np.isnan(gap_lo)
            fixed, last_gap = _fit_in_gaps(
                theta, ran_rows, free, converged, last_gap, box_lo, box_hi
            )
            gap_lo[fixed], gap_hi[fixed] = last_gap[0][fixed], last_gap[1][fixed]
            active = fitted & (~converged | fixed)
    a, b, c, d = _from_theta(theta).T
    empty = counts == 0
    for v in (a, b, c, d, ll):
        v[empty] = np.nan
    separable = ~empty & (theta[:, 1] >= box_hi[:, 1] - 1e-9)
    fields = (a, b, c, d, ll, converged & ~empty, n_iter, separable, gap_lo, gap_hi)
    return fields if trace is None else fields + trace.stops(theta, box_lo, box_hi)


def _still(c, ll, c_before, ll_before, tol) -> np.ndarray:
    """Groups whose ``c`` moved by at most :data:`X_TOL` and whose log-likelihood gained at
    most ``tol`` (relative) over a run of iterations: converged on what is reported, however
    the single steps zig-zag about it (Fisher scoring's steps in ``c`` with errors in x can
    swing by centimetres about an optimum that moves by a tenth of a millimetre a step)."""
    moved = np.abs(c - c_before) <= X_TOL
    return moved & (np.abs(ll - ll_before) <= tol * (1.0 + np.abs(ll)))


def _fit_in_gaps(theta, data, groups, converged, last_gap, box_lo, box_hi):
    """Which of ``groups`` (a mask) have their ``c`` in a gap of their samples wider than
    their transition (3/b, blurred by the samples' errors in x), ``converged`` there or in the
    same gap as ``last_gap`` (the gaps' ends the check before). Those have their ``c`` moved to
    the gap's middle (in place on ``theta``; to the box's end where the gap reaches beyond the
    samples) and their ``b`` to its upper bound: the samples see a step across the gap, sharper
    than anything they can tell (``b`` would creep up for hundreds of iterations, each making
    the step a little sharper), and the range holds the whole gap instead. Also returns each
    group's gap now."""
    x, y, w, g, v = data
    gap_lo, gap_hi = gap_around(x, w, g, theta[:, 2], groups)
    wide = groups & (gap_hi - gap_lo > 3.0 / blurred_slope(theta[:, 1], w, g, v))
    stays = (gap_lo == last_gap[0]) & (gap_hi == last_gap[1])
    in_gap = wide & (converged | stays)
    middle = np.where(np.isinf(gap_lo), box_lo[:, 2], box_hi[:, 2])
    finite = in_gap & np.isfinite(gap_lo) & np.isfinite(gap_hi)
    middle[finite] = 0.5 * (gap_lo[finite] + gap_hi[finite])
    theta[in_gap, 2] = middle[in_gap]
    theta[in_gap, 1] = box_hi[in_gap, 1]
    # a step across the gap: the open fractions above and below it are a and d (exact for
    # samples without errors in x; the fit goes on from there)
    rows = in_gap[g]
    xr, yr, wr, gr = x[rows], y[rows], w[rows], g[rows]
    above = xr >= gap_hi[gr]
    n = theta.shape[0]
    with np.errstate(invalid="ignore", divide="ignore"):
        a, d = (
            np.bincount(gr[side], wr[side] * yr[side], n) / np.bincount(gr[side], wr[side], n)
            for side in (above, ~above)
        )
    step = _to_theta(np.nan_to_num(np.column_stack([a, np.ones(n), middle, d]), nan=0.5))
    for k in (0, 3):
        theta[in_gap, k] = np.clip(step[in_gap, k], box_lo[in_gap, k], box_hi[in_gap, k])
    return in_gap, (gap_lo, gap_hi)


def _samples(x, y, weights, groups, n_groups, sd):
    """The samples as arrays (weights, groups and ``x``'s variances filled in), grouped
    (the likelihood sums run block by block), and the number of groups."""
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    w = np.ones_like(x) if weights is None else np.asarray(weights, dtype=float)
    g = np.zeros(x.shape, dtype=np.intp) if groups is None else np.asarray(groups, dtype=np.intp)
    v = np.zeros_like(x) if sd is None else np.asarray(sd, dtype=float) ** 2
    if n_groups is None:
        n_groups = int(g.max()) + 1 if g.size else 1
    if np.any(g[1:] < g[:-1]):
        order = np.argsort(g, kind="stable")
        x, y, w, g, v = x[order], y[order], w[order], g[order], v[order]
    return x, y, w, g, v, n_groups


def _start(x, y, w, g, v, n_groups, lo, hi, init, b_max) -> np.ndarray:
    """Each group's starting parameters: the likeliest of the best increasing step at three
    slopes (b, 4b, b/4) and as a step (``b_max``: separated data start where they end), and
    ``init``."""
    step = _initial_theta(x, y, w, g, n_groups, lo, hi)
    slope = np.array([0.0, 1.0, 0.0, 0.0])
    sharp = step.copy()
    sharp[:, 1] = np.log(b_max)
    starts = [step, step + np.log(4.0) * slope, step - np.log(4.0) * slope, sharp]
    if init is not None:
        starts.append(np.nan_to_num(_to_theta(init)))
    return _likeliest(starts, x, y, w, g, v, n_groups)


def _box(lo, hi, span, b_bounds, n_groups) -> tuple[np.ndarray, np.ndarray]:
    """The bounds of each group's parameters (logits of a and d, log b, c within a span of
    its observed range)."""
    logit, log_b = np.full(n_groups, _LOGIT_BOUND), (np.log(b_bounds[0]), np.log(b_bounds[1]))
    box_lo = np.column_stack([-logit, np.full(n_groups, log_b[0]), lo - span, -logit])
    box_hi = np.column_stack([logit, np.full(n_groups, log_b[1]), hi + span, logit])
    return box_lo, box_hi


class _LevenbergMarquardt:
    """Damped (projected) Newton steps on the Fisher information of every active group at
    once (in place on ``theta``), parameters marked ``fixed`` held where they are; each
    :meth:`run` goes on with the damping where the last left it."""

    def __init__(self, theta, data: _ActiveRows, active, box_lo, box_hi):
        self.theta, self.data, self.active = theta, data, active
        self.box_lo, self.box_hi = box_lo, box_hi
        self.fixed = np.zeros(theta.shape, dtype=bool)
        self.lam = np.full(theta.shape[0], 1e-3)

    def run(self, max_iter: int, tol: float, trace: Trace | None = None):
        """Step until each group converges (:data:`X_TOL`) or ``max_iter``: the parameters,
        log-likelihoods, convergence flags and iteration counts (``trace``: told each
        iteration's steps)."""
        theta, data, active, box_lo, box_hi = (
            self.theta,
            self.data,
            self.active,
            self.box_lo,
            self.box_hi,
        )
        n_groups = theta.shape[0]
        ll, grad, fisher = evaluate(theta, *data.arrays, n_groups, active)
        lam = self.lam
        converged = np.zeros(n_groups, dtype=bool)
        n_iter = np.zeros(n_groups, dtype=int)
        for _ in range(max_iter):
            if not active.any():
                break
            idx = np.flatnonzero(active)
            n_iter[idx] += 1
            # Parameters on a bound whose gradient pushes outwards stay there (projected Newton).
            frozen = (
                self.fixed[idx]
                | ((theta[idx] <= box_lo[idx] + 1e-12) & (grad[idx] < 0))
                | ((theta[idx] >= box_hi[idx] - 1e-12) & (grad[idx] > 0))
            )
            step = _damped_step(grad[idx], fisher[idx], lam[idx], frozen)
            trial = theta.copy()
            trial[idx] = np.clip(theta[idx] + step, box_lo[idx], box_hi[idx])
            t_ll, t_grad, t_fisher = evaluate(trial, *data.shrink(active), n_groups, active)
            gain = t_ll[idx] - ll[idx]
            accept = gain >= -1e-12 * (1.0 + np.abs(ll[idx]))
            acc = idx[accept]
            moved = np.abs(trial[idx] - theta[idx])
            theta[acc], ll[acc] = trial[acc], t_ll[acc]
            grad[acc], fisher[acc] = t_grad[acc], t_fisher[acc]
            lam[acc] = np.maximum(lam[acc] / 4.0, 1e-9)
            lam[idx[~accept]] *= 8.0
            small = (np.abs(gain) <= tol * (1.0 + np.abs(ll[idx]))) & (moved[:, 2] <= X_TOL)
            if trace is not None:
                trace.step(idx, gain / (1.0 + np.abs(ll[idx])), accept, lam, theta)
            done = (accept & (small | (moved.max(axis=1) < 1e-10))) | (lam[idx] > 1e12)
            converged[idx[done]] = True
            active[idx[done]] = False
        return theta, ll, converged, n_iter


#: The samples' x, y, w, g and v of :func:`~.likelihood.evaluate`.
_Samples = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]


class _ActiveRows:
    """The samples of the groups still iterating, compacted whenever they fall to three
    quarters, so that a few slow groups cost their own rows per iteration, not the whole
    dataset's (a compaction costs about one of the passes it saves)."""

    def __init__(self, x, y, w, g, v, active):
        self.arrays: _Samples = (x, y, w, g, v)
        self.shrink(active)

    def shrink(self, active: np.ndarray) -> _Samples:
        g = self.arrays[3]
        keep = active[g]
        if keep.sum() <= 0.75 * g.size:
            self.arrays = cast(_Samples, tuple(v[keep] for v in self.arrays))
        return self.arrays


def group_range(x: np.ndarray, g: np.ndarray, n_groups: int) -> tuple[np.ndarray, np.ndarray]:
    """Smallest and largest ``x`` of every group (0 for an empty group)."""
    lo = np.full(n_groups, np.inf)
    hi = np.full(n_groups, -np.inf)
    if np.all(g[1:] >= g[:-1]):  # a group's rows together (4PL-B's): reduce each run of rows
        starts = np.searchsorted(g, np.arange(n_groups))
        full = starts < np.searchsorted(g, np.arange(n_groups), side="right")
        if full.any():  # each run reaches the next run's start: exact, as min and max are
            lo[full] = np.minimum.reduceat(x, starts[full])
            hi[full] = np.maximum.reduceat(x, starts[full])
    else:
        np.minimum.at(lo, g, x)
        np.maximum.at(hi, g, x)
    lo[~np.isfinite(lo)] = 0.0
    hi[~np.isfinite(hi)] = 0.0
    return lo, hi


def _initial_theta(x, y, w, g, n_groups, lo, hi):
    """Start each group at its best increasing step: the split of the sorted samples whose
    two-level Bernoulli likelihood (open fraction ``d`` below, ``a > d`` above) is highest,
    i.e. the 4PL maximum-likelihood fit in the limit b -> inf."""
    theta = np.zeros((n_groups, 4))
    if x.size == 0:
        return theta
    if _sorted_by_group_then_x(x, g):
        xs, ys, ws, gs = x, y, w, g
    else:
        order = np.lexsort((x, g))
        xs, ys, ws, gs = x[order], y[order], w[order], g[order]
    starts = np.searchsorted(gs, np.arange(n_groups))
    ends = np.searchsorted(gs, np.arange(n_groups), side="right")
    ones = _within_cumsum(ws * ys, gs)  # weighted open labels at or below each sample
    mass = _within_cumsum(ws, gs)
    tot_ones = np.bincount(gs, ws * ys, n_groups)
    tot_mass = np.bincount(gs, ws, n_groups)
    p_below = ones / np.maximum(mass, 1e-300)
    up_mass = tot_mass[gs] - mass
    p_above = (tot_ones[gs] - ones) / np.maximum(up_mass, 1e-300)
    score = mass * _neg_entropy(p_below) + up_mass * _neg_entropy(p_above)
    last = np.r_[gs[1:] != gs[:-1], True]  # no split above the highest sample of a group
    score[(p_above <= p_below) | last] = -np.inf
    best = np.full(n_groups, -np.inf)
    np.maximum.at(best, gs, score)
    idx = np.arange(xs.size)
    pick = np.full(n_groups, -1)
    np.maximum.at(pick, gs[score == best[gs]], idx[score == best[gs]])
    has = (pick >= 0) & np.isfinite(best)
    mid = np.where(
        has,
        0.5 * (xs[np.maximum(pick, 0)] + xs[np.minimum(pick + 1, xs.size - 1)]),
        0.5 * (lo + hi),
    )
    d0 = np.where(has, p_below[np.maximum(pick, 0)], 0.1)
    a0 = np.where(has, p_above[np.maximum(pick, 0)], 0.9)
    a0 = np.clip(a0, 0.05, 0.99)
    d0 = np.clip(d0, 0.01, a0 - 0.02)
    # Slope: a transition about a quarter of the interquartile range wide (robust to the long
    # tail of high intersections); fit_4pl also tries 4x steeper and 4x gentler.
    count = ends - starts
    q1 = xs[np.minimum(starts + count // 4, xs.size - 1)]
    q3 = xs[np.minimum(starts + (3 * count) // 4, xs.size - 1)]
    b0 = 12.0 / np.maximum(q3 - q1, 1e-3)
    return _to_theta(np.column_stack([a0, b0, mid, d0]))


def _sorted_by_group_then_x(x, g):
    same = g[1:] == g[:-1]
    return not (np.any(g[1:] < g[:-1]) or np.any(same & (x[1:] < x[:-1])))


def _likeliest(starts, x, y, w, g, v, n_groups):
    """Per group, the likeliest of several starting points. The best step with three slopes
    guards against too gentle a start sliding into the flat (a = d) basin of the likelihood; a
    caller's start (the previous fit in 4PL-B) is kept only while it is still the likeliest, so
    an iteration cannot stay trapped where an earlier one went wrong."""
    everyone = np.ones(n_groups, dtype=bool)
    best = starts[0]
    best_ll = evaluate(best, x, y, w, g, v, n_groups, everyone, ll_only=True)[0]
    for cand in starts[1:]:
        ll = evaluate(cand, x, y, w, g, v, n_groups, everyone, ll_only=True)[0]
        better = ll > best_ll
        best = np.where(better[:, None], cand, best)
        best_ll = np.where(better, ll, best_ll)
    return best


def _within_cumsum(values, gs):
    """The running sum of ``values`` within each group (``gs`` sorted), each group summed on
    its own: not a difference of one running sum over all groups, whose rounding would depend
    on the groups before (a tile's or a whole run's)."""
    return pd.Series(values).groupby(gs, sort=False).cumsum().to_numpy()


def _neg_entropy(p):
    q = np.clip(p, 1e-300, 1.0)
    r = np.clip(1.0 - p, 1e-300, 1.0)
    return p * np.log(q) + (1.0 - p) * np.log(r)


def _to_theta(params):
    params = np.asarray(params, dtype=float)
    a = np.clip(params[:, 0], 1e-6, 1 - 1e-6)
    d = np.clip(params[:, 3], 1e-9, None)
    ratio = np.clip(d / a, 1e-6, 1 - 1e-6)
    return np.column_stack(
        [
            np.log(a / (1 - a)),
            np.log(np.maximum(params[:, 1], 1e-300)),
            params[:, 2],
            np.log(ratio / (1 - ratio)),
        ]
    )


def _from_theta(theta):
    a = expit(theta[:, 0])
    return np.column_stack([a, np.exp(theta[:, 1]), theta[:, 2], a * expit(theta[:, 3])])


def _damped_step(grad, fisher, lam, frozen):
    """Levenberg-Marquardt step; frozen parameters are decoupled and do not move."""
    free = (~frozen).astype(float)
    grad = grad * free
    fisher = fisher * free[:, :, None] * free[:, None, :]
    diag = np.einsum("kii->ki", fisher)
    damp = fisher + (lam[:, None] * np.maximum(diag, 1e-12) + frozen)[:, :, None] * np.eye(4)
    damp += 1e-12 * np.eye(4)
    return np.linalg.solve(damp, grad[:, :, None])[:, :, 0] * free
