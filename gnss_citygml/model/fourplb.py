"""4PL-B: the bootstrapped four-parameter logistic building-height estimator (Algorithm 1).

For every building, a 4PL in intersection height (the *map classifier*) is fitted to signals
labelled by a C/N0 *signal classifier*; the signals are then relabelled by the map (open where
the intersection height is above the fitted inflection point ``c``), the signal classifier is
refitted to those labels, and the loop repeats until fewer than 1 % of the map labels change or
10 iterations have run. The height estimate is ``c + 1.5/b`` with range ``(c, c + 3/b)``.

The signal classifier belongs to a dataset (one device): in a run over many buildings it is
co-trained on all buildings' relabelled signals at once, while each building keeps its own
height 4PL. When the table says which rows are the same signal (``signal``), a signal is
labelled open only when its ray clears every building it crosses.

Beyond the paper (its discussion section): the height fit can reweight the data by the
distribution of intersection heights (``weighting``), so that a building seen mostly from one
side of its roof line (a canyon where nearly all signals are blocked, a terrace where nearly
all are open) is fitted to the open-fraction-versus-height pattern, not to the bulk of the data.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .classifier import SignalClassifier
from .fourpl import B_BOUNDS, FourPLFit, fit_4pl

__all__ = ["WEIGHTINGS", "BuildingFits", "fourplb", "height_weights", "map_fit"]

#: Reweighting schemes of the height fit; see :func:`height_weights`.
WEIGHTINGS = ("none", "height", "balanced")

#: Width (m) of the intersection-height bins of the ``height`` weighting: finer than any
#: building's height uncertainty, coarse enough to hold several signals each.
HEIGHT_BIN = 1.0


@dataclass(frozen=True)
class BuildingFits:
    """Per-building results of a height estimator (arrays of length ``n_buildings``)."""

    a: np.ndarray
    b: np.ndarray
    c: np.ndarray
    d: np.ndarray
    n_signals: np.ndarray
    iterations: np.ndarray
    converged: np.ndarray
    status: np.ndarray
    height: np.ndarray
    height_lower: np.ndarray
    height_upper: np.ndarray


def height_weights(height, groups, n_groups, scheme, c=None):
    """Sample weights of the height fit, normalised to a mean of 1 within each building.

    ``none``
        Every signal counts once (the paper's MLE).
    ``height``
        Inverse density of intersection heights in :data:`HEIGHT_BIN` bins, so that each metre
        of height counts the same whatever the number of signals that happen to cross it.
        A bin's count is floored at the building's mean count per occupied bin, so that a
        sparsely crossed height does not weigh more than an average one.
    ``balanced``
        Signals above and below the current inflection point ``c`` carry equal total weight.
    """
    height = np.asarray(height, dtype=float)
    groups = np.asarray(groups, dtype=np.intp)
    if scheme == "none":
        return np.ones_like(height)
    if scheme == "height":
        bins = np.floor(height / HEIGHT_BIN).astype(np.int64)
        key = groups.astype(np.int64) * (1 << 32) + (bins - bins.min())
        _, inverse, counts = np.unique(key, return_inverse=True, return_counts=True)
        n = np.bincount(groups, minlength=n_groups).astype(float)
        occupied = np.bincount(groups[np.unique(inverse, return_index=True)[1]], minlength=n_groups)
        floor = n / np.maximum(occupied, 1)
        raw = 1.0 / np.maximum(counts[inverse], floor[groups])
    elif scheme == "balanced":
        if c is None:
            return np.ones_like(height)
        above = height > np.asarray(c)[groups]
        n_above = np.bincount(groups, weights=above.astype(float), minlength=n_groups)
        n_below = np.bincount(groups, minlength=n_groups) - n_above
        raw = np.where(
            above, 1.0 / np.maximum(n_above, 1)[groups], 1.0 / np.maximum(n_below, 1)[groups]
        )
    else:
        raise ValueError(f"unknown weighting {scheme!r}; use one of {', '.join(WEIGHTINGS)}")
    total = np.bincount(groups, weights=raw, minlength=n_groups)
    n = np.bincount(groups, minlength=n_groups)
    return raw * (n / np.maximum(total, 1e-300))[groups]


def map_fit(height, labels, groups, n_groups, weights, init=None) -> FourPLFit:
    """Fit every building's map classifier (a 4PL in intersection height) at once."""
    return fit_4pl(height, labels, weights, groups, n_groups, init=init)


def fourplb(
    groups,
    height,
    cn0,
    n_groups: int,
    *,
    init_threshold: float = 30.0,
    signal=None,
    weighting: str = "height",
    max_iter: int = 10,
    label_tol: float = 0.01,
    min_signals: int = 10,
    min_separation: float = 0.1,
    bootstrap: bool = True,
) -> tuple[BuildingFits, SignalClassifier]:
    """Run 4PL-B (or, with ``bootstrap=False``, the paper's one-shot 4PL) on coded arrays.

    Parameters
    ----------
    groups
        Building code of each row, in ``[0, n_groups)``.
    height, cn0
        Intersection height (m) and C/N0 (dB-Hz, NaN = blocked) of each row.
    n_groups
        Number of buildings.
    init_threshold
        C/N0 at which the initial signal classifier gives Pr(open) = 0.5.
    signal
        Optional signal code of each row (rows of one signal crossing several buildings).
    weighting
        Reweighting of the height fit, one of :data:`WEIGHTINGS`.
    max_iter, label_tol
        Stop after ``max_iter`` iterations or when fewer than ``label_tol`` of every building's
        map labels change between two iterations.
    min_signals, min_separation
        A building needs at least ``min_signals`` rows, and its fitted asymptotes must differ by
        at least ``min_separation`` (the height must change the open probability by that much),
        for its estimate to count as converged.
    bootstrap
        False runs a single pass (label by the initial classifier, fit, stop): the paper's 4PL.

    Returns
    -------
    (BuildingFits, SignalClassifier)
        The per-building fits and the final signal classifier.
    """
    groups = np.asarray(groups, dtype=np.intp)
    height = np.asarray(height, dtype=float)
    cn0 = np.asarray(cn0, dtype=float)
    n_rows = np.bincount(groups, minlength=n_groups)
    usable = n_rows >= min_signals
    rows = usable[groups]
    g, h, s = groups[rows], height[rows], cn0[rows]
    sig = None if signal is None else np.unique(np.asarray(signal)[rows], return_inverse=True)[1]

    classifier = SignalClassifier.initial(init_threshold)
    labels = classifier.label(s)
    weights = height_weights(h, g, n_groups, weighting)
    fit, prev_map, iterations = None, None, 0
    change = np.ones(n_groups)
    for iterations in range(1, (max_iter if bootstrap else 1) + 1):
        init = None if fit is None else fit.params
        fit_labels = labels
        fit = map_fit(h, fit_labels, g, n_groups, weights, init=init)
        if not bootstrap:
            break
        new_map = h > fit.c[g]
        if prev_map is not None:
            changed = np.bincount(
                g, weights=(new_map != prev_map).astype(float), minlength=n_groups
            )
            change = changed / np.maximum(n_rows, 1)
        prev_map = new_map
        classifier = classifier.refit(*_classifier_data(s, new_map, sig))
        labels = classifier.label(s)
        if weighting == "balanced":
            weights = height_weights(h, g, n_groups, weighting, c=fit.c)
        if prev_map is not None and iterations > 1 and np.all(change[usable] < label_tol):
            break

    result = _judge(
        fit,
        g,
        h,
        fit_labels,
        n_groups,
        n_rows,
        usable,
        change,
        iterations,
        label_tol if bootstrap else np.inf,
        min_separation,
        min_signals,
    )
    return result, classifier


def _classifier_data(cn0, open_map, sig):
    """C/N0 and map label per signal: with signal ids, a signal is open only if it clears every
    building it crosses, and counts once."""
    if sig is None:
        return cn0, open_map
    n_sig = int(sig.max()) + 1 if sig.size else 0
    closed = np.bincount(sig, weights=(~open_map).astype(float), minlength=n_sig)
    first = np.full(n_sig, -1)
    first[sig[::-1]] = np.arange(sig.size)[::-1]
    return cn0[first], closed == 0


def _judge(
    fit,
    g,
    h,
    labels,
    n_groups,
    n_rows,
    usable,
    change,
    iterations,
    label_tol,
    min_separation,
    min_signals,
):
    """Turn a fit into heights, with an explicit reason wherever it is not to be trusted."""
    a, b, c, d = (v.copy() for v in (fit.a, fit.b, fit.c, fit.d))
    lo = np.full(n_groups, np.inf)
    hi = np.full(n_groups, -np.inf)
    np.minimum.at(lo, g, h)
    np.maximum.at(hi, g, h)
    n_open = np.bincount(g, weights=labels.astype(float), minlength=n_groups)
    status = np.full(n_groups, "ok", dtype=object)
    checks = [
        (~fit.converged, "the 4PL optimiser did not converge"),
        (change >= label_tol, f"labels still changing after {iterations} iterations"),
        (b <= B_BOUNDS[0] * 1.0001, "no slope: the height does not change the open probability"),
        ((c < lo) | (c > hi), "inflection point outside the observed intersection heights"),
        (a - d < min_separation, f"asymptotes closer than {min_separation} (a - d)"),
        (n_open == 0, "no signal is labelled open"),
        (n_open == n_rows, "every signal is labelled open"),
        (~usable, f"fewer than {min_signals} signals"),
    ]
    for bad, reason in checks:  # the last failing check is the most basic one: it wins
        status[bad] = reason
    converged = status == "ok"
    height = np.where(converged, c + 1.5 / b, np.nan)
    return BuildingFits(
        a=a,
        b=b,
        c=c,
        d=d,
        n_signals=n_rows,
        iterations=np.where(usable, iterations, 0),
        converged=converged,
        status=status,
        height=height,
        height_lower=np.where(converged, c, np.nan),
        height_upper=np.where(converged, c + 3.0 / b, np.nan),
    )
