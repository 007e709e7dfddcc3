"""A run's parts: 4PL-B's steps on some buildings' rows (DESIGN.md, "4PL-B as parts").

A run is cut into parts (:class:`Part`: some buildings' rows, a tile's or the whole run's); each
iteration, a part fits its own buildings (map, :meth:`Part.fitted`), takes the fits of the
buildings its rays also cross (:class:`Shared`, exchange) and gives its :class:`Tally`, which
the run's parts sum to refit the signal model once (reduce). :mod:`.engine` steps the parts
through the iterations, in one process or as Dask tasks. The per-building maths the steps use
(the weights, the plausibility and visibility checks, the judgement of a fit) is
:mod:`.fourplb`'s; this module imports it, never the reverse.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
import numpy.typing as npt
import pandas as pd

from ..errors import ModelError
from ..settings import Estimator
from .classifier import Cn0Counts, SignalClassifier
from .exchange import Exchange, counted, differs, exchanged, group_rows
from .fourpl import FourPLFit, fit_4pl, group_range
from .fourplb import (
    BuildingFits,
    SignalModel,
    _judge,
    _plausible,
    _unoccluded,
    height_weights,
    look_ids,
    position_margin,
)
from .interval import c_interval
from .mixture import Cn0Mixture, Cn0Moments, clear_chance, clears_all, elevation_units
from .offsets import SkyCounts
from .settling import Settling

__all__ = ["LastFit", "Part", "Shared", "Tally"]


@dataclass(frozen=True)
class Shared:
    """A part's buildings' current fits, as the other parts' rays need them (the visibility
    model, which signals are open): each building's code in the whole run (``building``),
    its 4PL ``a``, ``b``, ``c``, ``d``, and whether the fit is plausible enough to stand in
    front of others and teach the classifier (``plausible``; ``fallback``: with no separation
    asked for, for an iteration where no building in the run is plausible)."""

    building: np.ndarray
    a: np.ndarray
    b: np.ndarray
    c: np.ndarray
    d: np.ndarray
    plausible: np.ndarray
    fallback: np.ndarray


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


@dataclass(frozen=True)
class Part:
    """Some buildings' rows (a tile's, or a whole run's) and where 4PL-B stands on them.

    The part *owns* buildings ``0 .. n_own - 1`` (it fits and judges them) and also holds the
    rows of the other buildings its signals cross (codes from ``n_own``): the visibility model
    and the classifier's data need a signal's every crossing. ``building`` maps the part's
    codes to the whole run's. Rows are sorted by building then height, so the own buildings'
    rows come first and each building's rows are together (faster fits). Each step returns a
    new part and leaves this one as it was, so an engine may run a step again.
    """

    g: np.ndarray
    h: np.ndarray
    s: np.ndarray
    sd: np.ndarray | None
    receiver: np.ndarray | None
    sig: np.ndarray
    order: np.ndarray | None
    looks: np.ndarray | None
    #: Each row's elevation in the mixture's units (:func:`.mixture.elevation_units`).
    e: np.ndarray
    building: np.ndarray
    n_own: int
    estimator: Estimator
    occlusion: bool
    #: The rows the next fit uses (the visibility model's).
    seen: np.ndarray
    #: The last fit (None before the first).
    last: LastFit | None = None
    #: Each row's chance of clearing its building by the fits last exchanged (None before).
    prior: np.ndarray | None = None
    #: Each row's phone, coded into ``phones`` (:meth:`levelled`; None: not known).
    phone: np.ndarray | None = None
    phones: np.ndarray | None = None
    #: What the last exchange found (the paper's signal model), for the next (:mod:`.exchange`).
    exchange: Exchange | None = None

    @classmethod
    def of(
        cls,
        groups: npt.ArrayLike,
        height: npt.ArrayLike,
        cn0: npt.ArrayLike,
        n_groups: int,
        estimator: Estimator = Estimator(),
        *,
        n_own: int | None = None,
        building: npt.ArrayLike | None = None,
        signal: npt.ArrayLike | None = None,
        order: npt.ArrayLike | None = None,
        height_sd: npt.ArrayLike | None = None,
        receiver: npt.ArrayLike | None = None,
        track: npt.ArrayLike | None = None,
        elevation: npt.ArrayLike | None = None,
        phone: npt.ArrayLike | None = None,
    ) -> Part:
        """A part from coded rows (see :func:`fourplb`): it owns the buildings coded below
        ``n_own`` (default: all ``n_groups``), whose codes in the whole run are ``building``
        (default: their own). A part that does not own every building needs ``signal`` and
        ``order``, so that each signal is counted by one part. ``phone`` names each row's
        phone, for :meth:`levelled` (with ``elevation``)."""
        if not estimator.fourpl:
            raise ModelError(f"fourplb runs 4PL-B or 4PL, not {estimator.method}")
        n_own = n_groups if n_own is None else int(n_own)
        if n_own < n_groups and (signal is None or order is None):
            raise ModelError("a part of a run needs each row's signal and order along its ray")
        g = np.asarray(groups, dtype=np.intp)
        h = np.asarray(height, dtype=float)
        by_group = _compact(_by_group(g, h))  # a building's rows together, by height: faster fits
        g, h = _compact(g[by_group]), h[by_group]
        # the codes first, while the part has few columns: their temporaries are the set-up's
        # peak of memory
        looks = None  # found once: a row's look does not change as 4PL-B iterates
        if estimator.weighting == "looks" or (estimator.method == "4PL-B" and track is not None):
            looks = _compact(look_ids(h, g, None if track is None else np.asarray(track)[by_group]))
        phone_code, phones = _phones(phone, elevation, by_group)
        if receiver is not None:  # coded in sorted order: the same order in any part
            receiver = _compact(_factorized(receiver, by_group, sort=True)[0])
        if signal is not None:
            sig = _compact(_ranks(np.asarray(signal)[by_group]))
        else:
            sig = _compact(np.arange(g.size))  # each row is a signal of its own
        if order is not None:  # only how a ray's rows compare: ranks where not whole (NaN last)
            order = _compact(np.asarray(order)[by_group])
            if order.dtype.kind == "f":
                order = _compact(np.unique(order, return_inverse=True)[1])
        sd = None if height_sd is None else np.asarray(height_sd, dtype=float)[by_group]
        e = np.zeros(h.size) if elevation is None else elevation_units(elevation)[by_group]
        occlusion = estimator.visibility and signal is not None
        seen = np.ones(h.size, dtype=bool)
        if occlusion and order is not None:
            seen = order == 0
        return cls(
            g=g,
            h=h,
            s=np.asarray(cn0, dtype=float)[by_group],
            sd=sd,
            receiver=receiver,
            sig=sig,
            order=order,
            looks=looks,
            e=e,
            building=np.arange(n_groups) if building is None else np.asarray(building),
            n_own=n_own,
            estimator=estimator,
            occlusion=occlusion,
            seen=seen,
            phone=phone_code,
            phones=phones,
        )

    @property
    def _own(self) -> slice:
        """The own buildings' rows: the first ones."""
        return slice(0, int(np.searchsorted(self.g, self.n_own)))

    def fitted(self, model: SignalModel) -> Part:
        """Step 1 (map): every row labelled by the signal ``model`` (the paper's classifier:
        open or not; the mixture: the chance that the row's ray clears its building, given
        the fits last exchanged), the own buildings' height 4PLs fitted to the rows the
        visibility model keeps, and how many of their map labels changed."""
        own, n_own, last = self._own, self.n_own, self.last
        g, h, seen = self.g[own], self.h[own], self.seen[own]
        if isinstance(model, Cn0Mixture):
            prior = np.full(self.h.size, 0.5) if self.prior is None else self.prior
            labels = model.row_labels(self.s, self.e, prior, self.sig)
        else:  # the rows the fits use, the own seen ones: the others stay closed, unused
            labels = np.zeros(self.h.size, dtype=bool)
            rows = np.flatnonzero(seen)
            labels[rows] = model.label(self.s[rows])
        weights = None  # the paper's MLE: every seen row counts once
        use = seen
        if self.estimator.weighting != "none":
            c_now = None if last is None else last.fit.c
            looks = None if self.looks is None else self.looks[own]
            weights = height_weights(
                h, g, n_own, self.estimator.weighting, c=c_now, mask=seen, looks=looks
            )
            use = weights > 0  # rows left out weigh nothing: do not carry them through the fit
        settling = Settling.start(n_own) if last is None else last.settling
        refit = ~settling.held  # a held building keeps its fit
        if last is not None and self.estimator.weighting in _FIXED_WEIGHTS:
            refit &= _changed(g, n_own, labels[own], last.labels[own], seen, last.seen[own])
        rows = group_rows(g, np.flatnonzero(refit))  # (late on, a few buildings' rows)
        use = rows[use[rows]]
        fit = fit_4pl(
            h[use],
            labels[use],
            None if weights is None else weights[use],
            g[use],
            n_own,
            init=None if last is None else last.fit.params,
            sd=None if self.sd is None else self.sd[use],
            max_iter=self.estimator.fit_max_iter,
        )
        if last is not None:
            fit = fit.where(~refit, last.fit)
        settling = settling.after(fit.c)
        change = np.ones(n_own)
        if last is not None:  # the seen rows' map labels (above c) by this fit and the last
            moved = np.flatnonzero(differs(fit.c, last.fit.c))  # (the others' labels stay)
            rows = group_rows(g, moved)
            rows = rows[seen[rows]]
            h_seen, g_seen = h[rows], g[rows]
            flips = (h_seen > fit.c[g_seen]) != (h_seen > last.fit.c[g_seen])
            n_flips = np.bincount(g_seen[flips], minlength=n_own)
            change = np.zeros(n_own)
            change[moved] = (
                n_flips[moved] / np.maximum(np.bincount(g_seen, minlength=n_own), 1)[moved]
            )
        return replace(self, last=LastFit(fit, self.seen, labels, change, model, settling))

    def shared(self) -> Shared:
        """What the other parts need of the own buildings' fits (after :meth:`fitted`)."""
        last, own = self._last, self._own
        fit = last.fit
        seen = last.seen[own]
        lo, hi = group_range(self.h[own][seen], self.g[own][seen], self.n_own)
        min_separation = self.estimator.acceptance.min_separation
        return Shared(
            building=self.building[: self.n_own],
            a=fit.a,
            b=fit.b,
            c=fit.c,
            d=fit.d,
            plausible=_plausible(fit, lo, hi, min_separation),
            fallback=_plausible(fit, lo, hi, 0.0),
        )

    def exchanged(self, *shared: Shared) -> tuple[Part, Tally]:
        """Steps 2-3 (exchange, map): given the current fits of every building the part's rows
        cross (``shared`` by the parts that own them, this one's included), the rows the next
        fit may use, and the part's :class:`Tally`. A signal is counted by the part that owns
        the first building along its ray that the fits used it for; it is open only if its
        ray clears every building it was used for.

        Only plausible fits teach the classifier: a building whose map says nothing (flat, or
        its inflection point outside its data) would relabel its signals at random. Where no
        fit is plausible (a poor initial classifier, e.g. a low threshold labelling reflections
        open, can leave every first fit short of the separation), every map whose roof line
        lies inside its data teaches the classifier once, or co-training would stop dead.

        With the mixture signal model, each row's prior chance of clearing its building is
        its building's 4PL at the row's height (blurred by the row's position error), and the
        signals teach the model each with its chance of being open: from the map's labels
        after the first fit, from the mixture's posterior after that.
        """
        a, b, c, d, plausible, fallback = _lookup(self.building, shared)
        own_plausible = bool(plausible[: self.n_own].any())
        teach = plausible if own_plausible else fallback
        last = self._last
        change = float(np.max(last.change, initial=0.0))
        moving = last.settling.moving(np.isfinite(last.fit.c))
        if self.estimator.signal_model != "mixture":
            seen, counts, state = exchanged(self, c, b, plausible, teach)
            part = replace(self, seen=seen, exchange=state)
            return part, Tally(counts, own_plausible, change, moving)
        used = last.seen & teach[self.g]
        lead, clear = _classifier_data(self, self.h > c[self.g], used)
        prior = clear_chance(self.h, self.g, self.sd, a, b, c, d)
        chance = clear.astype(float)
        if isinstance(last.model, Cn0Mixture):
            every = clears_all(prior, self.sig)[lead]
            chance = last.model.posterior(self.s[lead], self.e[lead], every)
        evidence = Cn0Moments.of(self.s[lead], self.e[lead], chance)
        seen = self.seen
        if self.occlusion:
            seen = _unoccluded(self.h, self.g, self.sig, c, b, plausible, self.order)
        part = replace(self, seen=seen, prior=prior)
        return part, Tally(evidence, own_plausible, change, moving)

    def crossing(self) -> Cn0Moments:
        """The signals the part counts (those whose first building along the ray is one of
        its own), once each, as open: a run of parts takes them from all its signals to leave
        those that cross no footprint (:func:`run_parts`' ``open_sky``)."""
        every = np.ones(self.h.size, dtype=bool)
        lead, _ = _classifier_data(self, every, every)
        return Cn0Moments.of(self.s[lead], self.e[lead], 1.0)

    def sky_crossing(self) -> SkyCounts:
        """:meth:`crossing`'s signals counted by phone (:class:`~.offsets.SkyCounts`): a run
        of parts takes them from all its signals' to leave its open sky's, which levels the
        phones (:meth:`levelled`)."""
        if self.phone is None or self.phones is None:
            return SkyCounts.empty()
        every = np.ones(self.h.size, dtype=bool)
        lead, _ = _classifier_data(self, every, every)
        lead = lead[self.phone[lead] >= 0]
        return SkyCounts.of(self.phones[self.phone[lead]], self.s[lead], self.e[lead])

    def levelled(self, offsets: pd.Series) -> Part:
        """The part with each row's C/N0 less its phone's offset (``offsets``, by phone name:
        :meth:`~.offsets.SkyCounts.offsets`; 0 for a phone without one), before its first
        fit."""
        if self.phone is None or self.phones is None:
            return self
        level = np.append(offsets.reindex(self.phones, fill_value=0.0).to_numpy(), 0.0)
        return replace(self, s=self.s - level[self.phone])

    def judged(self, iterations: int) -> BuildingFits:
        """The own buildings' heights, ranges and statuses after ``iterations`` iterations."""
        last, own, n_own = self._last, self._own, self.n_own
        fit = last.fit
        accept = self.estimator.acceptance
        bootstrap = self.estimator.method == "4PL-B"
        g, h, labels, fit_seen = self.g[own], self.h[own], last.labels[own], last.seen[own]
        sd = None if self.sd is None else self.sd[own]
        looks = None if self.looks is None else self.looks[own]
        c_range = None
        if bootstrap:  # the paper's 4PL keeps the paper's range
            # the evidence counted as independent: each look once where the looks are known
            evidence = fit_seen.astype(float)
            if looks is not None:
                evidence = height_weights(h, g, n_own, "looks", mask=fit_seen, looks=looks)
            c_lo, c_hi = c_interval(
                fit,
                h[fit_seen],
                labels[fit_seen],
                g[fit_seen],
                weights=evidence[fit_seen],
                sd=None if sd is None else sd[fit_seen],
                reach=accept.max_uncertainty,
            )
            # the range also holds the gap a c was fixed in, and a held building's cycle
            held = last.settling
            c_range = (
                np.fmin(c_lo, np.fmin(fit.gap_lower, held.span_lower)),
                np.fmax(c_hi, np.fmax(fit.gap_upper, held.span_upper)),
            )
        margin = np.zeros(n_own)
        if sd is not None:
            rec = None if self.receiver is None else self.receiver[own][fit_seen]
            margin = position_margin(fit, g[fit_seen], h[fit_seen], sd[fit_seen], rec, n_own)
        return _judge(
            fit,
            g,
            h,
            labels,
            fit_seen,
            n_own,
            last.change,
            # the mixture's roof lines creep to the end (its loop ends on its labels)
            last.settling.settled | isinstance(last.model, Cn0Mixture),
            iterations,
            accept,
            strict=bootstrap,
            margin=margin,
            c_range=c_range,
            paper_rule=self.estimator.height_rule == "paper",
        )

    @property
    def _last(self) -> LastFit:
        if self.last is None:
            raise ModelError("a part must be fitted first (Part.fitted)")
        return self.last


@dataclass(frozen=True)
class LastFit:
    """A part's last fit of its own buildings (:meth:`Part.fitted`): the 4PLs, the rows they
    used (``seen``, all the part's rows) and the labels of the rows they used then (by the
    paper's classifier, closed elsewhere), the share of each own building's map labels (above
    ``c``) that changed from the fit before on the rows it used (``change``; 1 at the first),
    the signal ``model`` that labelled them, and where each building's roof line stands
    (``settling``)."""

    fit: FourPLFit
    seen: np.ndarray
    labels: np.ndarray
    change: np.ndarray
    #: The signal model that labelled the rows.
    model: SignalModel
    #: Which buildings' roof lines have settled, and those held in a cycle.
    settling: Settling


#: Weightings whose weights do not change with the fits: a building whose rows and labels are
#: those of its last fit has that fit again.
_FIXED_WEIGHTS = ("none", "looks")


def _changed(g, n_own, labels, last_labels, seen, last_seen) -> np.ndarray:
    """The own buildings (``g``: each own row's) with a row whose label or whose use by the
    fit (``seen``) changed since the last fit: the others' fits would be their last ones, to
    the bit where the data pin them, and are not done again (the paper's labels settle
    building by building, and most of a late iteration's fits would repeat)."""
    differ = (labels != last_labels) | (seen != last_seen)
    return np.bincount(g[differ], minlength=n_own) > 0


def _ranks(values: np.ndarray) -> np.ndarray:
    """Each value's rank among the distinct ``values`` (``pd.factorize(values, sort=True)``'s
    codes): by a table of the values where they are small whole numbers (a signal's number,
    a row of the observations: ten times faster than hashing), else by hashing."""
    if values.dtype.kind in "iu" and values.size and values.min() >= 0:
        top = int(values.max())
        if top < 4 * values.size:
            present = np.zeros(top + 1, dtype=bool)
            present[values] = True
            return (np.cumsum(present) - 1)[values]
    return pd.factorize(values, sort=True)[0]


def _compact(codes: np.ndarray) -> np.ndarray:
    """Whole-number codes (a building's, a signal's, an order along the ray) as int32 where
    they fit: a run in tiles holds every part's rows for the whole run, so 4 bytes a column
    less is memory that a national run needs (68 -> 48 bytes a row). Anything else (an order
    with gaps or fractions from a user's table) is kept as it is."""
    if codes.size == 0:
        return codes.astype(np.int32)
    whole = codes.dtype.kind in "iu" or bool(
        np.all(np.isfinite(codes) & (codes == np.floor(codes)))
    )
    if whole and -(2**31) <= codes.min() and codes.max() < 2**31:
        return codes.astype(np.int32)
    return codes


def _by_group(g: np.ndarray, h: np.ndarray) -> np.ndarray:
    """The rows sorted by building ``g``, then height ``h`` (``np.lexsort((h, g))``): by height
    then, stably, by building, whose codes sort by radix where they fit in 16 bits (faster)."""
    by_height = np.argsort(h, kind="stable")
    small = g.size == 0 or (g.min() >= 0 and g.max() < 2**15)
    return by_height[np.argsort(g[by_height].astype(np.int16 if small else g.dtype), kind="stable")]


def _phones(phone, elevation, by: np.ndarray):
    """Each row's phone (of ``phone``, rows in the order ``by``) coded into the phones' names
    (-1 where the elevation is not known: neither counted nor levelled); (None, None) without
    phones or elevations."""
    if phone is None or elevation is None:
        return None, None
    code, names = _factorized(phone, by)
    unknown = ~np.isfinite(np.asarray(elevation, dtype=float)[by])
    return np.where(unknown, -1, _compact(code)), names.astype(str).astype(object)


def _factorized(values: npt.ArrayLike, by: np.ndarray, sort: bool = False):
    """``pd.factorize(values[by], sort=sort)`` as codes (-1: missing) and names (an object
    array), hashing ``values`` as they come (a categorical by its codes, Arrow strings as
    such) and not as one Python object a row."""
    code, names = pd.factorize(pd.Series(values, copy=False))  # first appearance in ``values``
    names = np.asarray(names, dtype=object)
    if sort:
        rank = pd.factorize(names, sort=True)[0]
    else:  # in order of first appearance in ``values[by]``
        first = pd.unique(code[by])
        first = first[first >= 0]
        rank = np.empty(names.size, dtype=np.intp)
        rank[first] = np.arange(first.size)
    names = names[np.argsort(rank)]
    return np.append(rank, -1)[code[by]], names  # the last entry keeps a missing one's -1


def _lookup(building: np.ndarray, shared: Sequence[Shared]):
    """``a``, ``b``, ``c``, ``d``, ``plausible`` and ``fallback`` of each of ``building``
    (codes in the whole run) from the parts' :class:`Shared` fits."""
    if len(shared) == 1 and np.array_equal(shared[0].building, building):
        return tuple(getattr(shared[0], k) for k in _SHARED)
    known = np.concatenate([s.building for s in shared])
    at = pd.Index(known).get_indexer(building)
    if (at < 0).any():
        missing = building[at < 0][:5].tolist()
        raise ModelError(f"no part shared the fits of buildings {missing}")
    return tuple(np.concatenate([getattr(s, k) for s in shared])[at] for k in _SHARED)


_SHARED = ("a", "b", "c", "d", "plausible", "fallback")


def _classifier_data(part: Part, open_map: np.ndarray, used: np.ndarray):
    """The rows of the signals the part counts, of the rows the fits ``used``, and each
    signal's map label (:func:`~.exchange.counted`)."""
    rows = np.flatnonzero(used)
    return counted(part.sig, part.order, part.g, part.n_own, rows, open_map[rows])
