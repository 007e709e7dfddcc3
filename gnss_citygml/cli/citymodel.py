"""Subcommands around city models: convert a footprint layer, export heights, validate a file.

``convert`` and ``export`` write a file, or with ``-o -`` CityJSONSeq to standard output: the
model is written and validated in a temporary file first and only then copied to standard
output, so a failed run puts nothing there (a reader such as ``cjio stdin`` would take a
partial stream for a whole city); every message goes to standard error.
"""

from __future__ import annotations

import contextlib
import functools
import os
import shutil
import sys
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING

import click

from ..errors import InputError, escape_controls, user_text
from ..files.paths import write_error
from .options import (
    DEM_CRS,
    GRID_DIR,
    ID_FIELD,
    LAYER,
    MODEL_OUTPUT,
    OVERWRITE,
    QUIET,
    SCHEMA_DIR,
    STDOUT,
    TYPED_ATTRIBUTES,
    dem_file,
    footprints_file,
    progress,
    together,
)

if TYPE_CHECKING:
    from ..export import ExportResult

_MODEL_OPTIONS = together(
    MODEL_OUTPUT,
    OVERWRITE,
    click.option("--strict", is_flag=True, help="Stop if a building has no usable height."),
    click.option("--no-validate", "no_validate", is_flag=True, help="Skip validating the output."),
    SCHEMA_DIR,
    TYPED_ATTRIBUTES,
    click.option(
        "--title", help="The model's title (CityJSON metadata, CityGML gml:name, 3D Tiles)."
    ),
    click.option(
        "--ranges",
        is_flag=True,
        help="3D Tiles: draw each height's interval (height_lower to height_upper) as a "
        "translucent prism.",
    ),
    QUIET,
)


def _run(job: Callable[..., ExportResult], output: Path, quiet: bool, **options) -> None:
    """Run ``job`` (a job of :mod:`gnss_citygml.jobs` writing a city model to the path it is
    given first) with ``options``, for ``output``, with a progress bar; report what was
    written and skipped."""
    with _staged(output) as path, progress(100, "writing", quiet) as bar:

        def told(what: str, done: float) -> None:
            bar.set_description(what)
            bar.update(round(100 * done) - bar.n)

        result = job(path, progress=told, **options)
    for building, reason in result.skipped.itertuples(index=False):
        click.echo(f"skipped {user_text(building)}: {reason}", err=True)
    notes = result.report.notes if result.report is not None and not quiet else []
    for note in notes:  # what the validation left out, which validators ran
        click.echo(f"note: {escape_controls(note)}", err=True)
    to = "standard output" if output == STDOUT else str(output)
    click.echo(result.summary(to), err=output == STDOUT)


def _options(
    layer, id_field, dem, dem_crs, grid_dir, overwrite, strict, no_validate, schema_dir, typed,
    title, ranges,
) -> dict:  # fmt: skip
    """The options ``convert`` and ``export`` share, as the jobs name them."""
    return {
        "layer": layer,
        "id_field": id_field,
        "dem": dem,
        "dem_crs": dem_crs,
        "grid_dir": grid_dir,
        "overwrite": overwrite,
        "strict": strict,
        "validate": not no_validate,
        "schema_dir": schema_dir,
        "typed_attributes": typed,
        "title": title,
        "ranges": ranges,
    }


@contextlib.contextmanager
def _staged(output: Path) -> Iterator[Path]:
    """The path to write ``output`` to: itself, or for standard output a temporary file that
    is copied there when the writer has finished without an error (else nothing is)."""
    if output != STDOUT:
        yield output
        return
    if sys.stdout is None:  # (the command was started with its standard output closed: >&-)
        raise InputError(
            "standard output is closed",
            where="-o -",
            fix="give the command one (> FILE, or | cjio stdin ...), or write a file with -o FILE",
        )
    with tempfile.TemporaryDirectory(prefix="gnss-citygml-") as folder:
        path = Path(folder) / "stdout.city.jsonl"
        yield path
        _copy_to_stdout(path)


def _copy_to_stdout(path: Path) -> None:
    """Copy a file to standard output; a reader that stops early (``| head``) is one error
    line, not a traceback."""
    stream = sys.stdout.buffer  # click.get_binary_stream is deprecated (gone in Click 9)
    try:
        with open(path, "rb") as source:
            shutil.copyfileobj(source, stream, 1 << 20)
        stream.flush()
    except BrokenPipeError:
        _stdout_gone(stream)
        raise InputError(
            "standard output was closed before the whole city model was written",
            where="-o -",
            fix="let the reader take all of it, or write a file with -o FILE",
        ) from None
    except OSError as exc:  # e.g. > /dev/full, or a full disk under a redirection
        _stdout_gone(stream)
        error = write_error(exc, "standard output, -o -")
        if error is None:
            raise
        raise error from None


def _stdout_gone(stream) -> None:
    """What is left in Python's buffer for a standard output that failed goes nowhere at
    exit, instead of a second error."""
    os.dup2(os.open(os.devnull, os.O_WRONLY), stream.fileno())


@click.command()
@click.argument("input_", metavar="INPUT", type=click.Path(path_type=Path))
@LAYER
@ID_FIELD
@click.option(
    "--height-field",
    default="height",
    show_default=True,
    help="Field with the roof height in metres (absolute ODN unless --relative).",
)
@click.option(
    "--relative",
    is_flag=True,
    help="The height field is above the ground (a heights layer says it of its own fields: "
    "relative_height is, height and height_gnss are not).",
)
@click.option("--ground-field", help="Field with the ground height (m ODN).")
@click.option(
    "--fallback-field",
    help="Field whose height the buildings without a usable height get (e.g. OS's relh2, with "
    "--fallback-relative); each building's height_source says where its height came from.",
)
@click.option(
    "--fallback-relative",
    is_flag=True,
    help="The fallback field is above the ground (as --relative is for the height field).",
)
@dem_file("DEM for the ground under each footprint (instead of --ground-field).")
@DEM_CRS
@GRID_DIR
@_MODEL_OPTIONS
def convert(
    input_,
    layer,
    id_field,
    height_field,
    relative,
    ground_field,
    fallback_field,
    fallback_relative,
    dem,
    dem_crs,
    grid_dir,
    output,
    overwrite,
    strict,
    no_validate,
    schema_dir,
    typed_attributes,
    title,
    ranges,
    quiet,
):
    """Turn footprints with a height attribute into CityJSON, CityJSONSeq, CityGML LOD1 or 3D Tiles.

    INPUT is the heights layer of `estimate` or any polygon source with a height field (e.g.
    OS Building Height Attribute's abshmax, or relh2 with --relative; the heights of estimate
    with OS's relh2 for the rest: --fallback-field relh2 --fallback-relative). The heights a run in
    tiles wrote into a folder are read as GeoParquet: FOLDER/heights for all of them,
    FOLDER/heights/tile=TQ2982 for one tile.
    """
    from ..jobs import convert_file

    job = functools.partial(
        convert_file,
        input_,
        height_field=height_field,
        relative=relative,
        ground_field=ground_field,
        fallback_field=fallback_field,
        fallback_relative=fallback_relative,
    )
    options = _options(
        layer, id_field, dem, dem_crs, grid_dir, overwrite, strict, no_validate, schema_dir,
        typed_attributes, title, ranges,
    )  # fmt: skip
    _run(job, output, quiet, **options)


@click.command()
@click.argument("heights", type=click.Path(path_type=Path))
@footprints_file(
    "The footprints the heights were estimated for (GeoPackage, MasterMap GML).", required=True
)
@LAYER
@ID_FIELD
@dem_file("DEM for the ground, when the heights table has no ground column.")
@DEM_CRS
@GRID_DIR
@_MODEL_OPTIONS
def export(
    heights,
    footprints,
    layer,
    id_field,
    dem,
    dem_crs,
    grid_dir,
    output,
    overwrite,
    strict,
    no_validate,
    schema_dir,
    typed_attributes,
    title,
    ranges,
    quiet,
):
    """Write the city model of a heights table (CSV or Parquet, from `heights`)."""
    from ..jobs import export_file

    job = functools.partial(export_file, heights, footprints)
    options = _options(
        layer, id_field, dem, dem_crs, grid_dir, overwrite, strict, no_validate, schema_dir,
        typed_attributes, title, ranges,
    )  # fmt: skip
    _run(job, output, quiet, **options)


@click.command()
@click.argument("path", type=click.Path(path_type=Path))
@SCHEMA_DIR
@click.option(
    "--max-errors",
    type=click.IntRange(min=0),
    default=50,
    show_default=True,
    help="Errors listed (all are counted).",
)
def validate(path, schema_dir, max_errors):
    """Check a CityGML 2.0, CityJSON, CityJSONSeq file or 3D Tiles tileset.json: exit 0 valid,
    1 invalid, 2 error.

    One line per error: object id (- for the whole file; a tileset's file), rule, message. A
    file cut short or not well-formed is invalid (1); one that cannot be checked (missing, not
    a city model, a CityGML with a <!DOCTYPE>, schemas missing) is an error (2). A tileset is
    checked against the 3D Tiles 1.1 schemas (bundled), its GLBs by the package's own checks
    and, when node is found, Khronos' glTF validator (a note says which ran)."""
    from ..validate import validate_file

    report = validate_file(path, schema_dir=schema_dir)
    for issue in report.errors[:max_errors]:
        click.echo(issue.line())
    if len(report.errors) > max_errors:
        counts = ", ".join(f"{rule} {n}" for rule, n in report.rule_counts().items())
        click.echo(f"... {len(report.errors) - max_errors} more ({counts})")
    for note in report.notes:
        click.echo(f"note: {escape_controls(note)}", err=True)
    click.echo(report.summary())
    sys.exit(report.exit_code)


@click.command()
@click.argument("path", type=click.Path(path_type=Path))
@LAYER
@click.option("--json", "as_json", is_flag=True, help="Print the record as JSON.")
def info(path, layer, as_json):
    """Print where an output came from: the version, command, settings and inputs (SHA-256).

    PATH is the heights GeoPackage, a CityJSON, CityJSONSeq or CityGML model, a 3D Tiles
    tileset (its tileset.json or folder) or a report page."""
    import json

    from ..files.provenance import plain, read_provenance

    record = plain(read_provenance(path, layer=layer))  # (1e999 is JSON, infinity is not)
    if as_json:
        click.echo(json.dumps(record, indent=1, allow_nan=False))
        return
    for key in ("software", "created", "command"):
        click.echo(f"{key + ':':<10}{_shown(record.get(key))}")
    click.echo("inputs:")
    for item in record.get("inputs", []):
        size = item.get("bytes")
        click.echo(
            f"  {_shown(item.get('role')):<13}{_shown(item.get('name')):<32}"
            f"{'-' if size is None else f'{size:,}':>14} B  sha256 {_shown(item.get('sha256'))}"
        )
    click.echo("settings:")
    for line in json.dumps(record.get("settings", {}), indent=1).splitlines()[1:-1]:
        click.echo(f" {line}")  # (json.dumps escapes every control and non-ASCII character)


def _shown(value: str | None) -> str:
    """A record's value as ``info`` prints it: escaped and cut (a SHA-256 whole), - if missing."""
    return "-" if value is None else user_text(value, 64)
