"""Which of a part's buildings 4PL-B fits again, and which 4PL each shows the others: a fit
whose data have not moved is kept as it was (:meth:`~.parts.Part.fitted`)."""

from __future__ import annotations

import numpy as np

from .fourpl import X_TOL, FourPLFit

__all__ = ["FIXED_WEIGHTS", "SAME_WITHIN", "SHOWN_WITHIN", "changed", "shown_fits"]

#: Weightings whose weights do not change with the fits: a building whose rows and labels are
#: those of its last fit has that fit again.
FIXED_WEIGHTS = ("none", "looks")


#: A row's label or weight that moved by at most this since its building's last fit leaves
#: that fit as it was: a millionth of a row's evidence moves a roof line by micrometres, and
#: refitting for it (soft labels and whole-ray blame move with every neighbour's fit) kept
#: roof lines creeping by them and each late exchange finding their signals again.
SAME_WITHIN = 1e-6


#: A fit shows the other buildings a new 4PL for their blame only where its asymptotes or its
#: slope (relative) moved by more than this, or its roof line by more than
#: :data:`~.fourpl.X_TOL`, since the 4PL it showed last (:func:`shown_fits`).
SHOWN_WITHIN = 1e-4


def shown_fits(fit: FourPLFit, before: np.ndarray) -> np.ndarray:
    """The 4PLs ``(a, b, c, d)`` each building shows the others for their blame: its ``fit``
    where it moved beyond :data:`SHOWN_WITHIN` (or its roof line beyond 1 mm) since the one it
    showed ``before``, else that one. Each building's blame hangs on its neighbours' fits, and
    theirs on its own: a roof line's micrometre move changed a sharp neighbour's rows by more
    than :data:`SAME_WITHIN` and the pair refitted each other, every iteration, down a slow
    geometric tail. A change this small moves no ray's chance by more than a ten-thousandth."""
    now = fit.params
    a0, b0, c0, d0 = before.T
    near = np.abs(fit.c - c0) <= X_TOL
    near &= (np.abs(fit.a - a0) <= SHOWN_WITHIN) & (np.abs(fit.d - d0) <= SHOWN_WITHIN)
    near &= np.abs(fit.b - b0) <= SHOWN_WITHIN * np.abs(b0)
    return np.where(near[:, None], before, now)


def changed(
    g: np.ndarray,
    n_own: int,
    labels: np.ndarray,
    last_labels: np.ndarray,
    seen: np.ndarray,
    last_seen: np.ndarray,
) -> np.ndarray:
    """The own buildings (``g``: each own row's) with a row whose label or whose use by the
    fit (``seen``, or its weight) changed by more than :data:`SAME_WITHIN` since the last fit:
    the others' fits would be their last ones, to the bit (hard labels) or to micrometres
    where the data pin them, and are not done again (the paper's labels settle building by
    building, and most of a late iteration's fits would repeat)."""
    differ = np.abs(np.subtract(labels, last_labels, dtype=float)) > SAME_WITHIN
    differ |= np.abs(np.subtract(seen, last_seen, dtype=float)) > SAME_WITHIN
    return np.bincount(g[differ], minlength=n_own) > 0
