"""Where 4PL-B's parts (:mod:`.parts`) are stepped through the iterations: an :class:`Engine`,
in one process (:class:`InProcess`) or as Dask tasks
(:class:`gnss_citygml.tiling.cluster.DaskEngine`), and :func:`run_parts`, the map / exchange /
reduce of DESIGN.md over it.
"""

from __future__ import annotations

import functools
import itertools
import operator
from collections.abc import Callable, Iterable, Sequence
from dataclasses import replace
from typing import Any, Protocol

from ..settings import Estimator
from .classifier import SignalClassifier
from .fourplb import BuildingFits, SignalModel
from .mixture import SETTLED_DB, Cn0Mixture, Cn0Moments
from .parts import Part
from .shares import Shared, Tally

__all__ = ["Engine", "InProcess", "WINDOW", "in_windows", "run_parts"]


class Engine(Protocol):
    """Where :func:`run_parts` runs each step: :class:`InProcess`, or a Dask cluster
    (:class:`gnss_citygml.tiling.cluster.DaskEngine`, whose ``submit`` returns futures that later
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


#: The most independent steps :func:`in_windows` keeps submitted at once.
WINDOW = 256


def in_windows(engine: Engine, steps: Iterable[tuple[Any, ...]], window: int = WINDOW) -> list[Any]:
    """The values of ``steps`` (each ``(key, func, *args)``, made as they are needed), run on
    ``engine`` ``window`` at a time. A step per tile (the tiles' writes, their files' checks)
    submitted all at once makes the client hold every tile's task and arguments until the
    last one ends; in windows it holds one window's, whatever the number of tiles."""
    values: list[Any] = []
    steps = iter(steps)
    while batch := list(itertools.islice(steps, window)):
        values += engine.gather([engine.submit(*step[1:], key=step[0]) for step in batch])
    return values


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
    (:class:`Tally`); the loop ends once every building's roof line and the signal model
    have settled (:mod:`.settling`; with the mixture, whose expectation-maximisation creeps,
    once fewer than ``label_tol`` of any building's labels change and its classes have
    settled, the paper's rule). ``progress`` is told each iteration's number as it ends.
    Returns what ``finish(part, iterations)`` gives of each part (default: its
    :class:`BuildingFits`, :meth:`Part.judged`), as the engine's handles (the values
    themselves in one process; futures on a cluster, left where they were made: gather them,
    or pass them on), and the classifier. ``names`` (one per part, e.g. its tile's) name the
    steps for the engine. ``open_sky``: the run's signals
    whose rays cross no footprint, which the mixture signal model learns open signals from.
    A part may be anything with :class:`Part`'s steps, e.g. a failed tile's stand-in
    (:class:`gnss_citygml.tiling.run.FailedTile`).
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
        parts, tally = _exchange(engine, parts, neighbours, names, iterations)
        if open_sky is not None and isinstance(tally.evidence, Cn0Moments):
            tally = replace(tally, evidence=tally.evidence + open_sky)
        before, model = model, tally.refit(model)
        if progress is not None:
            progress(iterations)
        # the mixture's expectation-maximisation creeps (docs/issue-46-settling.md): its loop
        # ends as the paper's did, when fewer than label_tol of any building's labels change
        settled = tally.moving == 0
        if isinstance(model, Cn0Mixture):
            settled = tally.change < estimator.acceptance.label_tol
        if iterations > 1 and settled and _settled(model, before):
            break
    finish = finish or _judged
    done = [
        engine.submit(finish, p, iterations, key=f"finish-{name}")
        for p, name in zip(parts, names, strict=True)
    ]
    return done, model


def _exchange(engine, parts, neighbours, names, iterations) -> tuple[list[Any], Tally]:
    """One iteration's exchange and reduce: each part takes its neighbours' fits (the parts
    it returns) and counts its signals; the counts are summed in a tree of :data:`_FAN_IN`."""
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
            engine.submit(_total, *tallies[k : k + _FAN_IN], key=f"sum-{iterations}-{level}-{k}")
            for k in range(0, len(tallies), _FAN_IN)
        ]
    return parts, engine.gather(tallies[0])


def _settled(model: SignalModel, before: SignalModel) -> bool:
    """Whether the signal model has settled: the mixture by its own test, the paper's
    classifier where its threshold moved less than the mixture's :data:`~.mixture.SETTLED_DB`
    (a tenth of a dB-Hz, what receivers report)."""
    if isinstance(model, Cn0Mixture):
        return model.settled(before)
    return abs(model.threshold - before.threshold) < SETTLED_DB


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
