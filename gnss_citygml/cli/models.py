"""Subcommands around the height model: a simulated site, heights from intersections."""

from __future__ import annotations

from pathlib import Path

import click

from ..model import METHODS
from ..simulate.scenes import PRESETS
from .observe import GRID_DIR
from .options import OVERWRITE, SEED, THRESHOLD, output_file


@click.command()
@click.argument("preset", type=click.Choice(list(PRESETS)))
@click.option(
    "--output-dir",
    "-o",
    type=click.Path(file_okay=False, path_type=Path),
    required=True,
    help="Folder for observations, intersections and truth tables.",
)
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
@click.option(
    "--method",
    type=click.Choice(list(METHODS)),
    default="4PL-B",
    show_default=True,
)
@THRESHOLD
@click.option(
    "--weighting",
    type=click.Choice(["height", "balanced", "none"]),
    default=None,
    help="Reweighting of the 4PL height fit (4PL-B and 4PL; default: none).",
)
@OVERWRITE
def heights(intersections, output, method, init_threshold, weighting, overwrite):
    """Estimate building heights from an intersections table (CSV or Parquet)."""
    from ..model.estimate import estimate_heights
    from ..tables import check_table_output, read_table, write_table

    check_table_output(output, overwrite=overwrite)
    options = {} if weighting is None else {"weighting": weighting}
    out = estimate_heights(
        read_table(intersections), method=method, init_threshold=init_threshold, **options
    )
    write_table(out, output, overwrite=overwrite)
    ok = int(out["converged"].sum())
    click.echo(f"{ok} of {len(out)} buildings converged -> {output}")
