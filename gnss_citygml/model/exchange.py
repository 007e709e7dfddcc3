"""The paper's exchange, signal by signal (:meth:`.parts.Part.exchanged`): which rows the
visibility model keeps, and which signal each part counts for the classifier and as what,
found again only for the signals that cross a building whose fit moved.

Late in 4PL-B a few roof lines still move while the rest have settled (on the benchmark of
1 M signals x 10,000 buildings, 12 of 23 iterations refit fewer than 25 of 9,075 buildings), and
an exchange over every row costs the same 0.3 s each time. The paper's classifier learns from
whole-number counts by C/N0, so taking the found-again signals' old counts out and their new
ones in is exact: the same rows kept and the same counts, bit for bit, as an exchange over every
row, which is what :func:`exchanged` does where many signals are touched (or nothing is known
yet).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from .classifier import Cn0Counts
from .fourplb import _unoccluded

__all__ = ["Exchange", "Rows", "counted", "differs", "exchanged", "group_rows"]

#: Above this share of the rows touched, an exchange goes over every row (as fast, simpler).
FULL_SHARE = 0.25


@dataclass(frozen=True)
class _SignalRows:
    """Each signal's rows, ``rows[start[s]:start[s + 1]]`` (found once, on the first update)."""

    rows: np.ndarray
    start: np.ndarray

    @classmethod
    def of(cls, sig: np.ndarray) -> _SignalRows:
        rows = np.argsort(sig, kind="stable")
        n_sig = int(sig.max(initial=-1)) + 1
        start = np.searchsorted(sig[rows], np.arange(n_sig + 1))
        return cls(rows.astype(_row_type(sig.size)), start.astype(_row_type(sig.size)))

    def of_signals(self, signals: np.ndarray) -> np.ndarray:
        """The rows of ``signals`` (distinct), sorted."""
        first = self.start[signals]
        return np.sort(self.rows[_ranges(first, self.start[signals + 1] - first)])


def _row_type(n_rows: int) -> type[np.signedinteger]:
    """The type of row numbers of ``n_rows`` rows: int32 where they fit (a run in tiles keeps
    every part's state, 4 bytes a row less), else the platform's."""
    return np.int32 if n_rows < 2**31 else np.intp


def group_rows(g: np.ndarray, groups: np.ndarray) -> np.ndarray:
    """The rows of ``groups`` (distinct, ascending) where the rows are sorted by group ``g``."""
    first = np.searchsorted(g, groups)
    count = np.searchsorted(g, groups, side="right") - first
    return _ranges(first[count > 0], count[count > 0])


def _ranges(first: np.ndarray, count: np.ndarray) -> np.ndarray:
    """``first[i], first[i] + 1, ..., first[i] + count[i] - 1`` for each ``i``, one after the
    other (each ``count`` at least 1)."""
    steps = np.ones(int(count.sum()), dtype=np.intp)
    if steps.size:
        steps[0] = first[0]
        steps[np.cumsum(count)[:-1]] = first[1:] - (first[:-1] + count[:-1] - 1)
    return np.cumsum(steps)


@dataclass(frozen=True)
class Exchange:
    """What a part's last exchange found, for the next one: the fits it was given (each
    building's ``c``, ``b``, ``plausible`` and whether it teaches), the rows it counted from
    (``used``), each signal's counted row (``lead``, -1: none of the part's) and map label
    (``clear``), the part's ``evidence``, and the signals whose kept rows changed
    (``moved``: their rows are counted from anew next time)."""

    c: np.ndarray
    b: np.ndarray
    plausible: np.ndarray
    teach: np.ndarray
    used: np.ndarray
    lead: np.ndarray
    clear: np.ndarray
    evidence: Cn0Counts
    moved: np.ndarray
    by_signal: _SignalRows | None = None


class Rows(Protocol):
    """What an exchange reads of a part (:class:`~.parts.Part`): its rows' building ``g``,
    height ``h``, C/N0 ``s``, signal ``sig`` and order along the ray, its own buildings'
    number, the rows the fits may use (``seen``), whether the visibility model is on, and
    its last :class:`Exchange`, and which rows' rays enter their building (``entered``; None:
    all)."""

    @property
    def g(self) -> np.ndarray: ...
    @property
    def h(self) -> np.ndarray: ...
    @property
    def s(self) -> np.ndarray: ...
    @property
    def sig(self) -> np.ndarray: ...
    @property
    def order(self) -> np.ndarray | None: ...
    @property
    def n_own(self) -> int: ...
    @property
    def seen(self) -> np.ndarray: ...
    @property
    def occlusion(self) -> bool: ...
    @property
    def exchange(self) -> Exchange | None: ...
    @property
    def entered(self) -> np.ndarray | None: ...


def counted(
    sig: np.ndarray,
    order: np.ndarray | None,
    g: np.ndarray,
    n_own: int,
    rows: np.ndarray,
    open_rows: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """The rows of the signals a part counts among ``rows`` (row numbers, those the fits used)
    and each one's map label. A signal is counted by its first row along the ray (by
    ``order``; without it, its first row), where that row is of an own building (code below
    ``n_own``), and is open only if each of its ``rows`` is (``open_rows``)."""
    s = sig[rows]
    n_sig = int(s.max(initial=-1)) + 1
    closed = np.bincount(s[~open_rows], minlength=n_sig)
    if order is not None:  # each signal's rows of its lowest order
        o = order[rows]
        lowest = np.full(n_sig, np.iinfo(o.dtype).max, dtype=o.dtype)
        np.minimum.at(lowest, s, o)  # fast where both are of one dtype
        keep = o == lowest[s]
        rows, s = rows[keep], s[keep]
    lead = np.full(n_sig, np.iinfo(rows.dtype).max)
    np.minimum.at(lead, s, rows)  # each signal's first row of those
    lead = lead[lead < np.iinfo(rows.dtype).max]
    mine = g[lead] < n_own
    return lead[mine], closed[sig[lead[mine]]] == 0


def exchanged(
    part: Rows,
    c: np.ndarray,
    b: np.ndarray,
    plausible: np.ndarray,
    teach: np.ndarray,
) -> tuple[np.ndarray, Cn0Counts, Exchange]:
    """The paper's exchange of ``part`` (a :class:`~.parts.Part` whose fits are done) given
    every building's fit: the rows its next fits may use (``seen``), its classifier evidence
    and the :class:`Exchange` for the next, by an update of the part's last one where few
    signals cross a building whose fit moved, else over every row."""
    last = part.exchange
    if last is None:
        return _everything(part, c, b, plausible, teach, None)
    moved = differs(c, last.c) | differs(b, last.b)
    moved |= (plausible != last.plausible) | (teach != last.teach)
    crossing = group_rows(part.g, np.flatnonzero(moved))
    if crossing.size > FULL_SHARE * part.h.size:
        return _everything(part, c, b, plausible, teach, last.by_signal)
    signals = _signals(np.r_[part.sig[crossing], last.moved], last.lead.size)
    if signals.size == 0:
        return part.seen, last.evidence, last
    by_signal = last.by_signal or _SignalRows.of(part.sig)
    rows = by_signal.of_signals(signals)
    if rows.size > FULL_SHARE * part.h.size:
        return _everything(part, c, b, plausible, teach, by_signal)
    return _update(part, c, b, plausible, teach, last, by_signal, signals, rows)


def _signals(sig: np.ndarray, n_sig: int) -> np.ndarray:
    """The distinct signals of ``sig`` (below ``n_sig``), sorted: by a mask, not a sort."""
    mask = np.zeros(n_sig, dtype=bool)
    mask[sig] = True
    return np.flatnonzero(mask)


def differs(now: np.ndarray, before: np.ndarray) -> np.ndarray:
    """Where a fit's value changed (NaN to NaN is no change)."""
    return (now != before) & ~(np.isnan(now) & np.isnan(before))


def _everything(part, c, b, plausible, teach, by_signal):
    """The exchange over every row."""
    used = part.seen & teach[part.g]
    rows = np.flatnonzero(used)
    lead, clear = counted(
        part.sig, part.order, part.g, part.n_own, rows, part.h[rows] > c[part.g[rows]]
    )
    n_sig = int(part.sig.max(initial=-1)) + 1
    lead_of = np.full(n_sig, -1, dtype=_row_type(part.h.size))
    clear_of = np.zeros(n_sig, dtype=bool)
    lead_of[part.sig[lead]], clear_of[part.sig[lead]] = lead, clear
    evidence = Cn0Counts.of(part.s[lead], clear)
    seen = part.seen
    if part.occlusion:
        seen = _unoccluded(part.h, part.g, part.sig, c, b, plausible, part.order, part.entered)
    moved = _signals(part.sig[seen != part.seen], n_sig)
    state = Exchange(c, b, plausible, teach, used, lead_of, clear_of, evidence, moved, by_signal)
    return seen, evidence, state


def _update(part, c, b, plausible, teach, last, by_signal, signals, rows):
    """The exchange of ``signals`` (their ``rows``) again; the other signals' as they were."""
    g, sig = part.g[rows], part.sig[rows]
    used = last.used.copy()
    used[rows] = part.seen[rows] & teach[g]
    mine = rows[used[rows]]
    lead, clear = counted(
        part.sig, part.order, part.g, part.n_own, mine, part.h[mine] > c[part.g[mine]]
    )
    before = last.lead[signals]
    had = before >= 0
    removed = Cn0Counts.of(part.s[before[had]], last.clear[signals][had])
    lead_of, clear_of = last.lead.copy(), last.clear.copy()
    lead_of[signals], clear_of[signals] = -1, False
    lead_of[part.sig[lead]], clear_of[part.sig[lead]] = lead, clear
    evidence = last.evidence.plus(Cn0Counts.of(part.s[lead], clear), removed)
    seen, moved = part.seen, np.empty(0, dtype=np.intp)
    if part.occlusion:
        order = None if part.order is None else part.order[rows]
        entered = None if part.entered is None else part.entered[rows]
        kept = _unoccluded(part.h[rows], g, sig, c, b, plausible, order, entered)
        moved = _signals(sig[kept != part.seen[rows]], last.lead.size)
        seen = part.seen.copy()
        seen[rows] = kept
    state = Exchange(c, b, plausible, teach, used, lead_of, clear_of, evidence, moved, by_signal)
    return seen, evidence, state
