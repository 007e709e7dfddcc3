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
buildings behind it), and the roof lines of its cycle, or of its swing's last turn (not the
whole window's: one early excursion, before the loop found its feet, is not where the roof
line swings now), stay in its range (:attr:`Settling.span_lower`,
:attr:`Settling.span_upper`): the data say no more of it than that.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

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


@dataclass(frozen=True)
class Settling:
    """Where each of a part's own buildings stands across the iterations (arrays of length
    ``n_own``)."""

    #: The ``c`` of the last :data:`MAX_PERIOD` fits, the newest last (NaN before the first).
    recent: np.ndarray
    #: Whether the last fit's ``c`` is within :data:`SETTLE_TOL` of the one before (held
    #: buildings have settled).
    settled: np.ndarray
    #: Buildings held at their fit since their roof line came back to an earlier one or swung.
    held: np.ndarray
    #: The lowest and highest roof line of a held building's cycle or swing (NaN for others).
    span_lower: np.ndarray
    span_upper: np.ndarray

    @classmethod
    def start(cls, n_own: int) -> Settling:
        """Before the first fit: nothing has settled."""
        nan = np.full(n_own, np.nan)
        no = np.zeros(n_own, dtype=bool)
        return cls(np.full((n_own, MAX_PERIOD), np.nan), no, no, nan, nan.copy())

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
        last_turn = window[swings, -3:]  # the swing's roof lines now: its last turn's
        span_lower[swings], span_upper[swings] = last_turn.min(axis=1), last_turn.max(axis=1)
        held |= swings
        recent = np.column_stack([recent[:, 1:], c])
        return Settling(recent, still | held, held, span_lower, span_upper)

    def moving(self, fitted: np.ndarray) -> int:
        """How many of the ``fitted`` buildings (those with a fit) have not settled."""
        return int(np.count_nonzero(fitted & ~self.settled))
