"""The stages composed: observations + footprints + DEM -> building heights.

:func:`run` (and :func:`estimate`, its heights only) runs, in order: the observations' schema
and elevation mask; the receivers in British National Grid + ODN (OSTN15/OSGM15) with grid
bearings; each building's ground from the DEM; the rays cast against the footprints
(:func:`intersections`); 4PL-B (or a baseline); and the heights joined back onto the
footprints. ``progress`` is told the name of each stage as it
starts, so a command line or QGIS can show it.

The stages themselves are in :mod:`gnss_citygml.stages` (and named here too); this module
composes them in one process (:func:`run`) and in tiles (:func:`run_partitioned`,
:func:`write_tiles`), and checks the inputs once, before any work.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import geopandas as gpd
import pandas as pd

from .calibrate import calibrate_receivers, check_map_heights
from .errors import InputError
from .files.folders import atomic_folder
from .files.ids import id_field
from .files.paths import StrPath
from .geodesy import check_bng
from .model.estimate import heights_and_signal_model
from .model.fourplb import SignalModel
from .settings import Estimator, RunSettings, Tiling
from .stages import EARTH_RADIUS as EARTH_RADIUS
from .stages import MIN_INCIDENCE as MIN_INCIDENCE
from .stages import REFRACTION as REFRACTION
from .stages import (
    in_mask,
    intersections,
    join_heights,
    open_sky,
    position_sds,
    receivers,
    recordings,
    run_receivers,
)
from .terrain import Dem, building_ground
from .tiling.buildings import BUILDINGS
from .tiling.from_partition import partitioned_heights
from .tiling.grid import building_tiles
from .tiling.output import INDEX, TileFolder, check_tile_folder, write_index
from .tiling.partition import (
    check_holds_buildings,
    check_partition,
    partition_footprints,
    partition_run,
)
from .tiling.run import TileRun, tiled_heights

__all__ = [
    "STAGES",
    "Run",
    "estimate",
    "fit_heights",
    "in_mask",
    "intersections",
    "join_heights",
    "open_sky",
    "position_sds",
    "receivers",
    "recordings",
    "run",
    "run_partitioned",
    "write_tiles",
]

#: The stages :func:`estimate` reports to ``progress``, in order.
STAGES = ("observations", "receivers", "buildings", "ray casting", "height model", "output")


@dataclass(frozen=True)
class Run:
    """What one run of the pipeline saw and decided: the heights, and the evidence behind them
    (for the report, :mod:`gnss_citygml.report`)."""

    #: One row per footprint, as :func:`estimate` returns.
    heights: gpd.GeoDataFrame
    #: The observations inside the elevation mask, with the receiver columns (:func:`receivers`).
    receivers: pd.DataFrame
    #: One row per (signal, building its ray enters) (:func:`intersections`); ``signal`` is
    #: the row of :attr:`receivers`. None for a run in tiles: they are never gathered.
    intersections: pd.DataFrame | None
    #: The buildings with their ``ground``.
    buildings: gpd.GeoDataFrame
    #: The final C/N0 signal classifier of 4PL-B or 4PL (None for the baselines).
    classifier: SignalModel | None
    #: A run in tiles' tiles whose cast failed (:attr:`~gnss_citygml.tiling.run.TileRun.failed`;
    #: their buildings' ``failed`` column says why); None for a run in one process.
    failed_tiles: pd.DataFrame | None = None


def estimate(
    observations: pd.DataFrame,
    footprints: gpd.GeoDataFrame,
    dem: Dem | None = None,
    settings: RunSettings | None = None,
    **options: Any,
) -> gpd.GeoDataFrame:
    """Building heights from observations, footprints and a DEM: the ``heights`` of
    :func:`run`, which documents the arguments."""
    return run(observations, footprints, dem, settings, **options).heights


def run(
    observations: pd.DataFrame,
    footprints: gpd.GeoDataFrame,
    dem: Dem | None = None,
    settings: RunSettings | None = None,
    *,
    progress: Callable[[str], None] | None = None,
    **changes: Any,
) -> Run:
    """Building heights from observations, footprints and a DEM, with the evidence.

    Parameters
    ----------
    observations
        The observations table (DESIGN.md), e.g. from :func:`~gnss_citygml.gnss.observe.observe`
        or :func:`~gnss_citygml.observations.read_observations`.
    footprints
        The buildings table (``id``, ``geometry`` in EPSG:27700), e.g. from
        :func:`~gnss_citygml.footprints.read_footprints`.
    dem
        A DEM rasterio opens, in EPSG:27700 (a path or an open dataset): each building's
        ``ground`` and, with receiver heights from the DEM, the receivers' heights.
    settings, changes
        The run's settings (:class:`~gnss_citygml.settings.RunSettings`; its parts by name in
        ``changes``, e.g. ``estimator=Estimator(method="4PL")``): the elevation mask and the rays'
        range (:func:`intersections`); where the antenna's height comes from
        (:func:`receivers`); the height estimator
        (:func:`~gnss_citygml.model.estimate.estimate_heights`); how far the receiver
        positions may be off (default: each observation's ``position_sd``, 1 m where it is
        empty; the fits model each height's error, ``height_sd`` of :func:`intersections`, and
        the ranges carry the roof line's; ``PositionError(sd=0)``: exact, as in the paper);
        the opt-in self-calibration of one position offset per recording, jointly with the
        heights (:func:`~gnss_citygml.calibrate.calibrate_receivers`; 4PL-B only); and with
        ``Tiling(scheduler=...)``, the rays cast and 4PL-B run in tiles on a Dask cluster
        (:func:`~gnss_citygml.tiling.run.tiled_heights`: the same heights, no machine holding
        every intersection, ``Run.intersections`` None; 4PL-B or 4PL, no self-calibration);
        the grids' folder and a DEM's CRS.
    progress
        Optional callable told the name of each stage (:data:`STAGES`) as it starts, and in
        a run in tiles what the tiles are doing within it (the plan, each iteration, a tile
        that failed).

    Returns
    -------
    Run
        ``heights``: one row per footprint: its geometry and attributes, ``ground``, the
        heights table columns and ``relative_height`` (height - ground); empty heights,
        ``converged = False`` and the reason in ``status`` where no ray enters or the estimate
        did not converge: never a guess; the id column named as the footprints' id field
        (:mod:`gnss_citygml.files.ids`). With them, the receivers, intersections, buildings
        and final signal classifier the heights came from.

    Raises
    ------
    InputError
        Self-calibration with a method other than 4PL-B, footprints not in EPSG:27700 or
        without its map heights' field (all before any work), and any stage's error.
    """
    settings = RunSettings.of(settings, **changes)
    check_map_heights(footprints, settings.calibration)
    say = progress or (lambda stage: None)
    rx, buildings = _prepared(observations, footprints, dem, settings, say)
    if settings.tiling.on:
        return _in_tiles(rx, buildings, footprints, settings, say)
    if settings.calibration.on:
        rx = calibrate_receivers(
            rx, buildings, settings.calibration, estimator=settings.estimator, rays=settings.rays
        )
    return _in_one_process(rx, buildings, id_field(footprints), settings, say)


def _in_tiles(rx, buildings, footprints, settings, say) -> Run:
    """The rest of :func:`run` on a Dask cluster: the rays cast and 4PL-B run in tiles."""
    in_tiles = _in_memory(rx, buildings, settings, settings.tiling.side, say)
    size = settings.tiling.side
    done = _on_cluster(in_tiles, buildings, settings, size, id_field(footprints), say)
    return Run(done.table, rx, None, buildings, done.classifier, done.failed)


def _in_one_process(rx, buildings, name, settings, say) -> Run:
    """The rest of :func:`run` in this process: the rays cast, the heights fitted (their id
    column called ``name``)."""
    inter = intersections(rx, buildings, rays=settings.rays, position_error=settings.position_error)
    heights, classifier = fit_heights(
        inter, buildings, settings.estimator, name, say, open_sky=open_sky(rx, inter)
    )
    return Run(heights, rx, inter, buildings, classifier)


def _prepared(observations, footprints, dem, settings, say):
    """The stages before the rays: the receivers table and the buildings with their ground."""
    rays = settings.rays
    check_bng(footprints, "footprints")
    say(STAGES[0])
    obs = in_mask(observations, rays)
    if obs.empty:
        raise InputError(
            f"no observations between {rays.min_elevation:g} and {rays.max_elevation:g} deg "
            "elevation",
            fix="check the elevation mask",
        )
    say(STAGES[1])
    rx = run_receivers(obs, dem, settings)
    _check_near(rx, footprints, rays.max_range)
    say(STAGES[2])
    buildings = _grounded(footprints, dem, settings.dem_crs)
    say(STAGES[3])
    return rx, buildings


def _grounded(footprints, dem, dem_crs):
    """The footprints with their ``ground`` from the DEM (or their own ``ground`` column)."""
    if dem is not None:
        return building_ground(footprints, dem, assume_crs=dem_crs)
    if "ground" not in footprints.columns:
        raise InputError("building ground heights need a DEM", fix="give --dem")
    return footprints


def _in_memory(rx, buildings, settings, size, say):
    """The run in tiles of receivers in memory, given an engine (and an output folder)."""
    return functools.partial(
        tiled_heights,
        rx,
        buildings,
        estimator=settings.estimator,
        rays=settings.rays,
        position_error=settings.position_error,
        tile_size=size,
        progress=say,
    )


def run_partitioned(
    folder: StrPath,
    footprints: gpd.GeoDataFrame | None,
    dem: Dem | None = None,
    settings: RunSettings | None = None,
    *,
    progress: Callable[[str], None] | None = None,
    **changes: Any,
) -> TileRun:
    """As :func:`run`, from observations partitioned by tile
    (:func:`~gnss_citygml.tiling.partition.partition_observations`) on a Dask cluster (the
    settings' ``tiling``; without settings, a local one; its tile size is the partition's):
    the heights, joined onto the footprints, with the final signal classifier and the failed
    tiles (:class:`~gnss_citygml.tiling.run.TileRun`). Each tile reads
    its own partitions (:func:`~gnss_citygml.tiling.from_partition.partitioned_heights`). The
    settings the partition applied (elevation mask, receiver heights, position-error window)
    must be the run's. ``footprints`` None: the partition's own (written with them), read
    back here to join the heights onto."""
    settings = _in_tiles_settings(settings, changes)
    say = progress or (lambda stage: None)
    in_tiles, buildings, size, name = _partitioned(folder, footprints, dem, settings, say)
    return _on_cluster(in_tiles, buildings, settings, size, name, say)


def _in_tiles_settings(settings: RunSettings | None, changes: dict[str, Any]) -> RunSettings:
    """The settings of a run in tiles (:func:`RunSettings.of`): on a local cluster when the
    caller gives no settings nor a ``tiling``."""
    if settings is None and "tiling" not in changes:
        changes = {**changes, "tiling": Tiling("local")}
    return RunSettings.of(settings, **changes)


def _partitioned(folder, footprints, dem, settings, say, *, held=False):
    """The stages before the rays of a partition's run in tiles: the run in tiles (given an
    engine and an output folder), the buildings with their ground, the tile size and the
    ids' name. Without ``footprints``, the partition's: read back here, or with ``held`` (the
    heights written per tile, never joined here) left where they are, each tile's worker
    reading its own (the buildings returned are None)."""
    index = partition_run(folder, settings.tiling)
    _check_one_set(folder, index, footprints)
    check_partition(index, settings.rays, settings.position_error, settings.receiver_heights,
                    dem, settings.dem_crs)  # fmt: skip
    own = footprints is None  # the partition's own buildings, with their ground
    if own and not held:
        footprints = partition_footprints(folder, index)
    if footprints is not None:
        check_bng(footprints, "footprints")
    say(STAGES[0])
    say(STAGES[1])  # the partition holds the receivers
    say(STAGES[2])
    if footprints is None:
        buildings, name = None, _held_ids(folder, index)
    else:
        buildings = footprints if own else _grounded(footprints, dem, settings.dem_crs)
        name = id_field(footprints)
    say(STAGES[3])
    in_tiles = functools.partial(
        partitioned_heights,
        folder,
        buildings,
        estimator=settings.estimator,
        rays=settings.rays,
        position_error=settings.position_error,
        progress=say,
    )
    return in_tiles, buildings, float(index["tile_size"]), name


def _check_one_set(
    folder: StrPath, index: dict[str, Any], footprints: gpd.GeoDataFrame | None
) -> None:
    """Refuse footprints given to a run from a partition that holds its own: two sets of
    buildings, and no telling which the user meant."""
    if footprints is not None and BUILDINGS in index:
        raise InputError(
            "the partition holds its own footprints (partition --footprints), and footprints "
            "were given too",
            where=str(folder),
            fix="leave out the footprints (and --dem), or partition again without --footprints",
        )


def _held_ids(folder: StrPath, index: dict[str, Any]) -> str:
    """The name of the ids of the buildings a partition holds, or an error if it holds none."""
    check_holds_buildings(folder, index)
    return str(index[BUILDINGS]["id_field"])


def write_tiles(
    observations: pd.DataFrame | StrPath,
    footprints: gpd.GeoDataFrame | None,
    dem: Dem | None,
    output: StrPath,
    settings: RunSettings | None = None,
    *,
    overwrite: bool = False,
    progress: Callable[[str], None] | None = None,
    **changes: Any,
) -> gpd.GeoDataFrame:
    """As :func:`run` in tiles (or :func:`run_partitioned`, when ``observations`` is a
    partition folder), with each tile's heights written into the folder ``output`` by the
    worker that fitted it (:mod:`gnss_citygml.tiling.output`), never gathered on one machine.
    Returns the tile index (also ``output/tiles.gpkg``). The folder appears whole or not at
    all; an existing one is replaced only with ``overwrite`` (checked before any work), and
    only if it is a folder of tiles (:func:`~gnss_citygml.tiling.output.check_tile_folder`).
    ``footprints`` None: the partition's own, each tile's worker reading its tile's and its
    halo's, so that this machine holds the plan only."""
    settings = _in_tiles_settings(settings, changes)
    check_tile_folder(output, settings.tiling, overwrite=overwrite)
    say = progress or (lambda stage: None)
    if isinstance(observations, pd.DataFrame):
        if footprints is None:
            raise InputError("no footprints", fix="give the footprints the observations saw")
        rx, buildings = _prepared(observations, footprints, dem, settings, say)
        size, name = settings.tiling.side, id_field(footprints)
        in_tiles = _in_memory(rx, buildings, settings, size, say)
    else:
        in_tiles, buildings, size, name = _partitioned(
            observations, footprints, dem, settings, say, held=True
        )
    done = _on_cluster(in_tiles, buildings, settings, size, name, say, output, overwrite)
    return done.table


def _on_cluster(in_tiles, buildings, settings, size, name, say, output=None, overwrite=False):
    """``in_tiles(engine=...)`` on the cluster the settings' ``tiling`` names
    (:class:`~gnss_citygml.tiling.run.TileRun`), its heights joined onto the buildings with
    each building's ``tile`` (of ``size`` metres; the tile index of the output) and that
    tile's failure, ``failed`` (empty if none): a failed tile's buildings, or one tile's, are a
    filter away. With ``output``, the tiles write their heights into that folder instead, and
    the table is the tile index."""
    from .tiling.cluster import connect  # the [dask] extra: only when asked for

    method = settings.estimator.method
    with connect(settings.tiling) as engine:
        if output is not None:
            with atomic_folder(output, overwrite=overwrite, mark=INDEX) as work:
                folder = TileFolder(str(work), method, name, size)
                done = in_tiles(engine=engine, output=folder)
                say(STAGES[4])
                say(STAGES[5])
                write_index(done.table, work)
            return done
        done = in_tiles(engine=engine)
    say(STAGES[4])
    say(STAGES[5])
    heights = join_heights(buildings, done.table, method, name)
    tiles = building_tiles(buildings, size)
    why = done.failed.set_index("tile")["reason"]
    heights.insert(len(heights.columns) - 1, "tile", tiles)
    failed = pd.Series(tiles).map(why).astype(object).fillna("").to_numpy()
    heights.insert(len(heights.columns) - 1, "failed", failed)
    return replace(done, table=heights)


def fit_heights(
    intersections: pd.DataFrame,
    buildings: gpd.GeoDataFrame,
    estimator: Estimator = Estimator(),
    name: str = "id",
    progress: Callable[[str], None] | None = None,
    open_sky: pd.DataFrame | None = None,
) -> tuple[gpd.GeoDataFrame, SignalModel | None]:
    """The height model's stage: the heights of every building (:func:`join_heights`, the id
    named ``name``) from the intersections (and the signals crossing no footprint,
    ``open_sky``, :func:`open_sky`), and the final signal model (None for the baselines).
    ``progress`` is told the model's stage and the output's."""
    say = progress or (lambda stage: None)
    say(STAGES[4])
    heights, classifier = heights_and_signal_model(intersections, estimator, open_sky=open_sky)
    say(STAGES[5])
    return join_heights(buildings, heights, estimator.method, name), classifier


def _check_near(rx: pd.DataFrame, footprints: gpd.GeoDataFrame, max_range: float) -> None:
    """Refuse receivers whose rays cannot reach the footprints' area: a wrong file or CRS."""
    x0, y0, x1, y1 = footprints.total_bounds
    far = ~(
        rx["e"].between(x0 - max_range, x1 + max_range)
        & rx["n"].between(y0 - max_range, y1 + max_range)
    )
    if far.any():
        row = rx[far].iloc[0]
        raise InputError(
            f"{int(far.sum())} observations are more than {max_range:g} m outside the "
            "footprints' area",
            where=f"first: receiver {row['receiver']} at {row['time_utc']}, "
            f"lat {row['lat']:.6f} lon {row['lon']:.6f} (E {row['e']:.0f} N {row['n']:.0f})",
            fix="give footprints that cover where the observations were made",
        )
