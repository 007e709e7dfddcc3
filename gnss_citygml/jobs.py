"""The jobs the command line and the QGIS plugin run: files in, one file out.

Each job is what one command does, with its options as arguments and nothing about how they
were asked for: ``gnss-citygml estimate`` and the plugin's "Estimate building heights" both
call :func:`estimate_file`, so they give the same heights (``observe`` and "Turn GnssLogger
logs into observations" both call :func:`observe_file`: the same observations). Every output
is checked before any work starts and written atomically. ``progress`` is told the name of
what is being done and the share of the job done (0 to 1) as the job goes on; it may raise to
stop the job (QGIS's cancel button), which leaves no output behind.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

from .errors import InputError
from .files.paths import StrPath
from .settings import RunSettings

if TYPE_CHECKING:
    import geopandas as gpd
    import pandas as pd

    from .export import ExportResult

__all__ = [
    "MODEL_SUFFIXES",
    "Estimated",
    "Observed",
    "Progress",
    "convert_file",
    "estimate_file",
    "export_file",
    "is_tile_folder",
    "observe_file",
    "read_buildings",
]

#: A job's progress: what is being done, and the share of the job done (0 to 1).
Progress = Callable[[str, float], None]

#: The city model formats, by file suffix: CityJSON 2.0, CityJSONSeq, CityGML 2.0 (twice).
MODEL_SUFFIXES = (".json", ".jsonl", ".gml", ".xml")


@dataclass(frozen=True)
class Estimated:
    """What :func:`estimate_file` made: the heights (every footprint with its attributes and
    the heights columns), or, where each tile's worker wrote its own, the tile index (a row per
    tile: ``buildings``, ``with_height``, ...; :func:`~gnss_citygml.tiling.output.write_index`)."""

    heights: gpd.GeoDataFrame | None = None
    tiles: pd.DataFrame | None = None

    @property
    def buildings(self) -> int:
        """How many buildings have a row."""
        if self.heights is not None:
            return len(self.heights)
        return 0 if self.tiles is None else int(self.tiles["buildings"].sum())

    @property
    def with_height(self) -> int:
        """How many of them have a height."""
        if self.heights is not None:
            return int(self.heights["converged"].sum())
        return 0 if self.tiles is None else int(self.tiles["with_height"].sum())


def _silent(what: str, done: float) -> None:
    """The progress of a job nobody watches."""


@dataclass(frozen=True)
class Observed:
    """What :func:`observe_file` made: the observations table."""

    table: pd.DataFrame

    def summary(self) -> str:
        """How many signals, received and blocked, from how many receivers."""
        signals = len(self.table)
        received = int(self.table["cn0"].notna().sum())
        receivers = self.table["receiver"].nunique()
        return (
            f"{signals} signals ({received} received, {signals - received} blocked) "
            f"from {receivers} receiver(s)"
        )


def observe_file(
    logs: Sequence[StrPath],
    orbit_files: Sequence[StrPath],
    output: StrPath,
    *,
    surveyed: StrPath | None = None,
    provider: str = "gps",
    method: str = "nearest",
    min_elevation: float = 10.0,
    max_elevation: float = 85.0,
    band: str = "L1",
    lenient: bool = False,
    overwrite: bool = False,
    progress: Progress = _silent,
) -> Observed:
    """Turn GnssLogger ``logs`` and the satellite orbits of ``orbit_files`` (SP3, RINEX
    navigation) into the observations table ``output`` (CSV or Parquet, checked before any
    log is read): :func:`gnss_citygml.gnss.observe.observe` with its options, one log after
    another (``progress`` is told each log's receiver when it is done)."""
    from .files.tables import check_table_output
    from .gnss.observe import observe
    from .observations import write_observations

    check_table_output(output, overwrite=overwrite, inputs=[*logs, *orbit_files, surveyed])
    done = 0

    def observed(receiver: str) -> None:
        nonlocal done
        done += 1
        progress(receiver, done / max(len(logs), 1))

    table = observe(
        logs, orbit_files, surveyed=surveyed, provider=provider, method=method,
        min_elevation=min_elevation, max_elevation=max_elevation, band=band, lenient=lenient,
        progress=observed,
    )  # fmt: skip
    write_observations(table, output, overwrite=overwrite)
    progress("done", 1.0)
    return Observed(table)


def estimate_file(
    observations: StrPath,
    footprints: StrPath | None,
    dem: StrPath | None,
    output: StrPath | None = None,
    *,
    report: StrPath | None = None,
    truth: StrPath | None = None,
    layer: str | None = None,
    id_field: str | None = None,
    settings: RunSettings | None = None,
    overwrite: bool = False,
    progress: Progress = _silent,
    **changes: Any,
) -> Estimated:
    """Estimate the height of every footprint; write the layer ``heights`` to ``output`` and
    the report of the run (:mod:`gnss_citygml.report`) into the folder ``report``.

    ``output`` is a GeoPackage (other layers of an existing one are kept; the layer gets the
    toolkit's QGIS style as its default), a FlatGeobuf or a GeoParquet file. ``truth`` (a
    simulator's truth table, CSV or Parquet) adds the true heights to the report. Returns the
    heights (:class:`Estimated`; see :func:`gnss_citygml.pipeline.run` for the ``settings``
    and their ``changes``). Both outputs are
    checked before any work; one of them must be given. ``observations`` may be a partition
    folder (:mod:`gnss_citygml.tiling.partition`), read tile by tile in a run with ``tiling``
    (:func:`gnss_citygml.pipeline.run_partitioned`); one written with its footprints needs
    neither ``footprints`` nor ``dem`` (None). In a run with ``tiling``, an ``output``
    without a suffix is a folder that each tile's worker writes its heights into
    (:func:`~gnss_citygml.pipeline.write_tiles`): the heights are not gathered, and the tile
    index is returned instead."""
    from .footprints import read_footprints
    from .observations import read_observations
    from .pipeline import STAGES, run, run_partitioned, write_tiles

    settings = RunSettings.of(settings, **changes)  # checked before any file is read
    index, folder, true = _check_estimate(
        observations, footprints, dem, output, report, truth, layer, settings, overwrite
    )
    steps = [*STAGES, "report"] if report is not None else list(STAGES)
    stage = _stage_progress(steps, progress)
    obs = None if index is not None else read_observations(observations)  # a partition: per tile
    fp = None  # without footprints, the partition's own: read by each tile's worker, or here
    if footprints is not None:
        fp = read_footprints(footprints, layer=layer, id_field=id_field, grid_dir=settings.grid_dir)
    if folder is not None:  # each tile's heights are written by its worker
        given = observations if obs is None else obs
        index = write_tiles(given, fp, dem, folder, settings, overwrite=overwrite, progress=stage)
        progress("done", 1.0)
        return Estimated(tiles=index)
    if obs is None:
        done = run_partitioned(observations, fp, dem, settings, progress=stage)
        heights = cast("gpd.GeoDataFrame", done.table)  # joined onto the footprints
        result = None
    else:  # (footprints given: _check_estimate refuses a file of observations without)
        result = run(obs, cast("gpd.GeoDataFrame", fp), dem, settings, progress=stage)
        heights = result.heights
    made = _provenance("estimate", settings, observations=observations, footprints=footprints,
                       dem=dem)  # fmt: skip
    _write_outputs(heights, result, output, report, true, overwrite, stage, made)
    progress("done", 1.0)
    return Estimated(heights=heights)


def _provenance(command: str, settings: Any, **inputs: StrPath | None) -> dict[str, Any]:
    """The provenance record of an output (:mod:`gnss_citygml.files.provenance`)."""
    from .files.provenance import provenance

    return provenance(command, settings, inputs.items())


def _write_outputs(heights, result, output, report, true, overwrite, stage, made) -> None:
    """The heights layer into ``output`` and, from a single run's ``result``, the report,
    each with the provenance record ``made``."""
    from .files.styles import heights_qml
    from .files.tables import write_layer
    from .report import write_report

    if output is not None:
        style = heights_qml()
        write_layer(heights, output, "heights", overwrite=overwrite, style=style, provenance=made)
    if result is not None and report is not None:
        stage("report")
        write_report(result, report, truth=true, overwrite=overwrite, provenance=made)


def _check_estimate(
    observations, footprints, dem, output, report, truth, layer, settings, overwrite
) -> tuple[dict[str, Any] | None, StrPath | None, pd.DataFrame | None]:
    """:func:`estimate_file`'s checks of its files, before any work: the outputs never over an
    input, a report only where the intersections are gathered, footprints and a DEM unless a
    partition holds the buildings. Returns the index of the partition ``observations`` is
    (None: a file), the tile folder to write into (None: one file), and the truth table, read
    (None without one)."""
    from .files.paths import check_not_input
    from .files.tables import check_layer_output
    from .report import check_report_request
    from .tiling.grid import check_reach
    from .tiling.output import check_tile_folder
    from .tiling.partition import partition_run

    tiling = settings.tiling
    if output is None and report is None:
        raise InputError("nothing to write", fix="give an output file or a report folder")
    if tiling.on and report is not None:
        raise InputError(
            "the report needs every intersection on one machine, and a run on a Dask "
            "scheduler does not gather them",
            fix="leave out --report, or --scheduler",
        )
    inputs = [observations, footprints, dem, truth]  # never written over (nor into)
    true = check_report_request(report, truth, overwrite=overwrite, inputs=inputs)
    index = partition_run(observations, tiling) if Path(observations).is_dir() else None
    if index is None and tiling.on:
        check_reach(tiling.side, settings.rays.max_range)  # (before a cluster starts)
    _check_buildings_given(footprints, dem, index)
    folder = output if output is not None and is_tile_folder(output) else None
    if folder is not None:
        check_not_input(check_tile_folder(folder, tiling, overwrite=overwrite), inputs)
    elif output is not None:
        check_layer_output(output, "heights", overwrite=overwrite, inputs=inputs, read_layer=layer)
    return index, folder, true


def _check_buildings_given(footprints, dem, index: dict[str, Any] | None) -> None:
    """Refuse a run without footprints, or without a DEM, unless its partition holds the
    buildings with their ground (and the receivers with their heights)."""
    from .tiling.buildings import BUILDINGS

    held = index is not None and BUILDINGS in index
    if footprints is None and not held:
        raise InputError(
            "no footprints",
            fix="give the FOOTPRINTS file, or a partition written with --footprints",
        )
    if dem is None and index is None:
        raise InputError("no DEM", fix="give --dem (a raster or a folder of its tiles)")


def _stage_progress(steps: list[str], progress: Progress) -> Callable[[str], None]:
    """The pipeline's progress callback: each of ``steps`` that starts moves the share done
    on; anything else is news within the current one (a tile run's)."""
    stages = iter(range(len(steps)))
    done = 0.0

    def stage(name: str) -> None:
        nonlocal done
        if name in steps:
            done = next(stages) / len(steps)
        progress(name, done)

    return stage


def is_tile_folder(output: StrPath) -> bool:
    """Whether ``output`` names a folder of tiles (no suffix; :mod:`gnss_citygml.tiling.output`)
    rather than one file."""
    return Path(output).suffix == ""


def read_buildings(
    path: StrPath,
    *,
    layer: str | None = None,
    id_field: str | None = None,
    dem: StrPath | None = None,
    dem_crs: str | None = None,
    grid_dir: StrPath | None = None,
) -> gpd.GeoDataFrame:
    """The footprints in EPSG:27700 (through the OSTN15/OSGM15 grids in ``grid_dir`` when in
    another CRS), with their ground from the DEM when one is given. A folder of heights a run
    in tiles wrote (:mod:`gnss_citygml.tiling.output`) is read whole, every tile's (or its
    ``heights`` folder, or one tile's folder), checked against its tile index first."""
    from .footprints import read_footprints
    from .terrain import building_ground
    from .tiling.output import run_folder_heights

    path = run_folder_heights(path) or path  # a folder of tiles: as its tile index lists it
    frame = read_footprints(path, layer=layer, id_field=id_field, grid_dir=grid_dir)
    return frame if dem is None else building_ground(frame, dem, assume_crs=dem_crs)


def _model_writer(
    output: StrPath,
    *,
    overwrite: bool = False,
    typed_attributes: bool = False,
    ranges: bool = False,
    grid_dir: StrPath | None = None,
    title: str | None = None,
    inputs: Iterable[object] = (),
) -> Callable[..., ExportResult]:
    """The writer for the format ``output`` names (:data:`MODEL_SUFFIXES`, or a folder's
    ``tileset.json`` for 3D Tiles), checked before any work, also against the job's ``inputs``
    (typed attributes are CityJSON's: CityGML's generic attributes and 3D Tiles' properties are
    typed already; ``ranges`` are drawn in 3D Tiles only)."""
    from .export import write_citygml, write_cityjson, write_cityjsonseq
    from .export.tiles3d import TILESET, write_3dtiles
    from .files.folders import check_new_folder
    from .files.paths import check_not_input, check_output

    if Path(output).name == TILESET:
        folder = check_new_folder(Path(output).parent, overwrite=overwrite, mark=TILESET)
        check_not_input(folder, inputs)
        if typed_attributes:
            raise InputError(
                "typed attributes are for CityJSON: 3D Tiles' properties are typed already",
                where=str(output),
                fix="leave --typed-attributes off",
            )
        return functools.partial(write_3dtiles, ranges=ranges, grid_dir=grid_dir, title=title)
    if ranges:
        raise InputError(
            "the heights' ranges are drawn in 3D Tiles only",
            where=str(output),
            fix=f"write FOLDER/{TILESET}, or leave --ranges off",
        )
    path = check_output(output, overwrite=overwrite, suffixes=MODEL_SUFFIXES)
    check_not_input(path, inputs)
    suffix = path.suffix.lower()
    writer: Callable[..., ExportResult] = {
        ".jsonl": write_cityjsonseq,
        ".json": write_cityjson,
    }.get(suffix, write_citygml)
    if typed_attributes and writer is write_citygml:
        raise InputError(
            "typed attributes are for CityJSON: CityGML's generic attributes are typed already",
            where=str(output),
            fix="write .city.json or .city.jsonl, or leave the typed attributes off",
        )
    typed = {"typed_attributes": True} if typed_attributes else {}
    return functools.partial(writer, title=title, **typed)


def _model_job(
    output: StrPath,
    buildings: Callable[[], gpd.GeoDataFrame],
    writer: Callable[..., ExportResult],
    progress: Progress,
    **options: Any,
) -> ExportResult:
    """Make the buildings (with ``ground`` and ``height``) with ``buildings``, write them as
    the city model ``output`` with ``writer`` (:func:`_model_writer`, called first: it checks
    the output before any work) and its ``options`` (overwrite, strict, validate,
    schema_dir); the result lists the buildings skipped and why."""
    progress("reading", 0.0)
    frame = buildings()
    total = max(len(frame), 1)
    written = 0

    def counted(n: int) -> None:
        nonlocal written
        written += n
        progress("writing", written / total)

    result = writer(frame, output, progress=counted, **options)
    progress("done", 1.0)  # (skipped buildings are not counted as they go)
    return result


def convert_file(
    source: StrPath,
    output: StrPath,
    *,
    layer: str | None = None,
    id_field: str | None = None,
    height_field: str = "height",
    relative: bool = False,
    ground_field: str | None = None,
    fallback_field: str | None = None,
    fallback_relative: bool = False,
    dem: StrPath | None = None,
    dem_crs: str | None = None,
    grid_dir: StrPath | None = None,
    overwrite: bool = False,
    strict: bool = False,
    validate: bool = True,
    schema_dir: StrPath | None = None,
    typed_attributes: bool = False,
    ranges: bool = False,
    title: str | None = None,
    progress: Progress = _silent,
) -> ExportResult:
    """Turn a polygon layer with a height field into a validated LOD1 city model (or 3D Tiles,
    ``output`` a folder's ``tileset.json``; ``ranges`` draws each height's interval there).

    The height is absolute (m ODN) unless ``relative`` (a heights layer says it of its own
    fields); the ground comes from ``ground_field`` or from the ``dem`` (one of the two, or the
    layer's ``ground`` column as the heights layer of :func:`estimate_file` has). The
    buildings without a usable height take ``fallback_field``'s, if given (above the ground
    if ``fallback_relative``), and every building says where its height came from
    (``height_source``: :func:`~gnss_citygml.export.heights.buildings_with_heights`)."""
    from .export import buildings_with_heights
    from .terrain import building_ground

    if ground_field is not None and dem is not None:
        raise InputError(
            "the ground is given twice, by a field and by a DEM",
            where=str(source),
            fix="give the ground field or the DEM, not both",
        )

    def buildings() -> gpd.GeoDataFrame:
        frame = read_buildings(source, layer=layer, id_field=id_field, grid_dir=grid_dir)
        if dem is not None:
            grounded = building_ground(frame, dem, assume_crs=dem_crs)
            if "ground" in frame.columns:
                _check_one_ground(frame["ground"], grounded["ground"], source)
            frame = grounded
        return buildings_with_heights(
            frame,
            height_field,
            relative=relative,
            ground_field=ground_field,
            fallback_field=fallback_field,
            fallback_relative=fallback_relative,
        )

    writer = _model_writer(
        output, overwrite=overwrite, typed_attributes=typed_attributes, ranges=ranges,
        grid_dir=grid_dir, title=title, inputs=[source, dem],
    )  # fmt: skip
    made = _provenance(
        "convert",
        {"height_field": height_field, "relative": relative, "ground_field": ground_field,
         "fallback_field": fallback_field, "fallback_relative": fallback_relative,
         "layer": layer, "id_field": id_field,
         "dem_crs": dem_crs, "strict": strict, "ranges": ranges},
        source=source, dem=dem,
    )  # fmt: skip
    return _model_job(
        output, buildings, writer, progress,
        overwrite=overwrite, strict=strict, validate=validate, schema_dir=schema_dir,
        provenance=made,
    )  # fmt: skip


def _check_one_ground(ground: pd.Series, dem_ground: pd.Series, where: StrPath) -> None:
    """Refuse a DEM beside the heights' own ``ground`` column (estimate's: the ground of the DEM
    they were estimated on) where the two differ by more than a millimetre, building by
    building in the same order: the DEM's would change each building's height above the
    ground and leave ``relative_height`` saying the old one. The same DEM given again passes."""
    import numpy as np

    column, dem = ground.to_numpy(dtype=float), dem_ground.to_numpy(dtype=float)
    off = ~(np.abs(column - dem) <= 1e-3) & ~(np.isnan(column) & np.isnan(dem))
    if off.any():
        worst = np.nanmax(np.abs(column - dem)) if np.isfinite(column - dem).any() else np.nan
        raise InputError(
            f"the ground is given twice, by the column ground and by a DEM, and they differ "
            f"for {int(off.sum())} of {off.size} buildings (by up to {worst:.2f} m)",
            where=str(where),
            fix="leave out --dem (the heights stand on the ground of their column), "
            "or drop the column ground and its relative_height",
        )


def export_file(
    heights: StrPath,
    footprints: StrPath,
    output: StrPath,
    *,
    layer: str | None = None,
    id_field: str | None = None,
    dem: StrPath | None = None,
    dem_crs: str | None = None,
    grid_dir: StrPath | None = None,
    overwrite: bool = False,
    strict: bool = False,
    validate: bool = True,
    schema_dir: StrPath | None = None,
    typed_attributes: bool = False,
    ranges: bool = False,
    title: str | None = None,
    progress: Progress = _silent,
) -> ExportResult:
    """Write the city model (or 3D Tiles, as :func:`convert_file`) of a heights table (CSV or
    Parquet) for the footprints it was estimated for; the ground from the table's ``ground``
    column or from the ``dem``."""
    from .export import footprints_with_heights
    from .files.ids import id_field as field_of
    from .files.tables import read_table

    def buildings() -> gpd.GeoDataFrame:
        frame = read_buildings(
            footprints, layer=layer, id_field=id_field, dem=dem, dem_crs=dem_crs, grid_dir=grid_dir
        )
        table = read_table(heights, text=[field_of(frame)])  # (the ids as text, by any name)
        if dem is None or "ground" not in table.columns:
            return footprints_with_heights(frame, table, where=str(heights))
        joined = footprints_with_heights(frame.drop(columns="ground"), table, where=str(heights))
        _check_one_ground(joined["ground"], frame["ground"], heights)  # (rows in one order)
        return joined

    writer = _model_writer(
        output, overwrite=overwrite, typed_attributes=typed_attributes, ranges=ranges,
        grid_dir=grid_dir, title=title, inputs=[heights, footprints, dem],
    )  # fmt: skip
    made = _provenance(
        "export",
        {"layer": layer, "id_field": id_field, "dem_crs": dem_crs, "strict": strict,
         "ranges": ranges},
        heights=heights, footprints=footprints, dem=dem,
    )  # fmt: skip
    return _model_job(
        output, buildings, writer, progress,
        overwrite=overwrite, strict=strict, validate=validate, schema_dir=schema_dir,
        provenance=made,
    )  # fmt: skip
