"""The ``heights`` subcommand: the model alone, on an intersections table."""

from __future__ import annotations

from pathlib import Path

import click

from ..settings import WEIGHTINGS, Estimator
from .options import (
    FIT_MAX_ITER,
    HEIGHT_RULE,
    MAX_ITER,
    METHOD,
    OVERWRITE,
    SIGNAL_MODEL,
    THRESHOLD,
    output_file,
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
@HEIGHT_RULE
@SIGNAL_MODEL
@MAX_ITER
@FIT_MAX_ITER
@OVERWRITE
def heights(
    intersections,
    output,
    method,
    init_threshold,
    weighting,
    height_rule,
    signal_model,
    max_iter,
    fit_max_iter,
    overwrite,
):
    """Estimate building heights from an intersections table (CSV or Parquet)."""
    from ..files.tables import check_table_output, read_table, write_table
    from ..model.estimate import estimate_heights

    estimator = Estimator(
        method=method,
        init_threshold=init_threshold,
        weighting=weighting,
        height_rule=height_rule,
        signal_model=signal_model,
        max_iter=max_iter,
        fit_max_iter=fit_max_iter,
    )
    check_table_output(output, overwrite=overwrite, inputs=[intersections])
    out = estimate_heights(read_table(intersections), estimator)
    write_table(out, output, overwrite=overwrite)
    ok = int(out["converged"].sum())
    click.echo(f"{ok} of {len(out)} buildings converged -> {output}")
