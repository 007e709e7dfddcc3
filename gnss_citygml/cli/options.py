"""Options and helpers shared by the subcommands (defined once, as in rasterio's ``rio``)."""

from __future__ import annotations

import sys
from pathlib import Path

import click

__all__ = ["OVERWRITE", "QUIET", "SEED", "THRESHOLD", "output_file", "progress"]

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


def output_file(help_text):
    """The required ``--output`` / ``-o`` file option of a command that writes one file."""
    return click.option(
        "--output",
        "-o",
        type=click.Path(dir_okay=False, path_type=Path),
        required=True,
        help=help_text,
    )


def progress(total, label, quiet):
    """A progress bar on stderr (only on a terminal; never with ``--quiet``)."""
    from tqdm import tqdm

    return tqdm(total=total, desc=label, disable=quiet or None, file=sys.stderr, leave=False)
