"""A run in tiles from a partition folder (:mod:`gnss_citygml.tiling.partition`): each tile's
worker reads its own files, with :func:`~gnss_citygml.tiling.run.run_tiles`'s heights.

:func:`partitioned_heights` has each tile read the receivers' partitions within reach of its
buildings. The buildings come from the caller, held in memory, or, when the partition holds
them (``partition --footprints``, :mod:`gnss_citygml.tiling.buildings`), from the partition
itself: then the client holds only the plan (each tile's name, extent and files, from the
index), and each worker reads its tile's buildings and those of the tiles within reach.
"""

from __future__ import annotations

import functools
import operator
import uuid
from collections.abc import Callable
from pathlib import Path
from typing import Any

import geopandas as gpd
import numpy as np
import pandas as pd
import shapely

from ..errors import InputError
from ..files.paths import StrPath
from ..model.engine import Engine, InProcess, in_windows
from ..model.mixture import Cn0Moments
from ..model.offsets import SkyCounts, sky_counts
from ..model.parts import Part
from ..settings import Estimator, PositionError, Rays
from .buildings import (
    BUILDINGS,
    building_files,
    files_shared_id,
    read_building_files,
    read_building_ids,
)
from .grid import Tile, building_tiles, receiver_tiles
from .output import TileFolder
from .partition import (
    check_digests,
    check_partition,
    listed_sha256,
    read_index,
    read_receivers,
    refuse_changed,
    refuse_shared_ids,
    tile_files,
)
from .run import Signals, TilePlan, TileRun, held_plan, run_tiles, signal_moments, tile_part

__all__ = [
    "file_counts",
    "file_moments",
    "partition_files_part",
    "partition_part",
    "partitioned_heights",
]


def partitioned_heights(
    folder: StrPath,
    buildings: gpd.GeoDataFrame | None = None,
    *,
    estimator: Estimator = Estimator(),
    rays: Rays = Rays(),
    position_error: PositionError = PositionError(),
    engine: Engine | None = None,
    progress: Callable[[str], None] | None = None,
    output: TileFolder | None = None,
) -> TileRun:
    """As :func:`~gnss_citygml.tiling.run.tiled_heights`, from a partition folder
    (:func:`~gnss_citygml.tiling.partition.partition_observations`, whose tiles it uses): each
    tile reads the partitions within ``rays.max_range`` of its buildings itself (on the
    engine's workers), and keeps the rows whose rays can enter them. Its halo is every
    building within twice the reach of its buildings' extent: more than the rays need, which
    adds only crossings the single run has too. The partition's elevation mask and
    position-error window must be the run's
    (:func:`~gnss_citygml.tiling.partition.check_partition`). Its files are checked against
    its index first: their listing and sizes here, their SHA-256 on the engine's workers (one
    task per partition tile), before any tile reads them.

    ``buildings`` (with their ``ground``) come from the caller, or, when None, from the
    partition (written with its footprints): each tile's worker then reads its own buildings
    and those of the tiles within reach, and the client holds only the plan. Each row's chance
    of crossing (``position_error.crossing``) is refused: a partition's tiles hold the rays that
    may enter their buildings, not those that pass near them."""
    if position_error.crossing:
        raise InputError(
            "a run from a partition cannot weigh rows by their chance of crossing "
            "(PositionError(crossing=True)): its tiles hold only the rays that enter them",
            fix="run from the observations (gnss_citygml.pipeline.run, tiled_heights) instead",
        )
    say = progress or (lambda text: None)
    index = read_index(folder)
    check_partition(index, rays, position_error)
    size, reach = float(index["tile_size"]), rays.max_range
    engine = engine or InProcess()
    parts = tile_files(folder, index)
    held = building_files(folder, index) if buildings is None else {}
    _check_digests(engine, index, {**parts, **{f"b-{k}": v for k, v in held.items()}})
    signals = _signals(engine, parts, estimator)
    squares = pd.DataFrame.from_dict(index["tiles"], orient="index")
    near = _Near(squares, parts, size, reach)
    task = (size, estimator, rays, position_error)
    if buildings is None:
        plan, casts = _partition_plan(index, held, near, task)
        _check_ids(engine, folder, plan.names, casts)
    else:
        plan, casts = _held_plan(buildings, near, task)
    say(f"tile plan: {len(plan.names)} tiles of {size:g} m from {len(squares)} partitions")
    return run_tiles(plan, casts, size, estimator, engine, say, output, signals)


def _check_digests(engine: Engine, index: dict[str, Any], files: dict[str, list[Path]]) -> None:
    """Refuse a partition whose files' SHA-256 are not its index's (one task per tile, on the
    workers, where the files are, in windows: :func:`~gnss_citygml.model.engine.in_windows`)."""
    bad = in_windows(
        engine,
        (
            (
                f"sha256-{name}-{uuid.uuid4().hex[:8]}",
                check_digests,
                [(f, listed_sha256(index, f)) for f in paths],
            )
            for name, paths in files.items()
        ),
    )
    refuse_changed([f for found in bad for f in found])


def _check_ids(engine: Engine, folder: StrPath, names: list[str], casts: list) -> None:
    """Refuse a partition whose buildings share an id within a tile's reach (its own and its
    halo's, read by its worker before any tile is cast): that tile would hold one building
    twice (and fail), its neighbours with it."""
    found = in_windows(
        engine,
        (
            (f"ids-{name}-{uuid.uuid4().hex[:8]}", files_shared_id, [*cast[2], *cast[3]])
            for name, cast in zip(names, casts, strict=True)
        ),
    )
    refuse_shared_ids(folder, next((f for f in found if f is not None), None))


def _signals(engine: Engine, parts: dict[str, list[Path]], estimator: Estimator) -> Signals:
    """All the run's signals, summed over the partition's files on the workers."""

    def summed(func, *args):  # each signal is in one partition file
        sums = [
            engine.submit(func, files, *args, key=f"signals-{name}-{uuid.uuid4().hex[:8]}")
            for name, files in parts.items()
        ]
        return functools.reduce(operator.add, engine.gather(sums))

    return Signals(
        lambda: summed(file_counts), lambda offsets: summed(file_moments, offsets), estimator
    )


class _Near:
    """The receivers' partitions within reach of an extent of buildings."""

    def __init__(self, squares: pd.DataFrame, parts: dict[str, list[Path]], size, reach):
        self.x0 = squares["ix"].to_numpy() * size
        self.y0 = squares["iy"].to_numpy() * size
        self.names, self.parts, self.size, self.reach = squares.index, parts, size, reach

    def files(self, bounds: np.ndarray) -> list[Path]:
        """The files of the squares within reach of ``bounds`` (x0, y0, x1, y1)."""
        lo, hi = bounds[:2] - self.reach, bounds[2:] + self.reach
        x0, y0, size = self.x0, self.y0, self.size
        near = (x0 <= hi[0]) & (x0 + size >= lo[0]) & (y0 <= hi[1]) & (y0 + size >= lo[1])
        return [f for name in self.names[near] for f in self.parts[name]]

    def halo_box(self, bounds: np.ndarray) -> np.ndarray:
        """Where a tile's halo lies: twice the reach around its buildings' extent."""
        return np.r_[bounds[:2] - 2 * self.reach, bounds[2:] + 2 * self.reach]


def _held_plan(buildings: gpd.GeoDataFrame, near: _Near, task) -> tuple[TilePlan, list]:
    """The plan and casts of buildings held here: each tile's halo found in the tree of all."""
    geometry = buildings.geometry.to_numpy()
    tree = shapely.STRtree(geometry)
    bounds = shapely.bounds(geometry)
    names = building_tiles(buildings, near.size)
    tiles, casts = [], []
    for key, own in pd.Series(np.arange(len(names))).groupby(names):
        own = own.to_numpy()
        extent = np.r_[bounds[own, :2].min(axis=0), bounds[own, 2:].max(axis=0)]
        files = near.files(extent)
        if not files:
            continue  # no ray can enter its buildings: they have no signal, as in one run
        halo = np.sort(tree.query(shapely.box(*near.halo_box(extent))))
        halo = halo[names[halo] != key]
        tiles.append(Tile(str(key), own, halo, np.empty(0, dtype=np.int64)))
        cast = buildings.iloc[np.concatenate([own, halo])]
        casts.append((partition_part, files, cast, own.size, *task))
    return held_plan(tiles, buildings, near.size), casts


def _partition_plan(index, held: dict[str, list[Path]], near: _Near, task) -> tuple[TilePlan, list]:
    """The plan and casts of the buildings the partition holds, from its index alone: each
    tile's worker reads its own buildings and those of the tiles whose extent meets its halo
    (:func:`partition_files_part`); the neighbours are those tiles (a few more than own a
    building of the halo: their fits are shared and not used)."""
    tiles = index[BUILDINGS]["tiles"]
    names = sorted(tiles)
    extents = np.array([tiles[name]["bounds"] for name in names], dtype=float).reshape(-1, 4)
    taking, halos, casts = [], [], []
    for k, name in enumerate(names):
        files = near.files(extents[k])
        if not files:
            continue  # no ray can enter its buildings: they have no signal, as in one run
        box = near.halo_box(extents[k])
        meets = (extents[:, 0] <= box[2]) & (extents[:, 2] >= box[0])
        meets &= (extents[:, 1] <= box[3]) & (extents[:, 3] >= box[1])
        meets[k] = False
        halo = [names[j] for j in np.flatnonzero(meets)]
        taking.append(name)
        halos.append(halo)
        halo_files = [f for other in halo for f in held[other]]
        casts.append((partition_files_part, files, held[name], halo_files, box, *task))
    at = {name: k for k, name in enumerate(taking)}
    neighbours = [
        sorted({k, *(at[other] for other in halo if other in at)}) for k, halo in enumerate(halos)
    ]
    return (
        TilePlan(
            taking,
            neighbours,
            lambda k: read_building_ids(held[taking[k]]),
            lambda: [(name, held[name]) for name in names],
        ),
        casts,
    )


def partition_files_part(
    files: list[Path],
    own_files: list[Path],
    halo_files: list[Path],
    box: np.ndarray,
    size: float,
    estimator: Estimator,
    rays: Rays,
    position_error: PositionError,
) -> Part:
    """:func:`partition_part` of a tile whose buildings the partition holds: its own read from
    ``own_files``, its halo from ``halo_files`` (the buildings whose extent meets ``box``)."""
    columns = ["id", "ground", "geometry"]
    own = read_building_files(own_files, columns)
    halo = read_building_files(halo_files, columns) if halo_files else own.iloc[:0]
    b = shapely.bounds(halo.geometry.to_numpy())
    inside = (b[:, 0] <= box[2]) & (b[:, 2] >= box[0]) & (b[:, 1] <= box[3]) & (b[:, 3] >= box[1])
    cast = pd.concat([own, halo[inside]], ignore_index=True)
    return partition_part(files, cast, len(own), size, estimator, rays, position_error)


def file_moments(files: list[Path], offsets: pd.Series | None = None) -> Cn0Moments:
    """:func:`signal_moments` of the receivers in partition ``files``."""
    return signal_moments(read_receivers(files), offsets)


def file_counts(files: list[Path]) -> SkyCounts:
    """The receivers in partition ``files`` counted by phone, elevation and C/N0
    (:func:`~gnss_citygml.model.offsets.sky_counts`)."""
    return sky_counts(read_receivers(files))


def partition_part(
    files: list[Path],
    buildings: gpd.GeoDataFrame,
    n_own: int,
    size: float,
    estimator: Estimator,
    rays: Rays,
    position_error: PositionError,
) -> Part:
    """One tile's part from partition files: their rows whose rays can enter the tile's own
    buildings (the first ``n_own`` of ``buildings``;
    :func:`~gnss_citygml.tiling.grid.receiver_tiles`), numbered by their ``signal``, cast as
    :func:`tile_part` does."""
    rx = read_receivers(files)
    own = buildings.iloc[:n_own]
    e, n, bearing = (rx[c].to_numpy(dtype=float) for c in ("e", "n", "bearing"))
    rows = np.unique(receiver_tiles(e, n, own, rays.max_range, size, bearing)["row"])
    rx = rx.iloc[rows].set_index("signal")
    return tile_part(rx, buildings, n_own, estimator, rays, position_error)
