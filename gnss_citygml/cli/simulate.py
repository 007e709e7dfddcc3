"""The ``simulate`` subcommand: a simulated site written as the files a user brings.

Only this command loads the simulator (its module is imported when the command runs).
"""

from __future__ import annotations

import click

from ..simulate.scenes import PRESETS
from .options import GRID_DIR, OVERWRITE, SEED, output_dir


@click.command()
@click.argument("preset", type=click.Choice(list(PRESETS)))
@output_dir("Folder for observations, footprints, DEM, intersections and truth tables.")
@click.option(
    "--locations",
    type=click.Choice(["manual", "gnss"]),
    default="manual",
    show_default=True,
    help="Receiver positions: hand-surveyed or the phone's fixes.",
)
@SEED
@click.option(
    "--interval",
    type=float,
    default=1.0,
    show_default=True,
    help="Seconds between epochs (0.01 to 3600).",
)
@click.option(
    "--format", "fmt", type=click.Choice(["csv", "parquet"]), default="csv", show_default=True
)
@GRID_DIR
@OVERWRITE
def simulate(preset, output_dir, locations, seed, interval, fmt, grid_dir, overwrite):
    """Simulate a site and write the files a user brings to `estimate`: observations,
    footprints.gpkg and dem.tif (EPSG:27700), plus the intersections and the true heights."""
    from ..files.tables import write_table
    from ..simulate import simulate as run
    from ..simulate.files import check_site, write_site

    intersections = output_dir / f"intersections.{fmt}"
    check_site(output_dir, fmt, overwrite=overwrite, also=[intersections])
    sim = run(preset, locations=locations, seed=seed, interval=interval)
    write_site(sim, output_dir, grid_dir=grid_dir, fmt=fmt, overwrite=overwrite)
    write_table(sim.intersections, intersections, overwrite=overwrite)
    click.echo(
        f"{len(sim.observations)} signals, {len(sim.intersections)} intersections, "
        f"{len(sim.truth)} buildings -> {output_dir}"
    )
