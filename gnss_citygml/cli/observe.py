"""Subcommands of the GNSS stage: ``observe`` (logs + orbits -> observations) and ``grids``."""

from __future__ import annotations

from pathlib import Path

import click

from .options import GRID_DIR, MAX_ELEVATION, MIN_ELEVATION, OVERWRITE, QUIET, output_file, progress


@click.command()
@click.argument("logs", nargs=-1, required=True, type=click.Path(path_type=Path))
@click.option(
    "--orbits",
    "orbit_files",
    multiple=True,
    required=True,
    type=click.Path(path_type=Path),
    help="SP3 or RINEX navigation file covering the logs (repeat for several).",
)
@click.option(
    "--positions",
    "surveyed",
    type=click.Path(dir_okay=False, path_type=Path),
    help="CSV of manually surveyed positions (receiver,start_utc,end_utc,lat,lon,h); "
    "default: the logs' own fixes.",
)
@click.option(
    "--provider",
    default="gps",
    show_default=True,
    help="Fix provider of the logs' positions (gps, flp, nlp).",
)
@click.option(
    "--interpolate", is_flag=True, help="Interpolate fixes in time instead of the nearest."
)
@MIN_ELEVATION
@MAX_ELEVATION
@click.option("--band", default="L1", show_default=True, help="Signal band kept (L1 or L5).")
@click.option("--lenient", is_flag=True, help="Skip bad log lines (counted) instead of failing.")
@output_file("Observations table (.parquet or .csv).")
@OVERWRITE
@QUIET
def observe(
    logs,
    orbit_files,
    surveyed,
    provider,
    interpolate,
    min_elevation,
    max_elevation,
    band,
    lenient,
    output,
    overwrite,
    quiet,
):
    """Turn GnssLogger LOGS and satellite orbits into an observations table.

    One row per epoch and satellite between the elevation masks, with the phone's C/N0, or
    empty C/N0 where the phone received nothing (a blocked signal).
    """
    from ..jobs import observe_file

    with progress(len(logs), "logs", quiet) as bar:

        def logs_done(_: str, done: float) -> None:
            bar.update(round(done * len(logs)) - bar.n)

        made = observe_file(
            logs,
            orbit_files,
            output,
            surveyed=surveyed,
            provider=provider,
            method="interpolate" if interpolate else "nearest",
            min_elevation=min_elevation,
            max_elevation=max_elevation,
            band=band,
            lenient=lenient,
            overwrite=overwrite,
            progress=logs_done,
        )
    click.echo(f"{made.summary()} -> {output}")


@click.command()
@GRID_DIR
@click.option(
    "--fetch",
    is_flag=True,
    help="Download the grids from PROJ's CDN into PROJ's user data folder (used from then on "
    "instead of the bundled copy).",
)
def grids(grid_dir, fetch):
    """Show which copy of the OSTN15 / OSGM15 grids is used, and where it comes from.

    Searched in order: --grid-dir (or $GNSS_CITYGML_GRID_DIR), PROJ's user data folder, PROJ's
    data folders, and last the copy bundled with gnss-citygml, so that nothing needs fetching.
    Exit code 1 if a grid is found nowhere (a damaged install)."""
    from ..geodesy.grids import fetch_grids, grid_status

    if fetch:
        for path in fetch_grids():
            click.echo(f"fetched {path}")
    status = grid_status(grid_dir)
    for row in status.itertuples(index=False):
        where = f"{row.path} ({row.source})" if row.found else "MISSING"
        click.echo(f"{row.grid}  {row.purpose}: {where}")
    if not status["found"].all():
        click.echo(
            "some grids are missing: reinstall gnss-citygml (it ships them), run "
            "`gnss-citygml grids --fetch`, or give the folder that holds them with --grid-dir",
            err=True,
        )
        raise SystemExit(1)
