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

from dataclasses import dataclass, replace

import numpy as np
import numpy.typing as npt
import pandas as pd

from ..errors import ModelError
from ..settings import Estimator
from .blame import MIN_WEIGHT, blamed, cleared, others_clear
from .exchange import Exchange, counted, differs, exchanged, group_rows
from .fourpl import X_TOL, FourPLFit, fit_4pl, group_range
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
from .refits import FIXED_WEIGHTS, changed, shown_fits
from .row_codes import building_order, compact, factorized, phone_codes, ranks, ray_order
from .settling import Settling
from .shares import Shared, Tally, lookup

__all__ = ["LastFit", "Part"]

#: Most refits of a building in one iteration of 4PL-B for its roof line to agree with the
#: blame its own fit gives its rows (:meth:`Part._self_consistent`); one that has not agreed
#: by then goes on from there in the next iteration.
SELF_ROUNDS = 10
#: The share of a building's open rays that may pass below its roof (reflections the signal
#: model takes for open): its lowest open rays bound how tall it may be (:meth:`Part.shared`).
OPEN_FLOOR = 0.05


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
    #: With whole-ray blame, each row's chance of clearing its building were that building as
    #: tall as its data leave possible and opaque below (:meth:`_tall`; None before the first
    #: exchange).
    tall: np.ndarray | None = None
    #: With whole-ray blame, the rows by signal and order along the ray
    #: (:func:`.blame.others_clear`; None: without an order, in the rows' order).
    along: np.ndarray | None = None
    #: Each row's chance that its ray crosses its building, given its receiver's position
    #: error (the intersections' ``crossing``; None: every ray crosses its buildings).
    crosses: np.ndarray | None = None
    #: Which rows' rays enter their building (None: all); the others pass near it.
    entered: np.ndarray | None = None

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
        crossing: npt.ArrayLike | None = None,
    ) -> Part:
        """A part from coded rows (see :func:`fourplb`): it owns the buildings coded below
        ``n_own`` (default: all ``n_groups``), whose codes in the whole run are ``building``
        (default: their own). A part that does not own every building needs ``signal`` and
        ``order``, so that each signal is counted by one part. ``phone`` names each row's
        phone, for :meth:`levelled` (with ``elevation``). ``crossing`` is each row's chance
        that its ray crosses its building; a row of a footprint the ray passes near without
        entering it (its ``order`` below 0, only with whole-ray blame) comes after every
        building the ray enters."""
        if not estimator.fourpl:
            raise ModelError(f"fourplb runs 4PL-B or 4PL, not {estimator.method}")
        n_own = n_groups if n_own is None else int(n_own)
        if n_own < n_groups and (signal is None or order is None):
            raise ModelError("a part of a run needs each row's signal and order along its ray")
        g = np.asarray(groups, dtype=np.intp)
        h = np.asarray(height, dtype=float)
        by_group = compact(building_order(g, h))  # a building's rows together: faster fits
        g, h = compact(g[by_group]), h[by_group]
        # the codes first, while the part has few columns: their temporaries are the set-up's
        # peak of memory
        looks = None  # found once: a row's look does not change as 4PL-B iterates
        if estimator.weighting == "looks" or (estimator.method == "4PL-B" and track is not None):
            looks = compact(look_ids(h, g, None if track is None else np.asarray(track)[by_group]))
        phone_code, phones = phone_codes(phone, elevation, by_group)
        if receiver is not None:  # coded in sorted order: the same order in any part
            receiver = compact(factorized(receiver, by_group, sort=True)[0])
        if signal is not None:
            sig = compact(ranks(np.asarray(signal)[by_group]))
        else:
            sig = compact(np.arange(g.size))  # each row is a signal of its own
        order, entered = ray_order(order, by_group, sig, h)
        sd = None if height_sd is None else np.asarray(height_sd, dtype=float)[by_group]
        e = np.zeros(h.size) if elevation is None else elevation_units(elevation)[by_group]
        occlusion = estimator.visibility and signal is not None
        seen = np.ones(h.size, dtype=bool)
        along = None
        if occlusion and order is not None:
            seen = order == 0
            if estimator.blame == "ray":
                along = compact(np.lexsort((order, sig)))
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
            along=along,
            crosses=None if crossing is None else np.asarray(crossing, dtype=float)[by_group],
            entered=entered,
        )

    @property
    def _own(self) -> slice:
        """The own buildings' rows: the first ones."""
        return slice(0, int(np.searchsorted(self.g, self.n_own)))

    def fitted(self, model: SignalModel) -> Part:
        """Step 1 (map): every row labelled by the signal ``model`` (the paper's classifier:
        open or not; the mixture: the chance that the row's ray clears its building, given
        the fits last exchanged), the own buildings' height 4PLs fitted to the rows the
        visibility model keeps, each by its chance of crossing its building where that is known
        (with whole-ray blame, every row weighted by the chance that its building alone blocks
        it, :mod:`.blame`), and how many of their map labels changed."""
        own, n_own, last = self._own, self.n_own, self.last
        g, h = self.g[own], self.h[own]
        rest = None  # with whole-ray blame: each own row's chance of clearing the others
        if self._blames and self.prior is not None and last is not None:
            rest = others_clear(cleared(self.prior, self.crosses), self.sig, self.along)[own]
            labels, blame = self._blame(model, rest, last.fit)
        else:
            labels, blame = self._labels(model), None
        seen = self.seen[own] if blame is None else blame[own] >= MIN_WEIGHT
        weights = None if blame is None else blame[own]  # the paper's MLE: each row once
        if blame is None and self.crosses is not None:  # each row by its chance of crossing
            weights = np.where(seen, self.crosses[own], 0.0)
        reweighted = None
        if self.estimator.weighting != "none":
            c_now = None if last is None else last.fit.c
            looks = None if self.looks is None else self.looks[own]
            reweighted = height_weights(
                h, g, n_own, self.estimator.weighting, c=c_now, mask=seen, looks=looks
            )
            weights = reweighted if weights is None else reweighted * weights
        use = seen if weights is None else weights > 0  # rows left out weigh nothing
        settling = Settling.start(n_own) if last is None else last.settling
        refit = ~settling.held  # a held building keeps its fit
        if last is not None and self.estimator.weighting in FIXED_WEIGHTS:
            before = last.seen if last.weight is None else last.weight
            now = self.seen if blame is None else blame
            refit &= changed(g, n_own, labels[own], last.labels[own], now[own], before[own])
        rows = group_rows(g, np.flatnonzero(refit))  # (late on, a few buildings' rows)
        use = rows[use[rows]]
        fit = self._fit(h, labels, weights, g, use, None if last is None else last.fit.params)
        if last is not None:
            fit = fit.where(~refit, last.fit)
        if rest is not None:
            fit, labels, blame = self._self_consistent(model, fit, refit, reweighted, rest)
            seen = blame[own] >= MIN_WEIGHT
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
        shown = None
        if blame is not None:
            shown = (
                fit.params if last is None or last.shown is None else shown_fits(fit, last.shown)
            )
        last = LastFit(fit, self.seen, labels, change, model, settling, blame, shown)
        return replace(self, last=last)

    @property
    def _blames(self) -> bool:
        """Whether the fits blame closed rays on the buildings along them (:mod:`.blame`)."""
        return self.occlusion and self.estimator.blame == "ray"

    def _fit(self, h, labels, weights, g, use, init) -> FourPLFit:
        """The own buildings' 4PLs fitted to the rows ``use`` of the own rows."""
        return fit_4pl(
            h[use],
            labels[use],
            None if weights is None else weights[use],
            g[use],
            self.n_own,
            init=init,
            sd=None if self.sd is None else self.sd[use],
            max_iter=self.estimator.fit_max_iter,
        )

    def _self_consistent(
        self,
        model: SignalModel,
        fit: FourPLFit,
        refit: np.ndarray,
        reweighted: np.ndarray | None,
        rest: np.ndarray,
    ) -> tuple[FourPLFit, np.ndarray, np.ndarray]:
        """With whole-ray blame, the ``refit`` buildings' fits again until each one's roof
        line moves by at most :data:`~.fourpl.X_TOL` (at most :data:`SELF_ROUNDS` times),
        each own row's blame (:meth:`_blame`, ``rest``) reweighed by its own building's fit
        just made (the other buildings along its ray as last exchanged, so that which
        buildings a part holds changes nothing), and the labels and blame weights they end
        with.

        A closed ray's weight for a building depends on the building's own fit: fitted against
        its last fit's weights, a roof line crept a few per cent of the way to agreeing each
        iteration, and the loop ran to its cap (the sample city's last building moved 7 mm at
        the 30th); agreeing within each fit, it settles at 10."""
        own = self._own
        g, h = self.g[own], self.h[own]
        moved = refit
        for _ in range(SELF_ROUNDS):
            labels, blame = self._blame(model, rest, fit)
            if not moved.any():
                break
            weights = blame[own] if reweighted is None else reweighted * blame[own]
            rows = group_rows(g, np.flatnonzero(moved))
            use = rows[(weights > 0)[rows] & (blame[own] >= MIN_WEIGHT)[rows]]
            again = self._fit(h, labels, weights, g, use, fit.params).where(~moved, fit)
            moved = np.abs(again.c - fit.c) > X_TOL
            fit = again
        return fit, labels, blame

    def _blame(
        self, model: SignalModel, rest: np.ndarray, fit: FourPLFit | None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Whole-ray blame's labels and weights (:func:`.blame.blamed`; rows of the part,
        filled for the own ones): each own row clears its building with the chance its
        ``fit`` gives (None: as last exchanged) and the other buildings along its ray with
        the chance ``rest`` (each crossing its own with its chance of crossing); it is open
        by the signal ``model`` (the paper's classifier's label, the mixture's posterior of
        clearing them all)."""
        own = self._own
        if fit is None:
            p = np.asarray(self.prior)[own]
        else:
            sd = None if self.sd is None else self.sd[own]
            p = clear_chance(self.h[own], self.g[own], sd, fit.a, fit.b, fit.c, fit.d)
        crossing = None if self.crosses is None else self.crosses[own]
        if isinstance(model, Cn0Mixture):
            rho = model.posterior(self.s[own], self.e[own], cleared(p, crossing) * rest)
        else:
            rho = model.label(self.s[own]).astype(float)
        labels, blame = np.zeros(self.h.size), np.zeros(self.h.size)
        labels[own], blame[own] = blamed(rho, p, rest, crossing)
        return labels, blame

    def _labels(self, model: SignalModel) -> np.ndarray:
        """Every row's label by the signal ``model`` without whole-ray blame: the paper's
        classifier's on the own rows the visibility model keeps (the others closed, unused);
        the mixture's chance that the row's ray clears its building, given the fits last
        exchanged."""
        if isinstance(model, Cn0Mixture):
            prior = np.full(self.h.size, 0.5) if self.prior is None else self.prior
            return model.row_labels(self.s, self.e, prior, self.sig)
        labels = np.zeros(self.h.size, dtype=bool)
        rows = np.flatnonzero(self.seen[self._own])
        labels[rows] = model.label(self.s[rows])
        return labels

    def shared(self) -> Shared:
        """What the other parts need of the own buildings' fits (after :meth:`fitted`)."""
        last, own = self._last, self._own
        fit = last.fit
        seen = last.counted[own]
        lo, hi = group_range(self.h[own][seen], self.g[own][seen], self.n_own)
        min_separation = self.estimator.acceptance.min_separation
        a, b, c, d = (fit.a, fit.b, fit.c, fit.d) if last.shown is None else last.shown.T
        return Shared(
            building=self.building[: self.n_own],
            a=a,
            b=b,
            c=c,
            d=d,
            plausible=_plausible(fit, lo, hi, min_separation),
            fallback=_plausible(fit, lo, hi, 0.0),
            top=np.fmax(
                np.fmax(c, self._open_floor()), np.fmax(fit.gap_upper, last.settling.span_upper)
            ),
        )

    def _open_floor(self) -> np.ndarray:
        """Each own building's lowest open rays (the :data:`OPEN_FLOOR` quantile of the heights
        of the rows its last fit counted as clearing it; NaN: none): a roof may stand up to
        there whatever its fit says (one whose closed rays whole-ray blame gave a neighbour
        has them all open, and a roof line far below them)."""
        last, own = self._last, self._own
        rows = np.flatnonzero(last.counted[own] & (last.labels[own] >= 0.5))
        g = self.g[own][rows]  # sorted by building, then height
        n_open = np.bincount(g, minlength=self.n_own)
        start = np.searchsorted(g, np.arange(self.n_own))
        k = start + np.maximum(np.ceil(OPEN_FLOOR * n_open).astype(np.intp), 1) - 1
        floor = np.full(self.n_own, np.nan)
        some = n_open > 0
        floor[some] = self.h[own][rows[k[some]]]
        return floor

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
        a, b, c, d, plausible, fallback, top = lookup(self.building, shared)
        own_plausible = bool(plausible[: self.n_own].any())
        teach = plausible if own_plausible else fallback
        last = self._last
        change = float(np.max(last.change, initial=0.0))
        moving = last.settling.moving(np.isfinite(last.fit.c))
        if self.estimator.signal_model != "mixture":
            seen, counts, state = exchanged(self, c, b, plausible, teach)
            prior = tall = None
            if self._blames:
                prior = clear_chance(self.h, self.g, self.sd, a, b, c, d)
                tall = self._tall(a, b, top)
            part = replace(self, seen=seen, exchange=state, prior=prior, tall=tall)
            return part, Tally(counts, own_plausible, change, moving)
        used = last.seen & teach[self.g]
        lead, clear = _classifier_data(self, self.h > c[self.g], used)
        prior = clear_chance(self.h, self.g, self.sd, a, b, c, d)
        chance = clear.astype(float)
        if isinstance(last.model, Cn0Mixture):
            ray_prior = cleared(prior, self.crosses) if self._blames else prior
            every = clears_all(ray_prior, self.sig)[lead]
            chance = last.model.posterior(self.s[lead], self.e[lead], every)
        evidence = Cn0Moments.of(self.s[lead], self.e[lead], chance)
        seen = self.seen
        if self.occlusion:
            seen = _unoccluded(self.h, self.g, self.sig, c, b, plausible, self.order, self.entered)
        tall = self._tall(a, b, top) if self._blames else None
        part = replace(self, seen=seen, prior=prior, tall=tall)
        return part, Tally(evidence, own_plausible, change, moving)

    def _tall(self, a: np.ndarray, b: np.ndarray, top: np.ndarray) -> np.ndarray:
        """Each row's chance of clearing its building were that building as tall as its data
        leave possible (``top``) and opaque below its roof line (``d`` 0): what a neighbour's
        range takes it for (:meth:`judged`)."""
        return clear_chance(self.h, self.g, self.sd, a, b, top, np.zeros_like(top))

    def crossing(self) -> Cn0Moments:
        """The signals the part counts (those whose first building along the ray is one of
        its own), once each, as open: a run of parts takes them from all its signals to leave
        those that enter no footprint (:func:`run_parts`' ``open_sky``)."""
        lead = self._leads()
        return Cn0Moments.of(self.s[lead], self.e[lead], 1.0)

    def sky_crossing(self) -> SkyCounts:
        """:meth:`crossing`'s signals counted by phone (:class:`~.offsets.SkyCounts`): a run
        of parts takes them from all its signals' to leave its open sky's, which levels the
        phones (:meth:`levelled`)."""
        if self.phone is None or self.phones is None:
            return SkyCounts.empty()
        lead = self._leads()
        lead = lead[self.phone[lead] >= 0]
        return SkyCounts.of(self.phones[self.phone[lead]], self.s[lead], self.e[lead])

    def _leads(self) -> np.ndarray:
        """The first row of each signal the part counts, of the rows whose rays enter their
        building (a ray that only passes near one is in the open sky as far as the map
        knows)."""
        every = np.ones(self.h.size, dtype=bool) if self.entered is None else self.entered
        return _classifier_data(self, every, every)[0]

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
        g, h, labels, fit_seen = self.g[own], self.h[own], last.labels[own], last.counted[own]
        sd = None if self.sd is None else self.sd[own]
        looks = None if self.looks is None else self.looks[own]
        c_range = None
        if bootstrap:  # the paper's 4PL keeps the paper's range
            # the rows the fit used (with whole-ray blame, weighed with the other buildings as
            # tall as their data leave possible), each look counted once where the looks are
            # known: the evidence counted as independent
            used, evidence, told = fit_seen, fit_seen.astype(float), labels
            if self.crosses is not None:
                evidence = evidence * self.crosses[own]
            if last.weight is not None:  # closed rays as far as no other building may block
                tall = cleared(np.asarray(self.tall), self.crosses)
                tall = others_clear(tall, self.sig, self.along)[own]
                robust, weight = self._blame(last.model, tall, None)
                told, evidence = robust[own], weight[own]
                used = evidence >= MIN_WEIGHT
            if looks is not None:
                evidence = evidence * height_weights(h, g, n_own, "looks", mask=used, looks=looks)
            c_lo, c_hi = c_interval(
                fit,
                h[used],
                told[used],
                g[used],
                weights=evidence[used],
                sd=None if sd is None else sd[used],
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
    #: Each row's weight in the fit by whole-ray blame (:mod:`.blame`; None: ``seen`` rows
    #: once each).
    weight: np.ndarray | None = None
    #: With whole-ray blame, the 4PLs ``(a, b, c, d)`` shown to the other buildings' blame
    #: (:func:`shown`; None: the fits themselves).
    shown: np.ndarray | None = None

    @property
    def counted(self) -> np.ndarray:
        """The rows that count as the fit's data for its checks (how many signals, which
        heights, how many below the roof line are seen): those it used, or with whole-ray
        blame those it weighed at least half."""
        return self.seen if self.weight is None else self.weight >= 0.5


def _classifier_data(part: Part, open_map: np.ndarray, used: np.ndarray):
    """The rows of the signals the part counts, of the rows the fits ``used``, and each
    signal's map label (:func:`~.exchange.counted`)."""
    rows = np.flatnonzero(used)
    return counted(part.sig, part.order, part.g, part.n_own, rows, open_map[rows])
