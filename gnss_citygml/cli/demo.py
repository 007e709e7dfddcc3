"""The ``demo`` subcommand: the main job on the sample city shipped with the package.

``gnss-citygml demo -o DIR`` needs no file of the user's and no network: the sample city
(``gnss_citygml/data/city``, made by the simulator: observations, footprints, a DEM and the true
heights) and the OSTN15/OSGM15 grids are package data. It runs the commands a user runs, with
their defaults (``estimate``, then ``convert`` to CityJSON and to CityGML, each validated), so
what it shows is what they do, and then compares every estimate with the simulator's truth.
"""

from __future__ import annotations

import contextlib
import io
from pathlib import Path

import click

from .options import OVERWRITE, QUIET, output_dir

#: The sample city: ``examples/city`` in the repository is a link to it.
CITY = Path(__file__).resolve().parents[1] / "data" / "city"
#: The files the demo writes into its folder.
OUTPUTS = ("heights.gpkg", "city.city.json", "city.gml")
#: And, where matplotlib is installed, the report of the run (:mod:`gnss_citygml.report`).
REPORT_OUTPUTS = ("report.html", "figures")


@click.command()
@output_dir(
    "Folder for heights.gpkg, city.city.json, city.gml and report.html (created if needed)."
)
@OVERWRITE
@QUIET
@click.pass_context
def demo(ctx, output_dir, overwrite, quiet):
    """Run the main job on the bundled sample city and compare it with the truth.

    Estimates the heights of the 30 buildings of the simulated city (as `estimate` does, with
    the grids found as always: the copy bundled with gnss-citygml unless another is there),
    writes them to DIR/heights.gpkg and converts them to DIR/city.city.json and DIR/city.gml
    (both validated), with the report of the run, the true heights included, in
    DIR/report.html (where matplotlib is installed). Ends with one row per building (estimate,
    range, the simulator's true height, error, status; heights above the ground in metres)
    and a summary line.
    """
    from .citymodel import convert
    from .estimate import estimate

    heights, cityjson, citygml = _outputs(output_dir, overwrite)
    report = output_dir if _can_plot() else None
    # The steps' own lines are held back until every file is written: a reader that stops
    # early (`demo -o DIR | head`) must not cut the job short.
    with contextlib.redirect_stdout(io.StringIO()) as steps:
        ctx.invoke(
            estimate,
            observations=CITY / "observations.parquet",
            footprints=CITY / "footprints.gpkg",
            dem=str(CITY / "dem.tif"),
            output=heights,
            report=report,
            truth=None if report is None else CITY / "truth.csv",
            overwrite=overwrite,
            quiet=quiet,
        )
        for model in (cityjson, citygml):
            ctx.invoke(
                convert,
                input_=heights,
                layer="heights",
                output=model,
                overwrite=overwrite,
                quiet=quiet,
            )
    click.echo(steps.getvalue(), nl=False)
    if report is None:
        click.echo(
            "note: no report.html: the report needs matplotlib (pip install 'gnss-citygml[plot]')",
            err=True,
        )
    for line in _comparison(heights, CITY / "truth.csv"):
        click.echo(line)


def _can_plot() -> bool:
    """Whether matplotlib, an extra the report needs, can be imported."""
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        return False
    return True


def _outputs(folder: Path, overwrite: bool) -> list[Path]:
    """The demo's output files in ``folder``, checked before any work (made if it is new)."""
    from ..files.paths import check_output_folder, make_folder

    paths = [folder / name for name in OUTPUTS]
    check_output_folder(folder, paths, overwrite=overwrite)
    make_folder(folder)
    return paths


def _comparison(heights, truth) -> list[str]:
    """The lines comparing a heights layer (from ``estimate``) with a simulator's truth table
    (:func:`gnss_citygml.compare.compare`): one row per building, then the summary line."""
    import pyogrio

    from ..compare import compare, summary
    from ..files.tables import read_table

    est = pyogrio.read_dataframe(heights, layer="heights", read_geometry=False)
    table = compare(est, read_table(truth))
    rows = [("id", "estimate", "range", "truth", "roof span", "error", "to span")]
    for row in table.itertuples(index=False):
        ok = row.converged
        rows.append(
            (
                str(row.id),
                f"{row.estimate:.2f}" if ok else "-",
                f"{row.lower:.2f}-{row.upper:.2f}" if ok else "-",
                f"{row.truth:.2f}",
                f"{row.roof_low:.2f}-{row.roof_high:.2f}",
                f"{row.error:+.2f}" if ok else "-",
                f"{row.span_error:.2f}" if ok else "-",
            )
        )
    widths = [max(len(row[i]) for row in rows) for i in range(len(rows[0]))]
    status = ["status", *table["status"]]
    lines = [
        "heights above the ground (m); error = estimate - true height (the roof span's middle); "
        "to span = distance to the roof span (0 inside)"
    ]
    for row, words in zip(rows, status, strict=True):
        cells = [f"{c:{a}{w}}" for c, a, w in zip(row, "<>>>>>>", widths, strict=True)]
        lines.append("  ".join([*cells, words]))
    lines.append(summary(table))
    return lines
