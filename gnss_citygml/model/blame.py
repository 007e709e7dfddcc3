"""Whole-ray blame: what a ray that crosses several buildings tells each of them.

A ray is open only if it clears every building it crosses, so an open ray is open evidence for
each of them, and a closed one was blocked by at least one. Which one the data cannot say; the
buildings' current 4PLs can: with ``p_k`` the chance that the ray clears building ``k`` (its 4PL
at the ray's height there), the chance that ``k`` alone blocks it, given that it is closed, is

    w_k = (1 - p_k) * prod_{j != k} p_j / (1 - prod_j p_j),

1 for a ray that crosses one building, near 0 where another building surely blocks it, in front
of ``k`` or behind. A closed ray is closed evidence for ``k`` with that weight. This is the
observed likelihood of the ray, ``1 - prod_j p_j``, as each building's fit sees it: its
gradient in ``p_k`` is the weighted Bernoulli's, so a fit that iterates with the others'
current fits stops where the rays' own likelihood has its maximum; and a ray that another
building explains weighs little, so it narrows no building's likelihood interval. It replaces
the visibility model's hard choice for the height fits (a ray left out for every building whose
neighbour *might* block it), which, with the neighbour's fit wrong, took the building's own
closed rays away (a roof line fitted 160 m up in a narrow street, issue 47).

A ray's chance of being open ``rho`` (the paper's classifier: 1 or 0; the mixture: its
posterior of clearing every building) makes each row one weighted soft label: the open part
weighs ``rho`` with label 1, the closed part ``(1 - rho) w_k`` with label 0, together weight
``W = rho + (1 - rho) w_k`` and label ``rho / W``, the same log-likelihood.

A ray may not cross a building at all: its receiver's position error may move it past the
footprint's corner (issue 47). With ``q_k`` its chance of crossing (the intersections'
``crossing``), the ray clears building ``k`` with chance ``1 - q_k (1 - p_k)`` (:func:`cleared`),
which takes ``p_k``'s place above; the ray's likelihood's gradient in ``p_k`` is then the
weighted Bernoulli's with the closed part weighing ``w_k`` of those chances and the open part
``q_k p_k / (1 - q_k (1 - p_k))``: an open ray below the roof line that may well miss the
building says little of it, nor does a closed one.
"""

from __future__ import annotations

import numpy as np

from .mixture import PRIOR_EPS

__all__ = ["blamed", "cleared", "others_clear", "sole_blocker"]

#: A row weighs at least this for its building's fit to carry it: below, another building
#: explains its ray (a thousandth of a row's evidence), and the fits are faster without it.
MIN_WEIGHT = 1e-3


def cleared(chance: np.ndarray, crossing: np.ndarray | None) -> np.ndarray:
    """Each row's chance that its ray clears its building, crossing it (its 4PL's ``chance``)
    or not (``crossing``: its chance of crossing it; None: it does)."""
    return chance if crossing is None else 1.0 - crossing * (1.0 - chance)


def others_clear(
    chance: np.ndarray, signal: np.ndarray, along: np.ndarray | None = None
) -> np.ndarray:
    """Each row's chance that its ray clears every *other* building it crosses: the product of
    the ``chance`` of clearing of the other rows of its ``signal`` (each kept
    :data:`~.mixture.PRIOR_EPS` from 0 and 1). ``along``, the rows in order along each ray,
    makes the product's rounding that of the ray, not of the rows' order in a part: every
    part of a run that holds a ray finds the same bits."""
    log_o = np.log(np.clip(chance, PRIOR_EPS, 1 - PRIOR_EPS))
    n_sig = int(signal.max(initial=-1)) + 1
    if along is None:
        total = np.bincount(signal, log_o, n_sig)
    else:
        total = np.bincount(signal[along], log_o[along], n_sig)
    return np.exp(total[signal] - log_o)


def sole_blocker(prior: np.ndarray, rest: np.ndarray) -> np.ndarray:
    """Each row's chance that its building alone blocks its ray, given that the ray is closed
    (``w_k`` above): ``prior`` is each row's chance of clearing its building (kept
    :data:`~.mixture.PRIOR_EPS` from 0 and 1), ``rest`` its ray's of clearing the others
    (:func:`others_clear`)."""
    p = np.clip(prior, PRIOR_EPS, 1 - PRIOR_EPS)
    return (1.0 - p) * rest / (1.0 - p * rest)


def blamed(
    open_chance: np.ndarray,
    prior: np.ndarray,
    rest: np.ndarray,
    crossing: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Each row's soft label and weight for its building's 4PL: ``open_chance`` is each row's
    chance that its whole ray is open, ``prior`` and ``rest`` as in :func:`sole_blocker`, and
    ``crossing`` each row's chance that its ray crosses its building (None: it does).

    A fit takes the other buildings at their fits as last exchanged and its own at its own fit
    (:meth:`~.parts.Part.fitted` refits until they agree: a building's blame does not depend
    on which other buildings a part of a run refits with it, so tiles give the single run's
    heights). The likelihood interval of its roof line takes the others as tall as their data
    leave possible (a roof line fixed in a gap of its rays at the gap's top, one held in a
    cycle at the cycle's top): a closed ray counts for a building's range only as far as no
    other building may have blocked it, so that a neighbour's guess cannot make the range
    narrow."""
    rho = np.clip(np.asarray(open_chance, dtype=float), 0.0, 1.0)
    if crossing is None:
        weight = rho + (1.0 - rho) * sole_blocker(prior, rest)
        label = np.divide(rho, weight, out=np.zeros_like(weight), where=weight > 0)
        return label, weight
    clear = np.clip(cleared(prior, crossing), PRIOR_EPS, 1 - PRIOR_EPS)
    opened = rho * crossing * np.clip(prior, PRIOR_EPS, 1 - PRIOR_EPS) / clear
    weight = opened + (1.0 - rho) * sole_blocker(clear, rest)
    label = np.divide(opened, weight, out=np.zeros_like(weight), where=weight > 0)
    return label, weight
