"""Whether each building's roof line has settled across 4PL-B's iterations, and the buildings
whose labels cycle.

The paper's loop stops when fewer than 1 % of the map labels change, and the largest building's
change decides. Two things keep that loop moving where the data are sparse: a building whose
roof line jumps between two to four places, taking rows across with it at every jump (the
labels cycle: relabelled by one roof line, the signals fit the next), and roof lines that creep
by millimetres to decimetres while their labels stay (the shared signal model and visibility
model under them move). Then the heights are wherever the iteration cap stops the loop.

So a building has *settled* when its ``c`` moved by at most :data:`SETTLE_TOL` since the
iteration before, and 4PL-B's loop ends when every building has settled. A building whose
``c`` comes back within :data:`SETTLE_TOL` of where it was two to :data:`MAX_PERIOD`
iterations before, having moved since, is in a cycle; one whose ``c`` turned back
:data:`REVERSALS` times in the last :data:`MAX_PERIOD` moves is swinging. Either is *held* at
its current fit from then on (no longer refitted, so it stops moving the signal model and the
buildings behind it), and the roof lines of its cycle or its swing
(:attr:`Settling.span_lower`, :attr:`Settling.span_upper`) stay in its range: the data say
no more of it than that.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .fourpl import FourPLFit

__all__ = ["MAX_PERIOD", "REVERSALS", "SETTLE_TOL", "Settling"]

#: How far (m) a building's roof line ``c`` may move between iterations and be settled: a
#: millimetre, what the height fits converge to (:data:`~.fourpl.X_TOL`).
SETTLE_TOL = 1e-3
#: The longest cycle of roof lines looked for (iterations): the benchmark city's cycles are of
#: periods 2 to 4 (docs/issue-46-settling.md).
MAX_PERIOD = 6
#: Turns (a move by more than :data:`SETTLE_TOL` followed by one the other way) over the last
#: :data:`MAX_PERIOD` moves after which a roof line that has not settled is held as swinging:
#: a converging roof line moves one way; one that turns back three times is driven by labels
#: that swap between roof lines without repeating exactly (a sparse building's, or one its
#: neighbours keep relabelling), and more iterations only draw more of the same swing.
REVERSALS = 3
#: The largest ratio of successive moves :meth:`Settling.extrapolated` leaps with: at most
#: nine times the last move.
MAX_RATIO = 0.9
#: How alike the ratios of successive moves must be for :meth:`Settling.extrapolated` to take
#: the moves as geometric.
RATIO_AGREE = 0.1


@dataclass(frozen=True)
class Settling:
    """Where each of a part's own buildings stands across the iterations (arrays of length
    ``n_own``)."""

    #: The ``c`` of the last :data:`MAX_PERIOD` fits, the newest last (NaN before the first).
    recent: np.ndarray
    #: Whether the last fit's ``c`` is within :data:`SETTLE_TOL` of the one before (held
    #: buildings have settled).
    settled: np.ndarray
    #: Buildings held at their fit since their roof line came back to an earlier one.
    held: np.ndarray
    #: The lowest and highest roof line of a held building's cycle (NaN for the others).
    span_lower: np.ndarray
    span_upper: np.ndarray
    #: Buildings whose last ``c`` was extrapolated (:meth:`extrapolated`).
    leapt: np.ndarray

    @classmethod
    def start(cls, n_own: int) -> Settling:
        """Before the first fit: nothing has settled."""
        nan = np.full(n_own, np.nan)
        no = np.zeros(n_own, dtype=bool)
        return cls(np.full((n_own, MAX_PERIOD), np.nan), no, no, nan, nan.copy(), no)

    def keep_held(self, last: FourPLFit, fit: FourPLFit) -> FourPLFit:
        """``fit`` with the held buildings' parameters those of their ``last`` fit."""
        if not self.held.any():
            return fit
        held = self.held
        kept = {
            k: np.where(held, getattr(last, k), getattr(fit, k))
            for k in ("a", "b", "c", "d", "loglik", "converged", "n_iter", "separable")
        }
        kept["gap_lower"] = np.where(held, last.gap_lower, fit.gap_lower)
        kept["gap_upper"] = np.where(held, last.gap_upper, fit.gap_upper)
        return replace(fit, **kept)

    def after(self, c: np.ndarray) -> Settling:
        """The buildings' state after a fit whose roof lines are ``c``."""
        recent, held = self.recent, self.held.copy()
        last = recent[:, -1]
        still = (np.abs(c - last) <= SETTLE_TOL) | (np.isnan(c) & np.isnan(last))
        span_lower, span_upper = self.span_lower.copy(), self.span_upper.copy()
        for period in range(2, MAX_PERIOD + 1):  # the shortest cycle that c closes
            back = ~held & ~still & (np.abs(c - recent[:, -period]) <= SETTLE_TOL)
            cycle = np.column_stack([recent[back, 1 - period :], c[back]])
            span_lower[back], span_upper[back] = cycle.min(axis=1), cycle.max(axis=1)
            held |= back
        # a roof line that turned back REVERSALS times over the window: oscillating, not settling
        window = np.column_stack([recent, c])
        step = np.diff(window, axis=1)
        way = np.where(np.abs(step) > SETTLE_TOL, np.sign(step), 0.0)
        turns = np.count_nonzero(way[:, 1:] * way[:, :-1] < 0, axis=1)
        swings = ~held & ~still & (turns >= REVERSALS)
        span_lower[swings] = np.nanmin(window[swings], axis=1)
        span_upper[swings] = np.nanmax(window[swings], axis=1)
        held |= swings
        recent = np.column_stack([recent[:, 1:], c])
        return Settling(recent, still | held, held, span_lower, span_upper, self.leapt)

    def extrapolated(self, c: np.ndarray) -> tuple[np.ndarray, Settling]:
        """Roof lines ``c`` that approach their limit geometrically moved to it (Aitken's
        delta-squared), and the state that remembers which were (they are not extrapolated
        again at the next step, which checks where the leap landed).

        The mixture's expectation-maximisation moves a roof line by a constant fraction ``r``
        of its last move, iteration after iteration (``r`` about 0.75 where the classes'
        C/N0 overlap: the missing information), so it takes dozens of iterations to settle to
        a millimetre. Where the last three moves went the same way, each shrinking by about the
        same ratio (within :data:`RATIO_AGREE`), ``r`` is the last ratio and the limit is
        ``r / (1 - r)`` of the last move further (``r`` taken at most :data:`MAX_RATIO`)."""
        window = np.column_stack([self.recent[:, -3:], c])
        moves = np.diff(window, axis=1)  # the last three moves, the newest last
        with np.errstate(divide="ignore", invalid="ignore"):
            ratios = moves[:, 1:] / moves[:, :-1]
        ratio = ratios[:, -1]
        move = moves[:, -1]
        geometric = np.all((ratios > 0.0) & (ratios < 1.0), axis=1) & (
            np.abs(ratios[:, 1] - ratios[:, 0]) <= RATIO_AGREE
        )
        leap = ~self.held & ~self.leapt & (np.abs(move) > SETTLE_TOL) & geometric
        r = np.minimum(ratio[leap], MAX_RATIO)
        out = c.copy()
        out[leap] = c[leap] + move[leap] * r / (1.0 - r)
        return out, replace(self, leapt=leap)

    def moving(self, fitted: np.ndarray) -> int:
        """How many of the ``fitted`` buildings (those with a fit) have not settled."""
        return int(np.count_nonzero(fitted & ~self.settled))
