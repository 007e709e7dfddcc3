"""What the parts of a run pass between them (DESIGN.md, "4PL-B as parts"): each building's
current fit as the other parts' rays need it (:class:`Shared`, the exchange) and each part's
share of the signal model's evidence (:class:`Tally`, the reduce)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
import pandas as pd

from ..errors import ModelError
from .classifier import Cn0Counts, SignalClassifier
from .fourplb import SignalModel
from .mixture import Cn0Mixture, Cn0Moments

__all__ = ["Shared", "Tally", "lookup"]


@dataclass(frozen=True)
class Shared:
    """A part's buildings' current fits, as the other parts' rays need them (the visibility
    model, which signals are open): each building's code in the whole run (``building``),
    its 4PL ``a``, ``b``, ``c``, ``d``, and whether the fit is plausible enough to stand in
    front of others and teach the classifier (``plausible``; ``fallback``: with no separation
    asked for, for an iteration where no building in the run is plausible), and the highest
    roof line its data leave possible (``top``: ``c``, the top of the gap between its rays that
    ``c`` was fixed in or of the cycle it is held in, or its lowest open rays; inf: above every
    ray)."""

    building: np.ndarray
    a: np.ndarray
    b: np.ndarray
    c: np.ndarray
    d: np.ndarray
    plausible: np.ndarray
    fallback: np.ndarray
    top: np.ndarray


@dataclass(frozen=True)
class Tally:
    """A part's share of an iteration's reduce: what its signals teach the signal model
    (``evidence``: those that plausible fits used, or, where the part has no plausible fit, the
    ``fallback``'s; counted by C/N0 and map label for the paper's classifier, summed by class
    for the mixture; None: nothing, e.g. a failed tile's), whether it has a plausible fit, and
    its buildings' largest share of changed labels and how many of its buildings' roof lines
    have not settled (:class:`~.settling.Settling`). Parts add up, exactly."""

    evidence: Cn0Counts | Cn0Moments | None
    plausible: bool
    change: float
    moving: int = 0

    def __add__(self, other: Tally) -> Tally:
        """Both parts' tallies: where any building is plausible only plausible fits teach (the
        others' counts are their fallbacks'), else every fallback does."""
        change = max(self.change, other.change)
        moving = self.moving + other.moving
        if self.plausible != other.plausible:
            return replace(self if self.plausible else other, change=change, moving=moving)
        if self.evidence is None or other.evidence is None:
            return replace(other if self.evidence is None else self, change=change, moving=moving)
        evidence = self.evidence + other.evidence  # type: ignore[operator]
        return Tally(evidence, self.plausible, change, moving)

    def refit(self, model: SignalModel) -> SignalModel:
        """The signal model refitted to the run's evidence."""
        if self.evidence is None:
            return model
        if isinstance(self.evidence, Cn0Moments):
            return Cn0Mixture.fitted(self.evidence)
        if not isinstance(model, SignalClassifier):
            raise ModelError("the paper's counts refit the paper's classifier only")
        return model.refit_counts(self.evidence)


#: What :func:`lookup` gives of each building, in order.
SHARED = ("a", "b", "c", "d", "plausible", "fallback", "top")


def lookup(building: np.ndarray, shared: Sequence[Shared]) -> tuple[np.ndarray, ...]:
    """``a``, ``b``, ``c``, ``d``, ``plausible`` and ``fallback`` of each of ``building``
    (codes in the whole run) from the parts' :class:`Shared` fits."""
    if len(shared) == 1 and np.array_equal(shared[0].building, building):
        return tuple(getattr(shared[0], k) for k in SHARED)
    known = np.concatenate([s.building for s in shared])
    at = pd.Index(known).get_indexer(building)
    if (at < 0).any():
        missing = building[at < 0][:5].tolist()
        raise ModelError(f"no part shared the fits of buildings {missing}")
    return tuple(np.concatenate([getattr(s, k) for s in shared])[at] for k in SHARED)
