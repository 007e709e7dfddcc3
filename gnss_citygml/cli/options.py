"""Options and helpers shared by the subcommands (defined once, as in rasterio's ``rio``)."""

from __future__ import annotations

import sys
from pathlib import Path

import click

__all__ = [
    "MODEL_OUTPUT",
    "OVERWRITE",
    "QUIET",
    "SEED",
    "STDOUT",
    "THRESHOLD",
    "TYPED_ATTRIBUTES",
    "output_file",
    "progress",
]

SEED = click.option(
    "--seed",
    type=int,
    default=0,
    show_default=True,
    help="Seed of the simulation's random choices.",
)
OVERWRITE = click.option("--overwrite", is_flag=True, help="Replace an existing output.")
QUIET = click.option("--quiet", "-q", is_flag=True, help="No progress output.")
THRESHOLD = click.option(
    "--init-threshold",
    type=float,
    default=30.0,
    show_default=True,
    help="C/N0 (dB-Hz) where the initial signal classifier gives 50 %.",
)

TYPED_ATTRIBUTES = click.option(
    "--typed-attributes",
    is_flag=True,
    help="CityJSON: write the toolkit's attributes as +height, +height_lower, ... typed by its "
    "CityJSON Extension (declared in the file; schemas/gnss_citygml.ext.json) instead of plain "
    "attributes.",
)


def output_file(help_text):
    """The required ``--output`` / ``-o`` file option of a command that writes one file."""
    return click.option(
        "--output",
        "-o",
        type=click.Path(dir_okay=False, path_type=Path),
        required=True,
        help=help_text,
    )


#: The output name that means standard output.
STDOUT = Path("-")

#: The output of the commands that write a city model (``convert``, ``export``).
MODEL_OUTPUT = click.option(
    "--output",
    "-o",
    type=click.Path(dir_okay=False, allow_dash=True, path_type=Path),
    required=True,
    help="OUT.city.json (CityJSON 2.0), OUT.city.jsonl (CityJSONSeq) or OUT.gml (CityGML 2.0); "
    "'-' writes CityJSONSeq to standard output (e.g. | cjio stdin ...) once it is complete "
    "and validated: it is written to a temporary file (in $TMPDIR) first, so a failed run "
    "writes nothing there; messages go to standard error.",
)


def progress(total, label, quiet):
    """A progress bar on stderr (only on a terminal; never with ``--quiet``)."""
    from tqdm import tqdm

    return tqdm(total=total, desc=label, disable=quiet or None, file=sys.stderr, leave=False)
