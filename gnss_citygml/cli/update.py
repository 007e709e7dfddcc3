"""The ``update`` subcommand: new observations -> the estimate columns of a GeoPackage map."""

from __future__ import annotations

from pathlib import Path

import click

from ..settings import RunSettings
from .options import (
    DEM_CRS,
    DEM_HELP,
    FIT_MAX_ITER,
    GRID_DIR,
    HEIGHT_RULE,
    ID_FIELD,
    LAYER,
    LEVEL_PHONES,
    MAX_ITER,
    METHOD,
    QUIET,
    REPORT,
    SIGNAL_MODEL,
    THRESHOLD,
    TRUTH,
    chosen_settings,
    dem_file,
    progress,
)


@click.command()
@click.argument("map_", metavar="MAP", type=click.Path(path_type=Path))
@click.option(
    "--observations",
    "observations",
    multiple=True,
    required=True,
    type=click.Path(dir_okay=False, path_type=Path),
    help="An observations table (CSV or Parquet); give it once per file.",
)
@dem_file(DEM_HELP, required=True)
@LAYER
@ID_FIELD
@click.option(
    "--min-signals",
    type=int,
    default=1,
    show_default=True,
    help="A building gets values when the evidence holds at least this many of its signals.",
)
@click.option(
    "--threshold",
    type=float,
    default=0.5,
    show_default=True,
    help="List the buildings whose height changes by more than this (m).",
)
@click.option("--dry-run", is_flag=True, help="Say what would change; write nothing.")
@click.option("--no-backup", is_flag=True, help="Do not keep the map as it was in MAP.bak.gpkg.")
@REPORT
@TRUTH
@THRESHOLD
@METHOD
@HEIGHT_RULE
@SIGNAL_MODEL
@LEVEL_PHONES
@MAX_ITER
@FIT_MAX_ITER
@DEM_CRS
@GRID_DIR
@QUIET
def update(
    map_,
    observations,
    dem,
    layer,
    id_field,
    min_signals,
    threshold,
    dry_run,
    no_backup,
    report,
    truth,
    dem_crs,
    grid_dir,
    quiet,
    **chosen,
):
    """Update a GeoPackage MAP's building heights with new GNSS observations, safely.

    Adds or updates height_gnss, height_lower, height_upper, height_paper, c_gnss, n_signals,
    converged, method, status_gnss and updated_utc on the footprint layer; every other
    column, feature, layer and style is kept, and so are the feature ids. The evidence (every
    intersection cast) is kept in the table gnss_evidence: a later update casts only what is
    new and refits on all of it. The map is written as a whole at the end (MAP.bak.gpkg keeps
    it as it was), so a failure or Ctrl-C leaves it untouched; running again with the same data
    changes nothing.
    """
    from ..update import update_map

    with progress(100, "update", quiet) as bar:

        def told(what, done):
            bar.set_description(what)
            bar.update(round(100 * done) - bar.n)

        result = update_map(
            map_,
            observations,
            dem,
            layer=layer,
            id_field=id_field,
            min_signals=min_signals,
            threshold=threshold,
            dry_run=dry_run,
            backup=not no_backup,
            settings=RunSettings.of(**chosen_settings(chosen), grid_dir=grid_dir, dem_crs=dem_crs),
            report=report,
            truth=truth,
            progress=told,
        )
    for line in result.lines():
        click.echo(line)
    if report is not None:
        click.echo(f"report -> {report / 'report.html'}")
    if dry_run:
        click.echo("dry run: nothing written")
    elif result.written:
        kept = f" (as it was: {result.backup})" if result.backup else ""
        click.echo(f"updated -> {map_}{kept}")
