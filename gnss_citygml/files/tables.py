"""Reading and writing the toolkit's tables (CSV or Parquet) and layers (GeoPackage,
FlatGeobuf, GeoParquet).

Outputs are written through :func:`gnss_citygml.files.paths.atomic_path`: to a temporary file in the
target folder, renamed into place only when complete, so a failed run never leaves a
half-written file behind. A layer written into an existing GeoPackage replaces that layer only:
every other layer (and the styles table) of the file is kept."""

from __future__ import annotations

import json
from collections.abc import Iterable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

from ..errors import InputError, first_line, user_text
from .geopackage import check_no_triggers
from .ids import source_named
from .names import check_utf8_name, native_name
from .paths import (
    StrPath,
    atomic_path,
    check_not_input,
    check_output,
    input_file,
    same_file,
)
from .provenance import KEY, summary
from .styles import save_default_style, style_saved
from .userjson import NotJSON, parse_json

if TYPE_CHECKING:
    import geopandas as gpd

__all__ = [
    "LAYER_FORMATS",
    "TEXT_COLUMNS",
    "check_layer_output",
    "check_parquet_metadata",
    "check_text",
    "check_table_output",
    "read_table",
    "write_layer",
    "write_table",
]

#: Layer formats by file suffix: the GDAL driver, or "GeoParquet" (written by geopandas).
LAYER_FORMATS = {".gpkg": "GPKG", ".fgb": "FlatGeobuf", ".parquet": "GeoParquet"}


#: The columns of the toolkit's tables that hold ids or names: ``id`` (buildings, heights,
#: truth), ``building`` (intersections), ``receiver`` (observations).
TEXT_COLUMNS = ("id", "building", "receiver")


def read_table(path: StrPath, *, text: Iterable[str] = ()) -> pd.DataFrame:
    """Read a CSV or Parquet table, with a one-line error for a missing or unreadable file.

    The ids and names of a CSV file (:data:`TEXT_COLUMNS` and the columns ``text`` names, e.g.
    the footprints' id field) are read as the text they are: a number parser would make
    ``008`` the building ``8`` and ``1e3`` ``1000.0``, and pandas' missing values would make
    the building ``NA`` no building. Only an empty field is a missing id there."""
    path = input_file(path)
    suffix = _suffix(path)
    try:
        if suffix == ".csv":
            return _read_csv(path, {*TEXT_COLUMNS, *text})
        return _read_parquet(path)
    except (ValueError, OSError, pd.errors.ParserError) as exc:
        raise InputError(
            f"cannot read the table: {first_line(exc)}",
            where=str(path),
            fix="give a well-formed CSV (with a header row) or Parquet file",
        ) from None


def _read_csv(path: Path, text: set[str]) -> pd.DataFrame:
    """A CSV table as pandas reads it, the columns named in ``text`` read again as text
    (missing only where empty: pandas has no public list of its missing values to keep for
    the other columns of one read)."""
    table = pd.read_csv(path)
    ids = [name for name in table.columns if name in text]
    if ids:
        as_text = pd.read_csv(path, usecols=ids, dtype=str, keep_default_na=False, na_values=[""])
        table[ids] = as_text[ids]
    return table


def check_text(frame: pd.DataFrame, where: str) -> pd.DataFrame:
    """``frame`` if its text columns hold UTF-8, else an :class:`InputError` naming the column
    and the first row that does not. Parquet does not check the text it stores (a file damaged
    or written by a careless tool reads without an error) and every string operation on it
    later fails with Arrow's error, far from the file."""
    import pyarrow as pa

    for name in frame.columns:
        column = frame[name]
        arrow = isinstance(column.dtype, pd.ArrowDtype) or (
            isinstance(column.dtype, pd.StringDtype) and column.dtype.storage == "pyarrow"
        )
        if not arrow:  # (Python's str objects are text already)
            continue
        try:
            pa.array(column.array).validate(full=True)
        except (pa.ArrowInvalid, pa.ArrowTypeError):
            raise InputError(
                f"the column '{user_text(name)}' is not UTF-8 text",
                where=f"{where}, row {_first_undecodable(column)}",
                fix="write its text as UTF-8 (e.g. read and write the table again with pandas)",
            ) from None
    return frame


def _first_undecodable(column: pd.Series) -> int:
    """The row of the first value of ``column`` that cannot be decoded (0 if none is found)."""
    for row in range(len(column)):
        try:
            str(column.iloc[row])
        except (UnicodeError, ValueError):
            return row
    return 0


#: The metadata of a Parquet file that pyarrow (``pandas``) and GeoPandas (``geo``) read as JSON.
JSON_METADATA = (b"pandas", b"geo")


def check_parquet_metadata(metadata: dict[bytes, bytes] | None, where: str) -> dict[bytes, Any]:
    """The JSON metadata of a Parquet file (:data:`JSON_METADATA`, those it has) parsed by
    :func:`~.userjson.parse_json`, before pyarrow or GeoPandas parse it with no bound on its
    depth; an :class:`InputError` naming the one that is not JSON."""
    metadata, parsed = metadata or {}, {}
    for key in JSON_METADATA:
        if key not in metadata:
            continue
        try:
            parsed[key] = parse_json(metadata[key], allow_nan=True)
        except NotJSON as exc:
            raise InputError(
                f"its {key.decode()} metadata cannot be read: {exc}",
                where=where,
                fix="write the file again (pandas' or GeoPandas' to_parquet)",
            ) from None
    return parsed


def _read_parquet(path: Path) -> pd.DataFrame:
    """A Parquet table (:func:`check_text`), its JSON metadata checked first
    (:func:`check_parquet_metadata`); pyarrow's errors on damaged pandas metadata as an
    InputError."""
    import pyarrow.parquet as pq

    check_parquet_metadata(pq.read_schema(native_name(path)).metadata, str(path))
    try:
        return check_text(pd.read_parquet(native_name(path)), str(path))
    except (KeyError, TypeError, IndexError, AttributeError) as exc:
        # pyarrow rebuilding the pandas columns from a Parquet file's damaged pandas metadata
        raise InputError(
            f"cannot read the table: damaged pandas metadata ({type(exc).__name__} "
            f"{first_line(exc)})",
            where=str(path),
            fix="give a well-formed CSV (with a header row) or Parquet file",
        ) from None


def _suffix(path: Path) -> str:
    suffix = path.suffix.lower()
    if suffix not in (".csv", ".parquet"):  # the table formats
        raise InputError(
            f"unknown table format {suffix or '(none)'!r}",
            where=str(path),
            fix="name the file .csv or .parquet",
        )
    return suffix


def check_table_output(path: StrPath, *, overwrite: bool, inputs: Iterable[object] = ()) -> Path:
    """Check, before the work starts, that a table can be written to ``path`` (CSV, Parquet)
    and that it is none of the command's ``inputs``
    (:func:`~gnss_citygml.files.paths.check_not_input`)."""
    if _suffix(Path(path)) == ".parquet":
        check_utf8_name(path, "output")
    path = check_output(path, overwrite=overwrite)
    check_not_input(path, inputs, folders=False)  # (a table is made of files)
    return path


def write_table(table: pd.DataFrame, path: StrPath, *, overwrite: bool = True) -> None:
    """Write a table as CSV or Parquet (by the file's suffix), atomically."""
    suffix = _suffix(Path(path))
    with atomic_path(path, overwrite=overwrite) as tmp:
        if suffix == ".csv":
            table.to_csv(tmp, index=False)
        else:
            table.to_parquet(tmp, index=False)


def check_layer_output(
    path: StrPath,
    layer: str,
    *,
    overwrite: bool,
    inputs: Iterable[object] = (),
    read_layer: str | None = None,
) -> Path:
    """Check, before the work starts, that ``layer`` can be written to ``path``.

    The suffix names the format (:data:`LAYER_FORMATS`); a Shapefile is refused, since it cuts
    field names to 10 characters and is several files that cannot be replaced at once. An
    existing GeoPackage takes a new layer without ``overwrite``; an existing layer of it, or an
    existing file of another format, needs ``overwrite``.

    The output must be none of the command's ``inputs``
    (:func:`~gnss_citygml.files.paths.check_not_input`), but for one case: a GeoPackage that is an
    input takes a new layer beside the one read from it (``read_layer``; None: its only one),
    as the footprints' own GeoPackage takes the layer ``heights``. The layer read itself is
    never replaced.
    """
    path = Path(path)
    if path.suffix.lower() == ".shp":
        raise InputError(
            "Shapefiles are not written (field names are cut to 10 characters, and the file's "
            "parts cannot be replaced at once)",
            where=str(path),
            fix="write .gpkg, .fgb or .parquet (ogr2ogr converts them to a Shapefile)",
        )
    check_utf8_name(path, "output")
    gpkg = path.suffix.lower() == ".gpkg"
    check_output(path, overwrite=overwrite, suffixes=tuple(LAYER_FORMATS), exists_ok=gpkg)
    if gpkg and path.exists():
        check_no_triggers(path)
    inputs = list(inputs)
    if gpkg and any(same_file(given, path) for given in inputs):
        if _replaces_layer_read(path, layer, read_layer):
            raise InputError(
                f"the output's layer {layer!r} would replace the layer read from the same "
                "GeoPackage",
                where=str(path),
                fix="write to another file (or name the layer read with --layer, if it is another)",
            )
        inputs = [given for given in inputs if not same_file(given, path)]
    check_not_input(path, inputs)
    if gpkg and path.exists() and not overwrite and layer in _layers(path):
        raise InputError(
            f"output exists and has a layer {layer!r}",
            where=str(path),
            fix="choose another name, or --overwrite to replace that layer (the file's other "
            "layers are kept)",
        )
    return path


def _replaces_layer_read(path: Path, layer: str, read_layer: str | None) -> bool:
    """Whether writing ``layer`` into the GeoPackage ``path`` replaces the layer read from it
    (``read_layer``, or when None the file's only one: any layer named ``layer``). GeoPackage
    table names are compared as SQLite does, whatever their case."""
    if read_layer is not None:
        return read_layer.lower() == layer.lower()
    return layer.lower() in (name.lower() for name in _layers(path))


def _layers(path: Path) -> list[str]:
    import pyogrio

    try:
        return [str(name) for name in pyogrio.list_layers(path)[:, 0]]
    except Exception as exc:  # GDAL raises its own errors for a file that is not a GeoPackage
        raise InputError(
            f"the output exists and is not a readable GeoPackage ({first_line(exc)})",
            where=str(path),
            fix="choose another name, or remove the file",
        ) from None


def write_layer(
    frame: gpd.GeoDataFrame,
    path: StrPath,
    layer: str,
    *,
    overwrite: bool = True,
    style: str | None = None,
    provenance: dict | None = None,
) -> None:
    """Write a GeoDataFrame as ``layer`` of ``path``, atomically, in the format its suffix names.

    GeoPackage (``.gpkg``): an existing file keeps its other layers and styles and ``layer`` is
    replaced (with ``overwrite``) or added. FlatGeobuf (``.fgb``) and GeoParquet
    (``.parquet``) hold one layer: the file is replaced. List-valued attributes (OS
    MasterMap's ``descriptiveGroup``, read by GDAL as lists) are written as text joined by
    ``|``, which every GIS reads. The id is written under the name of its source's field
    (e.g. ``toid``; :func:`gnss_citygml.files.ids.source_named`).

    ``style`` (QGIS QML) is saved in a GeoPackage as the layer's default style
    (:func:`gnss_citygml.files.styles.save_default_style`); the other formats have no place for it.
    So is ``provenance`` (:func:`gnss_citygml.files.provenance.provenance`): the layer's
    metadata item ``provenance`` in ``gpkg_metadata``, and its one-line summary as the layer's
    description.
    A new GeoPackage is version 1.2, which every GDAL since 2.2 (QGIS 3.22's too) reads
    without a warning."""
    path = check_layer_output(path, layer, overwrite=overwrite)
    out = source_named(frame).copy()
    for column in out.columns.drop([out.geometry.name]):
        if out[column].map(lambda v: isinstance(v, list | tuple | np.ndarray)).any():
            out[column] = out[column].map(
                lambda v: "|".join(map(str, v)) if isinstance(v, list | tuple | np.ndarray) else v
            )
    driver = LAYER_FORMATS[path.suffix.lower()]
    update = driver == "GPKG" and path.exists()
    with atomic_path(path, overwrite=overwrite or update, update=update) as tmp:
        if driver == "GeoParquet":
            out.to_parquet(tmp, index=False)
        elif driver == "GPKG":
            if update:  # the copy GDAL writes to (the file may have changed since the check)
                check_no_triggers(tmp)
            version = None if update else {"VERSION": "1.2"}
            made: dict[str, Any] = {}
            if provenance is not None:
                made = {
                    "layer_options": {"DESCRIPTION": summary(provenance)},
                    "layer_metadata": {KEY: json.dumps(provenance)},
                }
            out.to_file(tmp, layer=layer, driver=driver, dataset_options=version, **made)
            if style is not None:
                save_default_style(tmp, layer, style)
            _check_kept(tmp, layer, len(out), made, style, path)
        else:
            out.to_file(tmp, layer=layer, driver=driver)


def _check_kept(
    tmp: Path, layer: str, rows: int, made: dict[str, Any], style: str | None, path: Path
) -> None:
    """Read back what :func:`write_layer` put in the GeoPackage ``tmp`` (to be ``path``): the
    layer's rows, its provenance and its style. A trigger of the user's that no reading of its
    SQL can judge (a check of the standard's shape whose condition always holds) may abort
    or drop a row that GDAL writes, and GDAL only logs it: the file would go out without its
    provenance, exit 0."""
    import pyogrio

    info = pyogrio.read_info(tmp, layer=layer)
    lost = [] if info["features"] == rows else [f"the rows ({info['features']} of {rows})"]
    wanted = made.get("layer_metadata", {}).get(KEY)
    if wanted is not None and (info.get("layer_metadata") or {}).get(KEY) != wanted:
        lost.append("the provenance (gpkg_metadata, gpkg_metadata_reference)")
    if style is not None and not style_saved(tmp, layer, style):
        lost.append("the style (layer_styles)")
    if lost:
        raise InputError(
            f"the GeoPackage did not keep {' nor '.join(lost)} of the layer "
            f"{user_text(layer)!r} written: a trigger of its own?",
            where=str(path),
            fix="drop the GeoPackage's triggers on those tables (DROP TRIGGER name, e.g. in "
            "sqlite3 or QGIS's DB Manager) in a copy, or write to another file",
        )
