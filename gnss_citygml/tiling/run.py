"""4PL-B over a run cut into tiles (:mod:`gnss_citygml.tiling.grid`), with the single run's heights.

Each tile casts the rays that can reach its buildings against its buildings and its halo
(:func:`~gnss_citygml.tiling.grid.plan_tiles`), keeps the signals that cross one of its own
buildings, and takes part in 4PL-B's map / exchange / reduce
(:func:`~gnss_citygml.model.engine.run_parts`): the parts whose buildings its rays cross are
its neighbours. Run in one process (the default engine) or on a Dask cluster
(:mod:`gnss_citygml.tiling.cluster`), the heights are those of :func:`~gnss_citygml.pipeline.run`
on the same receivers, bit for bit (tested): each building is summed the same way in a tile
as in the whole run. :func:`tiled_heights` takes the receivers in memory;
:mod:`gnss_citygml.tiling.from_partition` has each tile read its own from a partition folder.
"""

from __future__ import annotations

import functools
import operator
import uuid
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import geopandas as gpd
import numpy as np
import pandas as pd

from ..errors import InputError
from ..model.engine import Engine, InProcess, in_windows, run_parts
from ..model.estimate import HEIGHTS_COLUMNS, intersections_part, no_heights
from ..model.fourplb import SignalModel
from ..model.mixture import Cn0Moments, elevation_units
from ..model.offsets import SkyCounts, levelled, sky_counts
from ..model.parts import Part
from ..model.shares import Shared, Tally
from ..settings import DEFAULT_TILE_SIZE, Estimator, PositionError, Rays
from ..stages import intersections, near_reach, recordings
from .grid import Tile, building_tiles, check_reach, plan_tiles
from .output import TileFolder, tile_index_frame

__all__ = [
    "FAILED_COLUMNS",
    "FailedTile",
    "TileRun",
    "failed_tiles",
    "Signals",
    "TilePlan",
    "held_plan",
    "run_tiles",
    "signal_moments",
    "tile_heights",
    "tile_part",
    "tiled_heights",
]


def tiled_heights(
    receivers: pd.DataFrame,
    buildings: gpd.GeoDataFrame,
    *,
    estimator: Estimator = Estimator(),
    rays: Rays = Rays(),
    position_error: PositionError = PositionError(),
    tile_size: float = DEFAULT_TILE_SIZE,
    engine: Engine | None = None,
    progress: Callable[[str], None] | None = None,
    output: TileFolder | None = None,
) -> TileRun:
    """The heights table of :func:`~gnss_citygml.model.estimate.estimate_heights` on
    :func:`~gnss_citygml.pipeline.intersections` of ``receivers`` (the pipeline's receivers
    table, :func:`~gnss_citygml.pipeline.receivers`) and ``buildings``, computed in tiles of
    ``tile_size`` metres, with the final signal classifier and the failed tiles
    (:class:`TileRun`). The intersections are never gathered: each tile casts its own (on
    ``engine``'s workers). ``progress`` is told what is being done ("tile plan: 16 tiles",
    "iteration 3"). With ``output``, each tile's worker writes its heights there
    (:mod:`gnss_citygml.tiling.output`), nobody gathers them, and the table returned is the
    tile index instead.
    """
    say = progress or (lambda text: None)
    check_reach(tile_size, rays.max_range)  # before the recordings are named
    rx = receivers.reset_index(drop=True)
    if not position_error.exact:  # one position error may span tiles: name it over the run
        rx["recording"] = recordings(rx, position_error)
    e, n, bearing = (rx[c].to_numpy(dtype=float) for c in ("e", "n", "bearing"))
    reach = near_reach(rx, position_error)  # how far beside a ray a footprint gives it a row
    widen = 0.0 if reach is None else float(reach.max(initial=0.0))
    tiles = plan_tiles(e, n, buildings, rays.max_range, tile_size, bearing, widen)
    say(f"tile plan: {len(tiles)} tiles of {tile_size:g} m")
    casts = [
        (
            tile_part,
            rx.iloc[tile.receivers],
            buildings.iloc[np.concatenate([tile.buildings, tile.halo])],
            tile.buildings.size,
            estimator,
            rays,
            position_error,
        )
        for tile in tiles
    ]
    signals = Signals(
        lambda: sky_counts(rx), lambda offsets: signal_moments(rx, offsets), estimator
    )
    plan = held_plan(tiles, buildings, tile_size)
    return run_tiles(plan, casts, tile_size, estimator, engine, say, output, signals)


def signal_moments(receivers: pd.DataFrame, offsets: pd.Series | None = None) -> Cn0Moments:
    """All the signals of a receivers table (``cn0``, ``elevation``), as open, each phone's
    C/N0 levelled by ``offsets`` (:meth:`~gnss_citygml.model.offsets.SkyCounts.offsets`)."""
    if offsets is not None:
        receivers = levelled(receivers, offsets)
    e = elevation_units(receivers["elevation"].to_numpy(dtype=float))
    return Cn0Moments.of(receivers["cn0"].to_numpy(dtype=float), e, 1.0)


@dataclass(frozen=True)
class Signals:
    """All the run's signals, where a run in tiles needs them: counted by phone (``counts``),
    to level the phones (``Estimator.level_phones``), and summed for the mixture signal model
    (``moments``, given the phones' offsets or None). Less those that the tiles find crossing
    a footprint, they are the open sky."""

    counts: Callable[[], SkyCounts]
    moments: Callable[[pd.Series | None], Cn0Moments]
    estimator: Estimator

    def offsets(
        self, parts: list[Any], engine: Engine, names: list[str], say: Callable[[str], None]
    ) -> pd.Series | None:
        """The phones' offsets from the open sky (None: not asked for)."""
        if not self.estimator.levels_phones:
            return None
        crossing = [
            engine.submit(_sky_crossing, p, key=f"sky-{name}")
            for p, name in zip(parts, names, strict=True)
        ]
        offsets = functools.reduce(operator.sub, engine.gather(crossing), self.counts()).offsets()
        if offsets.size:
            say(
                f"{offsets.size} phones levelled by their open sky: offsets "
                f"{offsets.min():+.1f} to {offsets.max():+.1f} dB-Hz"
            )
        return offsets

    def open_sky(
        self, parts: list[Any], engine: Engine, names: list[str], offsets: pd.Series | None
    ) -> Cn0Moments | None:
        """What the open sky teaches the mixture signal model (None: another model)."""
        if self.estimator.signal_model != "mixture":
            return None
        crossing = [
            engine.submit(_crossing, p, key=f"crossing-{name}")
            for p, name in zip(parts, names, strict=True)
        ]
        return functools.reduce(operator.sub, engine.gather(crossing), self.moments(offsets))


@dataclass(frozen=True)
class TilePlan:
    """What a run in tiles knows of its buildings, whether it holds them (:func:`held_plan`)
    or only the partition's index does: the tiles that take part (``names``, in the order of
    their casts), the tiles each needs the fits of (``neighbours``: positions in ``names``),
    a tile's own buildings' ids (``own_ids(k)``: a failed tile's, for its rows), and every
    tile that owns a footprint with its own buildings (``every_tile()``: ``(name, own)``,
    ``own`` as :meth:`~gnss_citygml.tiling.output.TileFolder.write` takes them), for the
    output written per tile."""

    names: list[str]
    neighbours: list[list[int]]
    own_ids: Callable[[int], np.ndarray]
    every_tile: Callable[[], list[tuple[str, Any]]]


def held_plan(tiles: list[Tile], buildings: gpd.GeoDataFrame, size: float) -> TilePlan:
    """The plan of ``tiles`` (positions in ``buildings``) of buildings held in memory."""
    owner = building_tiles(buildings, size)
    ids = buildings["id"].astype(str).to_numpy()

    def every_tile():
        groups = pd.Series(np.arange(len(owner))).groupby(owner)
        return [(str(name), buildings.iloc[own.to_numpy()]) for name, own in groups]

    return TilePlan(
        [tile.name for tile in tiles],
        _neighbours(tiles, owner),
        lambda k: ids[tiles[k].buildings],
        every_tile,
    )


def run_tiles(
    plan: TilePlan,
    casts: list[tuple[Any, ...]],
    size: float,
    estimator: Estimator,
    engine: Engine | None,
    say: Callable[[str], None],
    output: TileFolder | None,
    signals: Signals,
) -> TileRun:
    """4PL-B over the tiles of ``plan``, each made by its cast (a function and its
    arguments): the heights table, or with ``output`` the tile index of the tiles written
    there. ``signals``: all the run's signals (:class:`Signals`), whose open sky levels the
    phones and teaches the mixture signal model."""
    if not plan.names:
        raise InputError(
            "no building has a receiver within the rays' reach",
            fix="give footprints that cover where the observations were made",
        )
    engine = engine or InProcess()
    run = uuid.uuid4().hex[:8]  # the steps' names are this run's alone on a shared cluster
    names = [f"{tile}-{run}" for tile in plan.names]
    parts = [
        engine.submit(*cast, key=f"cast-{name}") for cast, name in zip(casts, names, strict=True)
    ]
    failed = {}
    for k, why in engine.failures(parts).items():
        say(f"tile {plan.names[k]} failed: {why}")
        own = plan.own_ids(k)
        parts[k] = FailedTile(plan.names[k], own, why)
        failed[plan.names[k]] = (why, own.size)
    _refuse_all_failed(failed, len(plan.names))
    open_sky = None
    if failed:
        say(
            "the signals crossing no footprint are not known without the failed tiles: "
            "the phones are not levelled, and the mixture signal model learns without them"
        )
    else:
        offsets = signals.offsets(parts, engine, names, say)
        if offsets is not None:
            parts = [
                engine.submit(_levelled, p, offsets, key=f"level-{name}")
                for p, name in zip(parts, names, strict=True)
            ]
        open_sky = signals.open_sky(parts, engine, names, offsets)
    tables, classifier = run_parts(
        parts,
        plan.neighbours,
        estimator,
        engine,
        progress=lambda k: say(f"iteration {k}"),
        finish=functools.partial(tile_heights, method=estimator.method),
        names=names,
        open_sky=open_sky,
    )
    lost = pd.DataFrame(
        [(name, why, n) for name, (why, n) in sorted(failed.items())],
        columns=list(FAILED_COLUMNS),
    ).astype({"buildings": np.int64})
    if output is None:
        return TileRun(pd.concat(engine.gather(tables), ignore_index=True), classifier, lost)
    made = dict(zip(plan.names, tables, strict=True))
    every = plan.every_tile()
    say(f"writing {len(every)} tiles")
    rows = in_windows(
        engine,
        (
            (
                f"write-{name}-{run}",
                output.write,
                made.get(name),
                own,
                name,
                failed.get(name, ("", 0))[0],
            )
            for name, own in every
        ),
    )
    return TileRun(tile_index_frame(rows, size), classifier, lost)


def _refuse_all_failed(failed: dict[str, tuple[str, int]], tiles: int) -> None:
    """Refuse a run whose every tile failed: it has no estimate to give, and its failures
    share a cause (bad rows everywhere, an input the tiles cannot read) that one tile names."""
    if failed and len(failed) == tiles:
        name, (why, _) = min(failed.items())
        raise InputError(
            f"every one of the {tiles} tiles failed, e.g. tile {name}: {why}",
            where=f"tile {name}",
            fix="mend what the tile's error names, then run again",
        )


def tile_part(
    receivers: pd.DataFrame,
    buildings: gpd.GeoDataFrame,
    n_own: int,
    estimator: Estimator,
    rays: Rays,
    position_error: PositionError,
) -> Part:
    """One tile's :class:`~gnss_citygml.model.parts.Part`: its ``receivers``' rays cast
    against ``buildings`` (its own ``n_own`` first, then its halo), the signals that cross
    one of its own buildings."""
    recording = receivers["recording"].array if "recording" in receivers.columns else None
    inter = intersections(
        receivers, buildings, rays=rays, position_error=position_error, recording=recording
    )
    mine = inter["building"].cat.codes.to_numpy() < n_own
    inter = inter[inter["signal"].isin(inter["signal"].to_numpy()[mine])]
    own = buildings["id"].astype(str).to_numpy()[:n_own]
    return intersections_part(inter, estimator, own=own, phones=estimator.levels_phones)[1]


def _crossing(part: Part) -> Cn0Moments:
    return part.crossing()


def _sky_crossing(part: Part) -> SkyCounts:
    return part.sky_crossing()


def _levelled(part: Part, offsets: pd.Series) -> Part:
    return part.levelled(offsets)


def tile_heights(part: Part | FailedTile, iterations: int, method: str) -> pd.DataFrame:
    """The heights table's rows of a tile's own buildings (every one its signals cross),
    fitted with ``method``."""
    if isinstance(part, FailedTile):
        return part.heights(method)
    fits = part.judged(iterations)
    table = pd.DataFrame({"id": part.building[: part.n_own], **fits.columns()})
    table["method"] = method
    return table[HEIGHTS_COLUMNS]


@dataclass(frozen=True)
class FailedTile:
    """A tile whose cast failed (twice, on a cluster): it takes no part in the run, and its
    buildings stand as unknown obstacles to the other tiles' rays (no plausible fit: the rows
    behind them are left out), as a building without an estimate does in any run. Its
    buildings are reported with the failure as their status."""

    name: str
    building: np.ndarray
    reason: str

    def fitted(self, model: SignalModel) -> FailedTile:
        """Nothing to fit."""
        return self

    def shared(self) -> Shared:
        """The buildings, with no fit."""
        nan = np.full(self.building.size, np.nan)
        no = np.zeros(self.building.size, dtype=bool)
        return Shared(self.building, nan, nan, nan, nan, no, no, nan)

    def exchanged(self, *shared: Shared) -> tuple[FailedTile, Tally]:
        """No signal to count, no label to change."""
        return self, Tally(None, plausible=False, change=0.0)

    def heights(self, method: str) -> pd.DataFrame:
        """The heights table's rows of the tile's buildings: not estimated, and why."""
        return no_heights(self.building, method, _FAILED.format(self.name, self.reason))


#: The status of a failed tile's buildings.
_FAILED = "tile {} failed: {}"

#: The columns of :attr:`TileRun.failed` (and of :func:`failed_tiles`).
FAILED_COLUMNS = ("tile", "reason", "buildings")


@dataclass(frozen=True)
class TileRun:
    """What a run in tiles gives back (:func:`tiled_heights`, :func:`partitioned_heights`)."""

    #: The heights table (:data:`~gnss_citygml.model.estimate.HEIGHTS_COLUMNS`); with an
    #: output folder, the tile index instead (:func:`~gnss_citygml.tiling.output.write_index`).
    table: pd.DataFrame
    #: The final signal classifier.
    classifier: SignalModel
    #: One row per tile whose cast failed (twice, on a cluster): ``tile``, ``reason`` and
    #: ``buildings``, how many it owns (they have no height: their status says why).
    failed: pd.DataFrame


def failed_tiles(table: pd.DataFrame) -> pd.DataFrame:
    """The tiles of a run whose cast failed, as :attr:`TileRun.failed`, from what the run
    wrote: its heights (a row per building, with its ``tile`` and that tile's failure,
    ``failed``, empty if none) or its tile index (a row per tile, with its ``buildings``)."""
    bad = table[table["failed"].astype(str) != ""]
    if "buildings" not in table.columns:  # the heights: count each tile's buildings
        bad = bad.groupby(["tile", "failed"], sort=True).size().rename("buildings").reset_index()
    out = bad.rename(columns={"failed": "reason"})[list(FAILED_COLUMNS)]
    return out.sort_values("tile").reset_index(drop=True).astype({"buildings": np.int64})


def _neighbours(tiles: list[Tile], owner: np.ndarray) -> list[list[int]]:
    """For each tile, the tiles (positions in ``tiles``) that own a building of its halo,
    and itself: whose fits it needs each iteration. A tile left out of the run (no receiver
    within reach of its buildings) owns buildings that no ray crosses: no one needs them."""
    at = {tile.name: k for k, tile in enumerate(tiles)}
    return [
        sorted({k, *(at[name] for name in np.unique(owner[tile.halo]) if name in at)})
        for k, tile in enumerate(tiles)
    ]
