"""Subcommands around the height model: a simulated site, heights from intersections."""

from __future__ import annotations

from pathlib import Path

import click

from ..settings import WEIGHTINGS, Estimator
from ..simulate.scenes import PRESETS
from .options import GRID_DIR, METHOD, OVERWRITE, SEED, THRESHOLD, output_dir, output_file


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
    "--interval", type=float, default=1.0, show_default=True, help="Seconds between epochs."
)
@click.option(
    "--format", "fmt", type=click.Choice(["csv", "parquet"]), default="csv", show_default=True
)
@GRID_DIR
@OVERWRITE
def simulate(preset, output_dir, locations, seed, interval, fmt, grid_dir, overwrite):
    """Simulate a site and write the files a user brings to `estimate`: observations,
    footprints.gpkg and dem.tif (EPSG:27700), plus the intersections and the true heights."""
    from ..simulate import simulate as run
    from ..simulate.files import check_site, write_site
    from ..tables import write_table

    intersections = output_dir / f"intersections.{fmt}"
    check_site(output_dir, fmt, overwrite=overwrite, also=[intersections])
    sim = run(preset, locations=locations, seed=seed, interval=interval)
    write_site(sim, output_dir, grid_dir=grid_dir, fmt=fmt, overwrite=overwrite)
    write_table(sim.intersections, intersections, overwrite=overwrite)
    click.echo(
        f"{len(sim.observations)} signals, {len(sim.intersections)} intersections, "
        f"{len(sim.truth)} buildings -> {output_dir}"
    )


@click.command()
@click.argument("intersections", type=click.Path(path_type=Path))
@output_file("Heights table (.csv or .parquet).")
@METHOD
@THRESHOLD
@click.option(
    "--weighting",
    type=click.Choice(list(WEIGHTINGS)),
    default=Estimator.weighting,
    show_default=True,
    help="Reweighting of the 4PL height fit (4PL-B and 4PL).",
)
@OVERWRITE
def heights(intersections, output, method, init_threshold, weighting, overwrite):
    """Estimate building heights from an intersections table (CSV or Parquet)."""
    from ..model.estimate import estimate_heights
    from ..tables import check_table_output, read_table, write_table

    estimator = Estimator(method=method, init_threshold=init_threshold, weighting=weighting)
    check_table_output(output, overwrite=overwrite)
    out = estimate_heights(read_table(intersections), estimator)
    write_table(out, output, overwrite=overwrite)
    ok = int(out["converged"].sum())
    click.echo(f"{ok} of {len(out)} buildings converged -> {output}")
