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
from typing import TYPE_CHECKING, Any

import click

from ..options import OPTIONS, Option, settings_arguments, settings_objects
from ..settings import DEFAULT_TILE_SIZE

__all__ = [
    "ANTENNA_HEIGHT",
    "DEM_CRS",
    "DEM_HELP",
    "FIT_MAX_ITER",
    "GRID_DIR",
    "ID_FIELD",
    "LAYER",
    "LEVEL_PHONES",
    "HEIGHT_RULE",
    "MAX_ELEVATION",
    "MAX_ITER",
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
    "chosen_settings",
    "dem_file",
    "footprints_file",
    "option",
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


def option(name: str) -> Callable[[FC], FC]:
    """The click option of :data:`gnss_citygml.options.OPTIONS`'s ``name`` (``MIN_ELEVATION``):
    its flag, type, default and help as declared there, once for the command line and QGIS."""
    spec: Option = OPTIONS[name]
    if spec.kind == "switch":
        flags = f"{spec.flag}/--no-{spec.flag.removeprefix('--')}"
        return click.option(flags, default=spec.default, show_default=True, help=spec.help)
    kinds = {"choice": click.Choice(list(spec.choices)), "field": str, "count": int}
    kind = kinds.get(spec.kind, float)
    return click.option(
        spec.flag, type=kind, default=spec.default, show_default=not spec.optional, help=spec.help
    )


def chosen_settings(chosen: dict[str, Any]) -> dict[str, Any]:
    """The settings objects (``{"rays": Rays(...), "estimator": Estimator(...), ...}``) made
    from a command's options of :data:`~gnss_citygml.options.OPTIONS`, taken out of
    ``chosen`` (its keyword arguments); those it has no option of keep their defaults."""
    names = [name for name, spec in OPTIONS.items() if spec.dest in chosen]
    values = {name: chosen.pop(OPTIONS[name].dest) for name in names}
    return settings_objects(settings_arguments(values, names))


MIN_ELEVATION = option("MIN_ELEVATION")
MAX_ELEVATION = option("MAX_ELEVATION")
RECEIVER_HEIGHT = option("RECEIVER_HEIGHT")
ANTENNA_HEIGHT = option("ANTENNA_HEIGHT")
THRESHOLD = option("INIT_THRESHOLD")
METHOD = option("METHOD")
HEIGHT_RULE = option("HEIGHT_RULE")
SIGNAL_MODEL = option("SIGNAL_MODEL")
LEVEL_PHONES = option("LEVEL_PHONES")
MAX_ITER = option("MAX_ITER")
FIT_MAX_ITER = option("FIT_MAX_ITER")
POSITION_DISTANCE = option("POSITION_DISTANCE")
POSITION_WINDOW = option("POSITION_WINDOW")

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
    help="Official schemas (CityJSON JSON schemas; optionally a schemas.opengis.net tree, "
    "3D Tiles 1.1 schemas in 3dtiles-1.1/, else those bundled).",
)
LAYER = click.option("--layer", help="Footprint layer (default: the only polygon layer).")
ID_FIELD = click.option(
    "--id-field",
    help="Footprint field with the building ids (default: toid, id or fid); the outputs' id "
    "column keeps its name.",
)
DEM_CRS = click.option("--dem-crs", help="CRS of a DEM that has none, e.g. EPSG:27700.")

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


#: What ``--dem`` takes, for the commands that need the ground.
DEM_HELP = (
    "DEM in EPSG:27700: a raster (GeoTIFF, ASCII grid, zip://...!/tile.asc, VRT) or a folder "
    "of its tiles of one grid (as OS Terrain 5 ships), read only where needed."
)


def dem_file(help_text: str, required: bool = False) -> Callable[[FC], FC]:
    """The ``--dem`` option: a raster GDAL reads, for what ``help_text`` says."""
    return click.option("--dem", type=click.Path(path_type=str), required=required, help=help_text)


def footprints_file(help_text: str, required: bool = False) -> Callable[[FC], FC]:
    """The ``--footprints`` option: a footprint source (any layer GDAL reads, MasterMap GML,
    GeoParquet), for what ``help_text`` says."""
    return click.option(
        "--footprints", type=click.Path(path_type=Path), required=required, help=help_text
    )


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
    help="OUT.city.json (CityJSON 2.0), OUT.city.jsonl (CityJSONSeq), OUT.gml (CityGML 2.0) "
    "or FOLDER/tileset.json (3D Tiles 1.1 for web viewers: the folder, written whole, holds the "
    "tiles and viewer.html); "
    "'-' writes CityJSONSeq to standard output (e.g. | cjio stdin ...) once it is complete "
    "and validated: it is written to a temporary file (in $TMPDIR) first, so a failed run "
    "writes nothing there; messages go to standard error.",
)


def progress(total: int, label: str, quiet: bool) -> tqdm:
    """A progress bar on stderr (only on a terminal; never with ``--quiet``)."""
    from tqdm import tqdm

    return tqdm(total=total, desc=label, disable=quiet or None, file=sys.stderr, leave=False)
