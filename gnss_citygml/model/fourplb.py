"""4PL-B: the bootstrapped four-parameter logistic building-height estimator (Algorithm 1).

For every building, a 4PL in intersection height (the *map classifier*) is fitted to signals
labelled by a C/N0 *signal classifier*; the signals are then relabelled by the map (open where
the intersection height is above the fitted inflection point ``c``), the signal classifier is
refitted to those labels, and the loop repeats until fewer than 1 % of the map labels change or
10 iterations have run. The paper's height estimate is ``c + 1.5/b`` with range
``(c, c + 3/b)``; by default the height is ``c`` itself (``Estimator.height_rule``), with the
transition's range ``(c - 1.5/b, c + 1.5/b)`` around it: where a roof edge is blurred alike
above and below (by position errors, by diffraction), ``c`` is on it.

Beyond the paper, the range is stretched over every roof line the data fit about as well as
``c`` (:func:`~.fourpl.c_interval`, a 95 % likelihood-ratio interval): a building seen only
below and far above its roof (a few satellites from a few places) fits any ``c`` in between,
and the paper's range, as wide as the transition, then claimed a precision the data do not
have (the truth was inside it for 16 % of the converged buildings of street scenes, issue 14).
The interval counts each *look* once (:func:`look_ids`: one recording's view of one satellite
within a metre of height): a phone at 1 Hz repeats one ray's geometry, its position error and
its multipath fading (which a static phone's reflections keep for minutes) epoch after epoch,
so its rows are not independent evidence of where the roof line is.

The signal classifier belongs to a dataset (one device): in a run over many buildings it is
co-trained on all buildings' relabelled signals at once, while each building keeps its own
height 4PL. When the table says which rows are the same signal (``signal``), a signal is
labelled open only when its ray clears every building it crosses.

Beyond the paper (``estimator.signal_model = "mixture"``): the signal model may be the
generative :class:`~.mixture.Cn0Mixture` instead of the threshold. Each building's 4PL is then
the prior chance that a ray clears it, the rows carry soft labels (each ray's chance of clearing
its building given its C/N0 and elevation and every building along it), and the classes are
refitted to the signals weighted by them, with the rays that cross no footprint as open ones
(``open_sky``); the loop also waits for the mixture to settle.

Beyond the paper: the height fit can reweight the data by the distribution of intersection
heights (``weighting``), as the paper's discussion proposes for buildings seen mostly from one
side of their roof line (a canyon where nearly all signals are blocked, a terrace where nearly
all are open). Measured on the simulated sites, neither reweighting beat the paper's unweighted
MLE once every fit starts from its likeliest step (DESIGN.md, "Design notes"), so ``none`` is
the default.
A visibility model (``signal`` and ``order``) leaves out, for each building, the signals that
another building blocks. Given how far each intersection height may be off from its receiver's
position error (``height_sd``), the height fits model that error, as the paper's discussion
plans ("modelling location error"): ``b`` is then the sharpness of the roof line itself, not
of the blur that position errors add, and the range carries the roof line's own position
uncertainty (:func:`position_margin`).
"""

from __future__ import annotations

import functools
import operator
from collections.abc import Callable, Sequence
from dataclasses import dataclass, fields, replace
from typing import Any, Protocol

import numpy as np
import numpy.typing as npt
import pandas as pd

from ..errors import ModelError
from ..settings import WEIGHTINGS, Estimator
from .classifier import Cn0Counts, SignalClassifier
from .fourpl import B_BOUNDS, FourPLFit, c_interval, fit_4pl, group_range
from .mixture import Cn0Mixture, Cn0Moments, clear_chance, clears_all, elevation_units

#: What labels the signals: the paper's C/N0 threshold, or the mixture (:mod:`.mixture`).
SignalModel = SignalClassifier | Cn0Mixture

__all__ = [
    "BuildingFits",
    "Engine",
    "InProcess",
    "Part",
    "Shared",
    "Tally",
    "fourplb",
    "height_weights",
    "look_ids",
    "position_margin",
    "run_parts",
]

#: With the visibility model, at least this fraction of the signals crossing a building below
#: its fitted roof line must be unblocked by other buildings; otherwise the lower edge of the
#: remaining data is where the buildings in front end, not where this one does.
MIN_VISIBLE = 0.1

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
    #: The paper's height ``c + 1.5/b`` (NaN where not converged), whichever rule ``height`` is.
    height_paper: np.ndarray

    def columns(self) -> dict[str, np.ndarray]:
        """The columns of the heights table (:data:`~.estimate.HEIGHTS_COLUMNS`) these fits
        give, by name."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


def height_weights(
    height: np.ndarray,
    groups: np.ndarray,
    n_groups: int,
    scheme: str,
    c: np.ndarray | None = None,
    mask: np.ndarray | None = None,
    looks: np.ndarray | None = None,
) -> np.ndarray:
    """Sample weights of the height fit, normalised to a mean of 1 within each building
    (``looks``: to its number of looks).

    Rows outside ``mask`` (default: all rows are in) get weight 0.

    ``none``
        Every signal counts once (the paper's MLE).
    ``height``
        Inverse density of intersection heights in :data:`HEIGHT_BIN` bins, so that each metre
        of height counts the same whatever the number of signals that happen to cross it.
        A bin's count is floored at the building's mean count per occupied bin, so that a
        sparsely crossed height does not weigh more than an average one.
    ``balanced``
        Signals above and below the current inflection point ``c`` carry equal total weight.
    ``looks``
        Each *look* counts once (``looks``: each row's look, :func:`look_ids`; default: a
        building's rows within one :data:`HEIGHT_BIN` are one look).
    """
    height = np.asarray(height, dtype=float)
    groups = np.asarray(groups, dtype=np.intp)
    mask = np.ones(height.size, dtype=bool) if mask is None else np.asarray(mask, dtype=bool)
    out = np.zeros(height.size)
    if scheme == "looks":
        ids = look_ids(height, groups) if looks is None else np.asarray(looks)
        rows = np.bincount(ids[mask])
        out[mask] = 1.0 / rows[ids[mask]]
        return out
    out[mask] = _weights(height[mask], groups[mask], n_groups, scheme, c)
    return out


def look_ids(
    height: np.ndarray, groups: np.ndarray, track: npt.ArrayLike | None = None
) -> np.ndarray:
    """Each row's *look* (a code from 0): a building's rows of one ``track`` (one recording's
    view of one satellite, any hashable codes; default: all rows one track) within one
    :data:`HEIGHT_BIN` of height.

    A phone logging at 1 Hz repeats the same ray geometry, and the same position error, for
    minutes: 300 epochs of one satellite from one standing point are one piece of geometric
    evidence, not 300. Counted as 300, a ray clipping a footprint's corner or one reflection
    outweighs the rest, and the likelihood interval of ``c`` is far too narrow.
    """
    bins = np.floor(np.asarray(height, dtype=float) / HEIGHT_BIN).astype(np.int64)
    bins -= bins.min(initial=0)
    tracks = np.zeros(bins.size, np.int64) if track is None else pd.factorize(np.asarray(track))[0]
    # codes of (track, bin), then of (building, that): each below the number of rows, so the
    # int64 keys cannot overflow, and hashing one int64 column is fast
    pair = pd.factorize(tracks * (int(bins.max(initial=0)) + 1) + bins)[0]
    building = np.asarray(groups, dtype=np.int64)
    return pd.factorize(building * (int(pair.max(initial=0)) + 1) + pair)[0]


def _weights(height, groups, n_groups, scheme, c):
    n = np.bincount(groups, minlength=n_groups).astype(float)
    if scheme == "none" or (scheme == "balanced" and c is None) or height.size == 0:
        return np.ones_like(height)
    if scheme == "height":
        bins = np.floor(height / HEIGHT_BIN).astype(np.int64)
        key = groups.astype(np.int64) * (1 << 32) + (bins - bins.min())
        _, first, inverse, counts = np.unique(
            key, return_index=True, return_inverse=True, return_counts=True
        )
        occupied = np.bincount(groups[first], minlength=n_groups)
        floor = n / np.maximum(occupied, 1)
        raw = 1.0 / np.maximum(counts[inverse], floor[groups])
    elif scheme == "balanced":
        above = height > np.asarray(c)[groups]
        n_above = np.bincount(groups, weights=above.astype(float), minlength=n_groups)
        n_below = n - n_above
        raw = np.where(
            above, 1.0 / np.maximum(n_above, 1)[groups], 1.0 / np.maximum(n_below, 1)[groups]
        )
    else:
        raise ValueError(f"unknown weighting {scheme!r}; use one of {', '.join(WEIGHTINGS)}")
    total = np.bincount(groups, weights=raw, minlength=n_groups)
    return raw * (n / np.maximum(total, 1e-300))[groups]


def fourplb(
    groups: npt.ArrayLike,
    height: npt.ArrayLike,
    cn0: npt.ArrayLike,
    n_groups: int,
    estimator: Estimator = Estimator(),
    *,
    signal: npt.ArrayLike | None = None,
    order: npt.ArrayLike | None = None,
    height_sd: npt.ArrayLike | None = None,
    receiver: npt.ArrayLike | None = None,
    track: npt.ArrayLike | None = None,
    elevation: npt.ArrayLike | None = None,
    open_sky: Cn0Moments | None = None,
) -> tuple[BuildingFits, SignalModel]:
    """Run 4PL-B (or, for method ``4PL``, the paper's one-shot 4PL) on coded arrays.

    Parameters
    ----------
    groups
        Building code of each row, in ``[0, n_groups)``.
    height, cn0
        Intersection height (m) and C/N0 (dB-Hz, NaN = blocked) of each row.
    n_groups
        Number of buildings.
    estimator
        The settings (:class:`~gnss_citygml.settings.Estimator`, method 4PL-B or 4PL): the
        initial threshold, the reweighting of the height fit (:func:`height_weights`), the
        visibility model, the iteration cap and what a converged estimate must satisfy. With
        ``visibility`` and ``signal``, a building leaves out the rows whose ray another building
        blocks (at the current estimates): such a signal says nothing about it; the first fit
        uses only the first building along each ray (needs ``order``). The loop stops after
        ``max_iter`` iterations or when fewer than ``acceptance.label_tol`` of every building's
        map labels change between two iterations. Method ``4PL`` runs a single pass (label by
        the initial classifier, fit, stop), which, as in the paper, always returns the fitted
        height when the optimiser converged on data of both classes; the plausibility checks of
        4PL-B are not applied to it.
    signal, order
        Optional signal code of each row (rows of one signal crossing several buildings) and
        the row's position along its ray (0 = first building crossed).
    height_sd, receiver
        Optional standard deviation (m) of each row's intersection height owing to its
        receiver's position error, and the row's recording (any hashable codes). With
        ``height_sd`` the height 4PLs model that error (errors in variables, see
        :mod:`.fourpl`), so ``b`` is the sharpness of the roof line itself, and the range is
        widened by :func:`position_margin` for the part of the error no fit averages away
        (``acceptance.max_uncertainty`` then bounds the widened range).
    track
        Optional look track of each row (one recording's view of one satellite,
        :func:`look_ids`).
    elevation, open_sky
        Optional elevation (deg) of each row's satellite, and the signals whose rays cross no
        footprint (:func:`~.estimate.open_sky_moments`): the mixture signal model
        (``estimator.signal_model = "mixture"``) learns how C/N0 changes with elevation, and
        what open signals look like.

    Returns
    -------
    (BuildingFits, SignalClassifier or Cn0Mixture)
        The per-building fits and the final signal model.
    """
    part = Part.of(
        groups,
        height,
        cn0,
        n_groups,
        estimator,
        signal=signal,
        order=order,
        height_sd=height_sd,
        receiver=receiver,
        track=track,
        elevation=elevation,
    )
    (fits,), model = run_parts([part], [[0]], estimator, open_sky=open_sky)
    return fits, model


class Engine(Protocol):
    """Where :func:`run_parts` runs each step: :class:`InProcess`, or a Dask cluster
    (:class:`gnss_citygml.cluster.DaskEngine`, whose ``submit`` returns futures that later
    steps take). ``key`` names a step (``fit-3-TQ2982``) for the engine's progress and
    errors."""

    def submit(self, func: Callable[..., Any], *args: Any, key: str | None = None) -> Any: ...

    def gather(self, futures: Any) -> Any: ...

    def failures(self, futures: Sequence[Any]) -> dict[int, str]: ...


class InProcess:
    """The :class:`Engine` of a single process: each step runs when submitted."""

    def submit(self, func: Callable[..., Any], *args: Any, key: str | None = None) -> Any:
        """``func(*args)``."""
        return func(*args)

    def gather(self, futures: Any) -> Any:
        """The values themselves."""
        return futures

    def failures(self, futures: Sequence[Any]) -> dict[int, str]:
        """None: a step that fails raises as it runs."""
        return {}


#: Tallies summed per task of :func:`run_parts`'s reduce: a tree, not one task of every part.
_FAN_IN = 32


def run_parts(
    parts: Sequence[Any],
    neighbours: Sequence[Sequence[int]],
    estimator: Estimator = Estimator(),
    engine: Engine | None = None,
    progress: Callable[[int], None] | None = None,
    finish: Callable[[Part, int], Any] | None = None,
    names: Sequence[str] | None = None,
    open_sky: Cn0Moments | None = None,
) -> tuple[list[Any], SignalModel]:
    """4PL-B over a run cut into parts (:class:`Part`, or an engine's futures of them), with
    the single process's result: the map / exchange / reduce of DESIGN.md.

    Each iteration, every part relabels its rows with the shared classifier and fits its own
    buildings (:meth:`Part.fitted`); then takes the fits of the buildings its rays also cross
    from the parts that own them (``neighbours[i]``: the parts whose buildings part ``i``'s
    rays cross, itself included), updates its visibility model and counts its signals for the
    classifier (:meth:`Part.exchanged`); the counts are summed and refit the classifier once
    (:class:`Tally`), and the largest change of labels decides whether to go on. ``progress``
    is told each iteration's number as it ends. Returns what ``finish(part, iterations)``
    gives of each part (default: its :class:`BuildingFits`, :meth:`Part.judged`), as the
    engine's handles (the values themselves in one process; futures on a cluster, left
    where they were made: gather them, or pass them on), and the classifier. ``names`` (one per
    part, e.g. its tile's) name the steps for the engine. ``open_sky``: the run's signals
    whose rays cross no footprint, which the mixture signal model learns open signals from.
    A part may be anything with :class:`Part`'s steps, e.g. a failed tile's stand-in
    (:class:`gnss_citygml.tiled.FailedTile`).
    """
    engine = engine or InProcess()
    bootstrap = estimator.method == "4PL-B"
    model: SignalModel = SignalClassifier.initial(estimator.init_threshold)
    if estimator.signal_model == "mixture" and open_sky is not None and open_sky.seen:
        model = Cn0Mixture.initial(open_sky)
    iterations = 0
    names = [str(k) for k in range(len(parts))] if names is None else list(names)
    for iterations in range(1, (estimator.max_iter if bootstrap else 1) + 1):
        parts = [
            engine.submit(_fitted, p, model, key=f"fit-{iterations}-{name}")
            for p, name in zip(parts, names, strict=True)
        ]
        if not bootstrap:
            break
        shared = [
            engine.submit(_shared, p, key=f"share-{iterations}-{name}")
            for p, name in zip(parts, names, strict=True)
        ]
        steps = [
            engine.submit(
                _exchanged, p, *(shared[j] for j in near), key=f"exchange-{iterations}-{name}"
            )
            for p, near, name in zip(parts, neighbours, names, strict=True)
        ]
        parts = [
            engine.submit(_first, step, key=f"part-{iterations}-{name}")
            for step, name in zip(steps, names, strict=True)
        ]
        tallies = [
            engine.submit(_second, step, key=f"tally-{iterations}-{name}")
            for step, name in zip(steps, names, strict=True)
        ]
        level = 0
        while len(tallies) > 1:
            level += 1
            tallies = [
                engine.submit(
                    _total, *tallies[k : k + _FAN_IN], key=f"sum-{iterations}-{level}-{k}"
                )
                for k in range(0, len(tallies), _FAN_IN)
            ]
        tally = engine.gather(tallies[0])
        if open_sky is not None and isinstance(tally.evidence, Cn0Moments):
            tally = replace(tally, evidence=tally.evidence + open_sky)
        before, model = model, tally.refit(model)
        if progress is not None:
            progress(iterations)
        settled = not isinstance(model, Cn0Mixture) or model.settled(before)
        if iterations > 1 and tally.change < estimator.acceptance.label_tol and settled:
            break
    finish = finish or _judged
    done = [
        engine.submit(finish, p, iterations, key=f"finish-{name}")
        for p, name in zip(parts, names, strict=True)
    ]
    return done, model


# The steps as functions of the part, for engines (a Part or a FailedTile alike).
def _fitted(part: Part, model: SignalModel) -> Part:
    return part.fitted(model)


def _shared(part: Part) -> Shared:
    return part.shared()


def _exchanged(part: Part, *shared: Shared) -> tuple[Part, Tally]:
    return part.exchanged(*shared)


def _judged(part: Part, iterations: int) -> BuildingFits:
    return part.judged(iterations)


def _first(pair: tuple[Any, Any]) -> Any:
    return pair[0]


def _second(pair: tuple[Any, Any]) -> Any:
    return pair[1]


def _total(*tallies: Tally) -> Tally:
    return functools.reduce(operator.add, tallies)


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
    its buildings' largest share of changed labels. Parts add up, exactly."""

    evidence: Cn0Counts | Cn0Moments | None
    plausible: bool
    change: float

    def __add__(self, other: Tally) -> Tally:
        """Both parts' tallies: where any building is plausible only plausible fits teach (the
        others' counts are their fallbacks'), else every fallback does."""
        change = max(self.change, other.change)
        if self.plausible != other.plausible:
            return replace(self if self.plausible else other, change=change)
        if self.evidence is None or other.evidence is None:
            return replace(other if self.evidence is None else self, change=change)
        evidence = self.evidence + other.evidence  # type: ignore[operator]
        return Tally(evidence, self.plausible, change)

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
    ) -> Part:
        """A part from coded rows (see :func:`fourplb`): it owns the buildings coded below
        ``n_own`` (default: all ``n_groups``), whose codes in the whole run are ``building``
        (default: their own). A part that does not own every building needs ``signal`` and
        ``order``, so that each signal is counted by one part."""
        if not estimator.fourpl:
            raise ModelError(f"fourplb runs 4PL-B or 4PL, not {estimator.method}")
        n_own = n_groups if n_own is None else int(n_own)
        if n_own < n_groups and (signal is None or order is None):
            raise ModelError("a part of a run needs each row's signal and order along its ray")
        g = np.asarray(groups, dtype=np.intp)
        h = np.asarray(height, dtype=float)
        by_group = np.lexsort((h, g))  # a building's rows together, by height: faster fits
        g, h = _compact(g[by_group]), h[by_group]
        sd = None if height_sd is None else np.asarray(height_sd, dtype=float)[by_group]
        if receiver is not None:  # coded in sorted order: the same order in any part
            receiver = _compact(pd.factorize(np.asarray(receiver)[by_group], sort=True)[0])
        if signal is not None:
            sig = _compact(np.unique(np.asarray(signal)[by_group], return_inverse=True)[1])
        else:
            sig = _compact(np.arange(g.size))  # each row is a signal of its own
        if order is not None:
            order = _compact(np.asarray(order)[by_group])
        tracks = None if track is None else np.asarray(track)[by_group]
        looks = None  # found once: a row's look does not change as 4PL-B iterates
        if estimator.weighting == "looks" or (estimator.method == "4PL-B" and tracks is not None):
            looks = _compact(look_ids(h, g, tracks))
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
        else:
            labels = model.label(self.s)
        c_now = None if last is None else last.fit.c
        looks = None if self.looks is None else self.looks[own]
        weights = height_weights(
            h, g, n_own, self.estimator.weighting, c=c_now, mask=seen, looks=looks
        )
        use = weights > 0  # rows left out weigh nothing: do not carry them through the fit
        fit = fit_4pl(
            h[use],
            labels[own][use],
            weights[use],
            g[use],
            n_own,
            init=None if last is None else last.fit.params,
            sd=None if self.sd is None else self.sd[own][use],
        )
        own_map = h > fit.c[g]
        change = np.ones(n_own)
        if last is not None:
            flips = (own_map != last.own_map) & seen
            change = np.bincount(g, flips, n_own) / np.maximum(np.bincount(g, seen, n_own), 1)
        return replace(self, last=LastFit(fit, self.seen, labels, own_map, change, model))

    def shared(self) -> Shared:
        """What the other parts need of the own buildings' fits (after :meth:`fitted`)."""
        last, own = self._last, self._own
        fit = last.fit
        g, h, seen = self.g[own], self.h[own], last.seen[own]
        min_separation = self.estimator.acceptance.min_separation
        return Shared(
            building=self.building[: self.n_own],
            a=fit.a,
            b=fit.b,
            c=fit.c,
            d=fit.d,
            plausible=_plausible(fit, h, g, seen, self.n_own, min_separation),
            fallback=_plausible(fit, h, g, seen, self.n_own, 0.0),
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
        open_map = self.h > c[self.g]
        used = last.seen & teach[self.g]
        lead, clear = _classifier_data(self, open_map, used)
        prior = self.prior
        evidence: Cn0Counts | Cn0Moments
        if self.estimator.signal_model == "mixture":
            prior = clear_chance(self.h, self.g, self.sd, a, b, c, d)
            chance = clear.astype(float)
            if isinstance(last.model, Cn0Mixture):
                every = clears_all(prior, self.sig)[lead]
                chance = last.model.posterior(self.s[lead], self.e[lead], every)
            evidence = Cn0Moments.of(self.s[lead], self.e[lead], chance)
        else:
            evidence = Cn0Counts.of(self.s[lead], clear)
        seen = self.seen
        if self.occlusion:
            seen = _unoccluded(self.h, self.g, self.sig, c, b, plausible, self.order)
        change = float(np.max(last.change, initial=0.0))
        part = replace(self, seen=seen, prior=prior)
        return part, Tally(evidence, own_plausible, change)

    def crossing(self) -> Cn0Moments:
        """The signals the part counts (those whose first building along the ray is one of
        its own), once each, as open: a run of parts takes them from all its signals to leave
        those that cross no footprint (:func:`run_parts`' ``open_sky``)."""
        every = np.ones(self.h.size, dtype=bool)
        lead, _ = _classifier_data(self, every, every)
        return Cn0Moments.of(self.s[lead], self.e[lead], 1.0)

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
            c_range = c_interval(
                fit,
                h[fit_seen],
                labels[fit_seen],
                g[fit_seen],
                weights=evidence[fit_seen],
                sd=None if sd is None else sd[fit_seen],
                reach=accept.max_uncertainty,
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
    used (``seen``, all the part's rows) and every row's label then, the map's labels of the
    own rows (``own_map``: above ``c``) and the share of each own building's labels that
    changed from the fit before (``change``; 1 at the first), and the signal ``model``
    that labelled them."""

    fit: FourPLFit
    seen: np.ndarray
    labels: np.ndarray
    own_map: np.ndarray
    change: np.ndarray
    #: The signal model that labelled the rows.
    model: SignalModel


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


def _plausible(fit, h, g, seen, n_groups, min_separation):
    """Buildings whose current fit may stand in front of others: separated asymptotes and an
    inflection point inside the heights they were fitted on."""
    lo, hi = group_range(h[seen], g[seen], n_groups)
    return (fit.a - fit.d >= min_separation) & (fit.c >= lo) & (fit.c <= hi)


def _unoccluded(h, g, sig, c, b, plausible, order=None):
    """Rows whose ray surely clears every *other* building at the current estimates (``c``,
    ``b`` per building): it passes above the top of each one's height range, c + 3/b. A
    signal that may have been blocked by another building tells nothing about this one,
    whatever its C/N0. A building without a plausible estimate may stand at any height: with
    ``order``, the rows behind it along the ray are left out too."""
    blocks = plausible[g] & (h < c[g] + 3.0 / b[g])
    n_sig = int(sig.max(initial=-1)) + 1
    n_blocking = np.bincount(sig, blocks, n_sig)
    clear = (n_blocking[sig] - blocks) == 0
    if order is not None:
        first_unknown = np.full(n_sig, np.iinfo(np.int64).max)
        np.minimum.at(first_unknown, sig[~plausible[g]], order[~plausible[g]])
        clear &= order <= first_unknown[sig]
    return clear


def _classifier_data(part: Part, open_map: np.ndarray, used: np.ndarray):
    """The rows of the signals the part counts (one each: the first row along the ray, by
    ``order``, of those the fits ``used``; without ``order``, the first row), those of own
    buildings, and each signal's map label: open only if it clears every building it was
    used for."""
    sig, open_map = part.sig[used], open_map[used]
    n_sig = int(sig.max(initial=-1)) + 1
    closed = np.bincount(sig, weights=(~open_map).astype(float), minlength=n_sig)
    rows = np.arange(sig.size)
    if part.order is not None:  # the last assignment wins: the lowest order's
        rows = rows[np.argsort(part.order[used], kind="stable")]
    lead = np.full(n_sig, -1)
    lead[sig[rows[::-1]]] = rows[::-1]
    lead = lead[lead >= 0]
    mine = part.g[used][lead] < part.n_own
    return np.flatnonzero(used)[lead[mine]], closed[sig[lead[mine]]] == 0


def position_margin(
    fit: FourPLFit,
    g: np.ndarray,
    h: np.ndarray,
    sd: np.ndarray,
    recording: np.ndarray | None,
    n_groups: int,
) -> np.ndarray:
    """How far (m) the roof line may be off owing to the receivers' position errors: twice
    the standard error of ``c`` when every recording's error is shared by all its rows.

    The errors-in-variables fit averages the position errors of rows as if independent, but a
    recording's offset (a point picked on a map, a phone's drifting fix) moves all its rows
    alike. So each recording's rows within the transition (``|h - c| <= 1.5/b + sd``) move
    ``c`` together, each by its ``sd`` in proportion to what it tells of ``c``: its Fisher
    information, the square of its slope at the roof line, ``kappa^2 = 1 / (1 + pi b^2 sd^2 /
    8)`` (:mod:`.fourpl`). ``se(c)^2 = sum_r (sum_{i in r} w_i s_i)^2 / (sum_i w_i)^2``: one
    recording of rows alike moves ``c`` by their ``sd``, ``R`` such recordings by ``sd /
    sqrt(R)``, and a grazing ray whose height a metre of position moves by tens of metres
    tells little of ``c`` and moves it little. Without recordings all rows are one recording
    (the widest margin).
    """
    near = np.abs(h - fit.c[g]) <= 1.5 / fit.b[g] + sd
    g, sd = g[near], sd[near]
    w = 1.0 / (1.0 + np.pi * (fit.b[g] * sd) ** 2 / 8.0)
    rec = np.zeros(g.size, dtype=np.intp) if recording is None else recording[near]
    key, pair = np.unique(np.column_stack([g, rec]), axis=0, return_inverse=True)
    shift = np.bincount(pair, w * sd, minlength=len(key))
    num = np.bincount(key[:, 0], shift**2, minlength=n_groups)
    den = np.bincount(g, w, minlength=n_groups)
    return 2.0 * np.sqrt(num) / np.maximum(den, 1e-300)


#: Why a range is too wide, where the data say (after ``height range wider than ... m: ``):
#: the receivers' shared position errors move the roof line more than the data leave it open,
POSITIONS_UNCERTAIN = "the receivers' positions are too uncertain"
#: or fewer than ``min_signals`` rays cross the building within a quarter of the widest range
#: of the roof line (a static phone sees a building at a few heights only).
NO_RAYS = "no rays near the roof line"


def _far_from(h, g, c, reach, n_groups, min_signals):
    """Buildings with fewer than ``min_signals`` rows within ``reach`` of their ``c``."""
    near = np.abs(h - c[g]) <= reach
    return np.bincount(g, near, n_groups) < min_signals


def _judge(
    fit,
    g,
    h,
    labels,
    seen,
    n_groups,
    change,
    iterations,
    accept,
    *,
    strict=True,
    margin=0.0,
    c_range=None,
    paper_rule=False,
):
    """Turn a fit on the ``seen`` rows into heights, with an explicit reason wherever it is
    not to be trusted (``strict``: also where 4PL-B's loop or the fit itself is implausible).
    The height is ``c`` (``c + 1.5/b`` by the ``paper_rule``), its range the 3/b-wide
    transition centred on it, widened at each end by that side of the interval of ``c`` and
    the ``margin`` in quadrature."""
    below_all = h < fit.c[g]
    hidden = np.bincount(g, below_all & seen, n_groups) < MIN_VISIBLE * np.bincount(
        g, below_all, n_groups
    )
    g, h, labels = g[seen], h[seen], labels[seen]
    label_tol, min_signals = accept.label_tol, accept.min_signals
    min_separation, max_uncertainty = accept.min_separation, accept.max_uncertainty
    a, b, c, d = (v.copy() for v in (fit.a, fit.b, fit.c, fit.d))
    n_rows = np.bincount(g, minlength=n_groups)
    usable = n_rows >= min_signals
    lo, hi = group_range(h, g, n_groups)
    n_open = np.bincount(g, weights=labels > 0.5, minlength=n_groups)  # soft labels: likelier
    n_below = np.bincount(g, h < c[g], minlength=n_groups)
    c_lo, c_hi = (c, c) if c_range is None else c_range  # c_interval's ends hold c
    offset = 1.5 / b if paper_rule else 0.0
    # the data's uncertainty of c and the receivers' shared position errors are independent:
    # they add in quadrature; the transition, the roof line's own blur, adds to both
    lower = c + offset - 1.5 / b - np.hypot(c - c_lo, margin)
    upper = c + offset + 1.5 / b + np.hypot(c_hi - c, margin)
    wide = upper - lower > max_uncertainty
    status = np.full(n_groups, "ok", dtype=object)
    wide_text = f"height range wider than {max_uncertainty:g} m"
    plausibility = [
        (change >= label_tol, f"labels still changing after {iterations} iterations"),
        (b <= B_BOUNDS[0] * 1.0001, "no slope: the height does not change the open probability"),
        ((c < lo) | (c > hi), "inflection point outside the observed intersection heights"),
        (a - d < min_separation, f"asymptotes closer than {min_separation} (a - d)"),
        # Relabelling by h > c presumes the map classifies below c as closed and above as open.
        ((d >= 0.5) | (a <= 0.5), "the roof line does not separate open from closed signals"),
        (wide, wide_text),
        (wide & (margin > np.maximum(c - c_lo, c_hi - c)), f"{wide_text}: {POSITIONS_UNCERTAIN}"),
        (
            wide & _far_from(h, g, c, max_uncertainty / 4, n_groups, min_signals),
            f"{wide_text}: {NO_RAYS}",
        ),
        (hidden, "roof line hidden: most signals below it are blocked by other buildings"),
        (
            np.minimum(n_below, n_rows - n_below) < min_signals,
            f"fewer than {min_signals} signals on one side of the roof line",
        ),
    ]
    checks = [
        (~fit.converged, "the 4PL optimiser did not converge"),
        *(plausibility if strict else []),
        (n_open == 0, "no signal is labelled open"),
        (n_open == n_rows, "every signal is labelled open"),
        (~usable, f"fewer than {min_signals} signals"),
    ]
    for bad, reason in checks:  # the last failing check is the most basic one: it wins
        status[bad] = reason
    converged = status == "ok"
    return BuildingFits(
        a=a,
        b=b,
        c=c,
        d=d,
        n_signals=n_rows,
        iterations=np.where(usable, iterations, 0),
        converged=converged,
        status=status,
        height=np.where(converged, c + offset, np.nan),
        height_lower=np.where(converged, lower, np.nan),
        height_upper=np.where(converged, upper, np.nan),
        height_paper=np.where(converged, c + 1.5 / b, np.nan),
    )
