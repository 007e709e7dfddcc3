"""Options and helpers shared by the subcommands (each declared once, as in rasterio's ``rio``).

An option that two commands take is declared here, so that it has one name, one type, one
default and one help text everywhere. The defaults of the model's options are those of
:mod:`gnss_citygml.settings`, the objects the commands build from them. Options with a unit
are plain numbers here: their ranges are checked once, when those objects are made, and a bad
value is the toolkit's one-line error naming the option.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

import click

from ..model import METHODS
from ..settings import (
    DEFAULT_TILE_SIZE,
    HEIGHT_RULES,
    RECEIVER_HEIGHTS,
    SIGNAL_MODELS,
    Estimator,
    PositionError,
    Rays,
    ReceiverHeights,
)

__all__ = [
    "ANTENNA_HEIGHT",
    "DEM_CRS",
    "GRID_DIR",
    "ID_FIELD",
    "LAYER",
    "LEVEL_PHONES",
    "HEIGHT_RULE",
    "MAX_ELEVATION",
    "METHOD",
    "MIN_ELEVATION",
    "MODEL_OUTPUT",
    "OVERWRITE",
    "POSITION_DISTANCE",
    "POSITION_WINDOW",
    "QUIET",
    "RECEIVER_HEIGHT",
    "REPORT",
    "SCHEMA_DIR",
    "SEED",
    "SIGNAL_MODEL",
    "STDOUT",
    "THRESHOLD",
    "TILE_SIZE",
    "TRUTH",
    "TYPED_ATTRIBUTES",
    "dem_file",
    "output_dir",
    "output_file",
    "progress",
]

if TYPE_CHECKING:
    from click.decorators import FC
    from tqdm import tqdm

SEED = click.option(
    "--seed",
    type=int,
    default=0,
    show_default=True,
    help="Seed of the simulation's random choices.",
)
OVERWRITE = click.option("--overwrite", is_flag=True, help="Replace an existing output.")
QUIET = click.option("--quiet", "-q", is_flag=True, help="No progress output.")
RECEIVER_HEIGHT = click.option(
    "--receiver-height",
    type=click.Choice(list(RECEIVER_HEIGHTS)),
    default=ReceiverHeights.source,
    show_default=True,
    help="Antenna height from the DEM (+ --antenna-height) or from the observations' h.",
)
ANTENNA_HEIGHT = click.option(
    "--antenna-height",
    type=float,
    default=ReceiverHeights.antenna_height,
    show_default=True,
    help="Metres.",
)
POSITION_DISTANCE = click.option(
    "--position-distance",
    type=float,
    default=PositionError.distance,
    show_default=True,
    help="Metres a moving receiver (a walker's traced path, a phone's fixes) goes with one "
    "position error: the next begins once its reported position is this far from where the "
    "last began (the next stretch of street has other reflections). A receiver standing at one "
    "point, or a phone lying still, keeps one. Longer than the walk: one per recording.",
)
POSITION_WINDOW = click.option(
    "--position-window",
    type=float,
    help="Instead of --position-distance: seconds one position error of a moving receiver "
    "lasts. A receiver standing at one point (a point placed by hand) shares one error over "
    "its stay either way.",
)
TILE_SIZE = click.option(
    "--tile-size",
    type=float,
    help=f"Side of a tile (m), aligned to the OS grid (a run with --scheduler). Default: "
    f"{DEFAULT_TILE_SIZE:g}, or a partition's own.",
)
GRID_DIR = click.option(
    "--grid-dir",
    type=click.Path(file_okay=False, path_type=Path),
    envvar="GNSS_CITYGML_GRID_DIR",
    help="Folder holding the OSTN15/OSGM15 grids, searched first (default: PROJ's folders, "
    "then the copy bundled with gnss-citygml).",
)
SCHEMA_DIR = click.option(
    "--schema-dir",
    type=click.Path(file_okay=False, path_type=Path),
    envvar="GNSS_CITYGML_SCHEMA_DIR",
    help="Official schemas (CityJSON JSON schemas; optionally a schemas.opengis.net tree).",
)
LAYER = click.option("--layer", help="Footprint layer (default: the only polygon layer).")
ID_FIELD = click.option(
    "--id-field",
    help="Footprint field with the building ids (default: toid, id or fid); the outputs' id "
    "column keeps its name.",
)
DEM_CRS = click.option("--dem-crs", help="CRS of a DEM that has none, e.g. EPSG:27700.")
MIN_ELEVATION = click.option(
    "--min-elevation",
    type=float,
    default=Rays.min_elevation,
    show_default=True,
    help="Signals below this elevation (deg) are left out.",
)
MAX_ELEVATION = click.option(
    "--max-elevation",
    type=float,
    default=Rays.max_elevation,
    show_default=True,
    help="Signals above this elevation (deg) are left out.",
)
METHOD = click.option(
    "--method",
    type=click.Choice(list(METHODS)),
    default=Estimator.method,
    show_default=True,
    help="Height estimator: 4PL-B, the paper's one-shot 4PL, or the hinge or Bayes baseline.",
)
HEIGHT_RULE = click.option(
    "--height-rule",
    type=click.Choice(list(HEIGHT_RULES)),
    default=Estimator.height_rule,
    show_default=True,
    help="How the height is read off a building's 4PL: its inflection point c, or the paper's "
    "c + 1.5/b (both are in every output: c and height_paper).",
)
SIGNAL_MODEL = click.option(
    "--signal-model",
    type=click.Choice(list(SIGNAL_MODELS)),
    default=Estimator.signal_model,
    show_default=True,
    help="How 4PL-B tells open signals from closed ones: the paper's C/N0 threshold trained "
    "on the map's labels, or a mixture of open and closed signals' C/N0 by elevation learnt "
    "by EM (method 4PL-B only).",
)
LEVEL_PHONES = click.option(
    "--level-phones/--no-level-phones",
    default=Estimator.level_phones,
    show_default=True,
    help="Put every phone's C/N0 on one level before the signals are classified, each "
    "phone's offset learnt from its signals that cross no footprint (phones differ by a few "
    "dB-Hz; method 4PL-B). --no-level-phones: the C/N0 as recorded, as in the paper.",
)
THRESHOLD = click.option(
    "--init-threshold",
    type=float,
    default=Estimator.init_threshold,
    show_default=True,
    help="C/N0 (dB-Hz) where the initial signal classifier gives 50 %.",
)

REPORT = click.option(
    "--report",
    type=click.Path(file_okay=False, path_type=Path),
    help="Also write the report of the fit (report.html, figures/*.png) into this folder; "
    "needs matplotlib (pip install 'gnss-citygml[plot]').",
)
TRUTH = click.option(
    "--truth",
    type=click.Path(dir_okay=False, path_type=Path),
    help="For the report: a truth table (id, height, ground in m ODN, optionally the roof "
    "span roof_low, roof_high; a simulator's truth.csv), to show the true heights and the "
    "errors.",
)

TYPED_ATTRIBUTES = click.option(
    "--typed-attributes",
    is_flag=True,
    help="CityJSON: write the toolkit's attributes as +height, +height_lower, ... typed by its "
    "CityJSON Extension (declared in the file; schemas/gnss_citygml.ext.json) instead of plain "
    "attributes.",
)


def together(*options: Callable[[FC], FC]) -> Callable[[FC], FC]:
    """One decorator for options that several commands share, listed top to bottom as they
    appear in ``--help``."""

    def apply(func: FC) -> FC:
        for option in reversed(options):
            func = option(func)
        return func

    return apply


def dem_file(help_text: str, required: bool = False) -> Callable[[FC], FC]:
    """The ``--dem`` option: a raster GDAL reads, for what ``help_text`` says."""
    return click.option("--dem", type=click.Path(path_type=str), required=required, help=help_text)


def output_dir(help_text: str) -> Callable[[FC], FC]:
    """The required ``--output-dir`` / ``-o`` folder option of a command that writes several
    files; the command itself says when the path is a file, in its own words."""
    return click.option(
        "--output-dir", "-o", type=click.Path(path_type=Path), required=True, help=help_text
    )


def output_file(help_text: str) -> Callable[[FC], FC]:
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


def progress(total: int, label: str, quiet: bool) -> tqdm:
    """A progress bar on stderr (only on a terminal; never with ``--quiet``)."""
    from tqdm import tqdm

    return tqdm(total=total, desc=label, disable=quiet or None, file=sys.stderr, leave=False)
