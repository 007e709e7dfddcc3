"""The ``estimate`` and ``report`` subcommands: observations + footprints + DEM -> building
heights, and the report of the run (HTML and PNGs)."""

from __future__ import annotations

from pathlib import Path

import click

from ..settings import RunSettings, Tiling
from .options import (
    ANTENNA_HEIGHT,
    DEM_CRS,
    DEM_HELP,
    FIT_MAX_ITER,
    GRID_DIR,
    HEIGHT_RULE,
    ID_FIELD,
    LAYER,
    LEVEL_PHONES,
    MAX_ELEVATION,
    MAX_ITER,
    METHOD,
    MIN_ELEVATION,
    OVERWRITE,
    POSITION_DISTANCE,
    POSITION_WINDOW,
    QUIET,
    RECEIVER_HEIGHT,
    REPORT,
    SIGNAL_MODEL,
    THRESHOLD,
    TILE_SIZE,
    TRUTH,
    chosen_settings,
    dem_file,
    option,
    output_dir,
    progress,
    together,
)

#: The options of the run, which ``estimate`` and ``report`` share.
_RUN_OPTIONS = together(
    click.argument("observations", type=click.Path(path_type=Path)),
    click.argument("footprints", type=click.Path(path_type=Path), required=False),
    dem_file(DEM_HELP + " Not needed with a partition written with --footprints."),
    LAYER,
    ID_FIELD,
    MIN_ELEVATION,
    MAX_ELEVATION,
    RECEIVER_HEIGHT,
    ANTENNA_HEIGHT,
    THRESHOLD,
    METHOD,
    HEIGHT_RULE,
    SIGNAL_MODEL,
    LEVEL_PHONES,
    MAX_ITER,
    FIT_MAX_ITER,
    option("MAX_RANGE"),
    option("POSITION_SD"),
    POSITION_DISTANCE,
    POSITION_WINDOW,
    option("CALIBRATION_SD"),
    option("CALIBRATION_WINDOW"),
    option("CALIBRATION_MATCHING"),
    option("CALIBRATION_HEIGHTS"),
    option("CALIBRATION_HEIGHTS_SD"),
    TRUTH,
    DEM_CRS,
    GRID_DIR,
    OVERWRITE,
    QUIET,
)


@click.command()
@click.option(
    "--output",
    "-o",
    type=click.Path(path_type=Path),
    required=True,
    help="Output layer 'heights': a GeoPackage (.gpkg; other layers of an existing one are "
    "kept), FlatGeobuf (.fgb) or GeoParquet (.parquet). With --scheduler, a name without a "
    "suffix is a folder the workers write tile by tile: heights/tile=NAME/part-0.parquet "
    "and the tile index tiles.gpkg.",
)
@REPORT
@_RUN_OPTIONS
@click.option(
    "--scheduler",
    help="Run in tiles on Dask (pip install 'gnss-citygml[dask]'): 'local' starts a cluster "
    "on this machine, tcp://HOST:PORT uses a running scheduler. The heights are the same as "
    "without it. Not with --report or self-calibration.",
)
@click.option(
    "--workers",
    type=click.IntRange(min=1),
    help="With --scheduler local: worker processes (default: one per core).",
)
@TILE_SIZE
def estimate(output, report, scheduler, workers, tile_size, **options):
    """Estimate the height of every footprint from GNSS OBSERVATIONS.

    OBSERVATIONS is the observations table (CSV or Parquet: time_utc, receiver, lat, lon, h,
    constellation, svid, azimuth, elevation, cn0 with empty = blocked). FOOTPRINTS is a
    GeoPackage or any polygon layer, OS MasterMap Topography GML, or GeoParquet; leave it (and
    --dem) out when OBSERVATIONS is a partition written with --footprints. The output holds
    each footprint with its estimate; buildings with too little data have empty heights.
    """
    tiling = Tiling(scheduler=scheduler, workers=workers, size=tile_size)
    made = _run(output, report, tiling=tiling, **options)
    tiles = "" if made.tiles is None else f" ({len(made.tiles)} tiles)"
    click.echo(f"{made.with_height} of {made.buildings} buildings have a height -> {output}{tiles}")
    if tiling.on:
        from ..tiling.run import failed_tiles

        table = made.heights if made.tiles is None else made.tiles
        for tile, why, n in failed_tiles(table).itertuples(index=False):
            click.echo(
                f"warning: tile {tile} failed ({why}): {n} buildings without a height", err=True
            )
    if report is not None:
        click.echo(f"report -> {report / 'report.html'}")


@click.command()
@output_dir("Folder for report.html and figures/*.png (created if needed).")
@_RUN_OPTIONS
def report(output_dir, **options):
    """Estimate as `estimate` does and write the report of the run: an HTML page and PNGs.

    A map of the buildings by height (those without one hatched by their status) with the
    receivers' tracks; the ranges; the height fits of the worst, best and sampled buildings;
    skyplots; C/N0 by final label with the signal classifier; a table of every building.
    Needs matplotlib (pip install 'gnss-citygml[plot]').
    """
    _run(None, output_dir, **options)
    click.echo(f"report -> {output_dir / 'report.html'}")


def _run(
    output,
    report,
    observations,
    footprints,
    dem,
    layer,
    id_field,
    truth,
    dem_crs,
    grid_dir,
    overwrite,
    quiet,
    tiling=Tiling(),
    **chosen,
):
    """Build the settings from the options (``chosen``: those of
    :data:`gnss_citygml.options.OPTIONS`) and run :func:`gnss_citygml.jobs.estimate_file` with
    a progress bar over its stages."""
    from ..jobs import estimate_file
    from ..pipeline import STAGES

    settings = RunSettings.of(
        **chosen_settings(chosen), tiling=tiling, dem_crs=dem_crs, grid_dir=grid_dir
    )
    steps = len(STAGES) + (report is not None)
    with progress(steps, "stages", quiet) as bar:

        def stage(name, done):
            bar.set_description(name)
            bar.update(round(done * steps) - bar.n)

        return estimate_file(
            observations,
            footprints,
            dem,
            output,
            report=report,
            truth=truth,
            layer=layer,
            id_field=id_field,
            settings=settings,
            overwrite=overwrite,
            progress=stage,
        )
