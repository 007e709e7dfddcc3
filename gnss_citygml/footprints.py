"""Building footprints: the *buildings* table of DESIGN.md, before its ``ground``.

Footprints come from any polygon layer pyogrio reads (GeoPackage, Shapefile, GeoJSON, ...),
from OS MasterMap Topography Layer GML, or from GeoParquet (a file or a hive folder, such as
a run's heights written per tile); they leave :func:`read_footprints` as a GeoDataFrame in
EPSG:27700 with a text ``id``, valid Polygon/MultiPolygon geometries and the input attributes.
The ground under them comes from a DEM, in :mod:`gnss_citygml.terrain`.

Rules
-----
- **id**: ``id_field`` if given; else the first column named ``toid``, ``id`` or ``fid`` (in
  that order, any letter case); else the source's feature id (the GeoPackage ``fid``, the row
  number of a Shapefile). MasterMap features use their TOID (the ``fid`` attribute, or
  ``gml_id`` in newer schemas). The id field *moves* to the text column ``id``; every other
  attribute is kept untouched. Ids must be present and unique. The field's name is kept in the
  table's ``attrs`` (:mod:`gnss_citygml.files.ids`) so that the outputs carry the id under it: a
  field's own name, ``toid`` for MasterMap's TOIDs, ``id`` for feature ids and for a field
  named ``fid`` (GDAL's name for the feature id itself: a GeoPackage cannot hold it as text).
- **geometry**: every feature must be a Polygon or MultiPolygon: a missing geometry, a point,
  a line or a collection is an error naming the features (pick a polygon layer or filter the
  source), never a silently dropped building (:func:`check_polygonal`, which the terrain
  checks its buildings with too). Z coordinates are dropped. Invalid polygons are
  repaired with ``shapely.make_valid`` keeping only their polygonal parts, with a warning that
  lists their ids; a polygon with no area left is dropped, with a warning.
- **CRS**: footprints in another CRS are transformed to EPSG:27700 by
  :func:`gnss_citygml.geodesy.to_bng`, the toolkit's one path (OSTN15 + OSGM15 for ETRS89 and
  WGS 84, a conversion for OSGB36); a CRS on any other datum, or missing grids, is an error,
  never PROJ's 2 m Helmert transformation. Footprints without a CRS, or whose coordinates
  contradict their CRS (degrees in a projected CRS, metres in a geographic one), are an error.
"""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
import warnings
import xml.parsers.expat
import zlib
from collections.abc import Iterator
from pathlib import Path

import geopandas as gpd
import numpy as np
import pandas as pd
import pyogrio
import shapely
from pandas.api.types import is_list_like

from .errors import InputError, MissingColumnError, first_line, listing, user_text
from .files.ids import id_text, missing_ids, with_id_field
from .files.paths import StrPath, gunzipped, input_file
from .files.tables import check_text
from .geodesy import CrsError, OutsideExtentError, is_bng, to_bng

__all__ = ["check_polygonal", "read_footprints"]

_BNG = "EPSG:27700"
_ID_FIELDS = ("toid", "id", "fid")
_MASTERMAP_NAMESPACES = (
    b"ordnancesurvey.co.uk/xml/namespaces/osgb",
    b"namespaces.os.uk/mastermap/topography",
)
#: What makes GDAL read an XML file (starting with "<", after a UTF-8 byte order mark) with
#: its GML driver, which writes a .gfs sidecar unless told not to (ogrgmldatasource.cpp).
_GML_MARKERS = (b"opengis.net/gml", b"<csw:GetRecordsResponse")


def read_footprints(
    path: StrPath,
    *,
    layer: str | None = None,
    id_field: str | None = None,
    grid_dir: StrPath | None = None,
) -> gpd.GeoDataFrame:
    """Read building footprints as the *buildings* table (without ``ground``).

    Parameters
    ----------
    path
        A GeoPackage or any polygon source pyogrio reads, or an OS MasterMap Topography Layer
        GML file (``.gml`` or ``.gml.gz``; its TopographicArea features whose descriptiveGroup
        includes ``Building`` are read). GML is read with ``WRITE_GFS=NO``: no ``.gfs`` sidecar
        is written next to it. It is checked to be well-formed XML first: GDAL reads no
        feature at all from a file cut short, without an error. Or GeoParquet: a file, or a
        folder in the hive layout such as the heights a run in tiles wrote per tile
        (``FOLDER/heights``, :mod:`gnss_citygml.tiling.output`), read by GeoPandas.
    layer
        The layer to read. By default: the only polygon layer of the source, or
        ``TopographicArea`` for MasterMap.
    id_field
        The column holding the building ids (default: see the module's rules).
    grid_dir
        Folder of the OSTN15/OSGM15 grids, for footprints in another CRS than EPSG:27700
        (see :mod:`gnss_citygml.geodesy.grids`; default ``$GNSS_CITYGML_GRID_DIR``, then PROJ's
        folders, then the copy bundled with the package).

    Returns
    -------
    geopandas.GeoDataFrame
        ``id`` (str), the input attributes, and ``geometry`` (Polygon/MultiPolygon, valid)
        in EPSG:27700; ``attrs["id_field"]`` is the name the outputs give the id (see the
        module's rules and :mod:`gnss_citygml.files.ids`).

    Raises
    ------
    InputError
        An unreadable source (a damaged gzip file, GML that is not well-formed XML, naming
        the line), an empty layer, missing or duplicate ids, non-polygon features,
        no CRS or coordinates that contradict it, a CRS with no exact path to EPSG:27700
        (:class:`~gnss_citygml.geodesy.CrsError`) or footprints outside the grids.
    GridError
        Footprints in another CRS and the grids are missing.
    """
    where = os.fspath(path)
    local = not (where.startswith("/vsi") or "://" in where)
    if local and not Path(where).is_dir():  # a folder may hold a Shapefile or a FileGDB
        input_file(where, "footprint file")
    kind = _sniff_gml(Path(where)) if local else None
    if kind:  # GDAL reads no feature at all from a GML file that is not well-formed
        _check_xml(Path(where))
    options = {"WRITE_GFS": "NO"} if kind else {}
    if local and _is_geoparquet(Path(where)):
        if layer is not None:
            raise InputError(
                f"GeoParquet has no layers to choose (--layer {layer})",
                where=where,
                fix="leave out --layer",
            )
        frame = _read_geoparquet(Path(where))
    else:
        with _nothing_written_beside(where):
            if layer is None:
                layer = "TopographicArea" if kind == "mastermap" else _polygon_layer(where, kind)
            where = f"{where}, layer {layer}" if layer is not None else where
            frame = _read_layer(path, layer, where, options)
    if kind == "mastermap" and "descriptiveGroup" in frame.columns:
        frame = frame[_has_building_group(frame["descriptiveGroup"])]
        if id_field is None:
            id_field = next((c for c in ("fid", "gml_id") if c in frame.columns), None)
    if frame.empty:
        what = "no building features" if kind == "mastermap" else "the layer has no features"
        raise InputError(what, where=where, fix="give a layer with building footprints")
    frame, field = _with_ids(frame, id_field, where)
    check_polygonal(frame.geometry.to_numpy(), frame["id"].to_numpy(), where)
    frame = _repaired(_to_bng(frame, where, grid_dir), where)
    return with_id_field(frame, _output_name(field, kind == "mastermap"))


def _sniff_gml(path: Path) -> str | None:
    """``"mastermap"``, ``"gml"`` or None from the first 64 kB of a (possibly gzipped) file.

    A file is GML when GDAL would read it with its GML driver, also when the file is damaged
    (a mistyped namespace): the reader must then pass ``WRITE_GFS=NO``."""
    if not path.is_file():
        return None
    with open(path, "rb") as raw:
        head = raw.read(65536)
    if head[:2] == b"\x1f\x8b":
        with _gunzipped(path) as unzipped:
            head = unzipped.read(65536)
    head = head.removeprefix(b"\xef\xbb\xbf")
    if not head.startswith(b"<") or not any(marker in head for marker in _GML_MARKERS):
        return None
    return "mastermap" if any(ns in head for ns in _MASTERMAP_NAMESPACES) else "gml"


@contextlib.contextmanager
def _gunzipped(path: Path) -> Iterator:
    """A gzipped file opened for reading as a capped stream (:func:`~gnss_citygml.files.paths.
    gunzipped`: a decompression bomb is an InputError); a damaged one (while read too) is an
    InputError."""
    try:
        with gunzipped(path, "footprint file") as unzipped:
            yield unzipped
    except (OSError, EOFError, zlib.error) as exc:  # BadGzipFile is an OSError
        raise InputError(
            f"cannot read the footprints: a damaged gzip file ({exc})",
            where=str(path),
            fix="download or compress it again (gzip -t checks it)",
        ) from None


def _check_xml(path: Path) -> None:
    """An :class:`InputError` naming the line where a (gzipped) GML file stops being
    well-formed XML (a cut download, a bad hand edit): GDAL would read no feature from it and
    say nothing. Expat expands no external entity and caps entity expansion."""
    parser = xml.parsers.expat.ParserCreate()
    with open(path, "rb") as raw:
        gzipped = raw.read(2) == b"\x1f\x8b"
    try:
        with _gunzipped(path) if gzipped else open(path, "rb") as stream:
            parser.ParseFile(stream)
    except xml.parsers.expat.ExpatError as exc:
        raise InputError(
            f"the GML file is not well-formed XML: {xml.parsers.expat.errors.messages[exc.code]}",
            where=f"{path}, line {exc.lineno}, column {exc.offset + 1}",
            fix="download or export it again; a file cut short ends before its last element",
        ) from None
    except (LookupError, ValueError) as exc:  # an unknown or multi-byte declared encoding
        raise InputError(
            f"the GML file declares an encoding that cannot be read ({exc})",
            where=str(path),
            fix="save it as UTF-8, as OS MasterMap is delivered",
        ) from None


@contextlib.contextmanager
def _nothing_written_beside(path: str) -> Iterator:
    """Reading must not write beside the input. GDAL's VFK driver (Czech cadastre; it claims
    any file starting with ``&H``) puts an SQLite database beside the file it opens: point it
    at a temporary folder instead (found by fuzzing). GML's ``.gfs`` is kept off by
    ``WRITE_GFS=NO``."""
    previous = pyogrio.get_gdal_config_option("OGR_VFK_DB_NAME")
    with tempfile.TemporaryDirectory(prefix="gnss-citygml-vfk-") as folder:
        pyogrio.set_gdal_config_options({"OGR_VFK_DB_NAME": os.path.join(folder, "vfk.db")})
        try:
            yield
        finally:
            pyogrio.set_gdal_config_options({"OGR_VFK_DB_NAME": previous})


def _polygon_layer(path: str, kind: str | None) -> str | None:
    """The source's only polygon layer (None: let GDAL take the first layer of a GML file)."""
    if kind:  # listing a GML file's layers would write a .gfs sidecar beside it
        return None
    try:
        layers = pyogrio.list_layers(path)
    except pyogrio.errors.DataSourceError as exc:
        raise _unreadable(exc, path) from None
    if len(layers) == 1:
        return str(layers[0][0])
    polygonal = [str(name) for name, geom in layers if geom == "Unknown" or "Polygon" in str(geom)]
    if len(polygonal) == 1:
        return polygonal[0]
    names = ", ".join(str(name) for name, _ in layers)
    raise InputError(
        f"the source has several layers ({names})", where=path, fix="choose one with --layer"
    )


def _unreadable(exc: Exception, where: str) -> InputError:
    return InputError(
        f"cannot read the footprints: {first_line(exc)}",
        where=where,
        fix="give a polygon layer GDAL reads (GeoPackage, Shapefile, GeoJSON, MasterMap GML)",
    )


def _read_layer(path, layer: str | None, where: str, options: dict) -> gpd.GeoDataFrame:
    """The layer (None: the first), or an :class:`InputError` for an unreadable source, a
    source without layers or a geometry GEOS cannot build (e.g. an unclosed ring)."""
    try:
        return pyogrio.read_dataframe(
            path, layer=0 if layer is None else layer, force_2d=True, fid_as_index=True, **options
        )
    except (
        pyogrio.errors.DataSourceError,
        pyogrio.errors.DataLayerError,
        shapely.errors.GEOSException,
    ) as exc:
        raise _unreadable(exc, where) from None


def _is_geoparquet(path: Path) -> bool:
    """A GeoParquet file, or a folder of them (in the hive layout: a run's heights written per
    tile, :mod:`gnss_citygml.tiling.output`, or one tile's folder): GeoPandas reads them, GDAL
    only with Arrow."""
    if path.is_dir():
        return next(path.rglob("*.parquet"), None) is not None
    return path.suffix.lower() == ".parquet"


def _read_geoparquet(path: Path) -> gpd.GeoDataFrame:
    """A GeoParquet file or hive folder, its partition keys (``tile``) as text; an
    :class:`InputError` if it cannot be read as GeoParquet (:func:`_check_geoparquet` first:
    GeoPandas's own errors on a metadata it does not expect are not one line)."""
    _check_geoparquet(path)
    try:
        frame = gpd.read_parquet(path)
    except (OSError, ValueError, TypeError, shapely.errors.GEOSException) as exc:
        # pyarrow's errors are these too; GEOS's: WKB it cannot parse
        raise InputError(
            f"cannot read the footprints as GeoParquet ({first_line(exc)})",
            where=str(path),
            fix="give a GeoParquet file (with its geometry metadata), or a GeoPackage",
        ) from None
    check_text(frame, str(path))
    for column in frame.columns:
        if isinstance(frame[column].dtype, pd.CategoricalDtype):
            frame[column] = frame[column].astype(str)
    return frame


#: The geometry encodings of GeoParquet 1.1 (WKB, and GeoArrow's native ones) and the Arrow
#: types that hold them: binary, or lists (of lists ...) of structs of coordinates.
_ENCODINGS = {
    "WKB": ("binary", "large_binary"),
    **{
        kind: ("list", "large_list", "struct")
        for kind in ("point", "linestring", "polygon", "multipoint", "multilinestring")
    },
    "multipolygon": ("list", "large_list"),
}


def _check_geoparquet(path: Path) -> None:
    """Refuse, in one line, a file (or any file of a folder) that GeoPandas cannot read as
    GeoParquet: not Parquet, no ``geo`` metadata (plain Parquet), metadata that is not the
    standard's, or a geometry whose encoding is not one of :data:`_ENCODINGS` (WKT is not
    GeoParquet) or not what its column holds. Reads the files' footers only."""
    import pyarrow as pa
    import pyarrow.parquet as pq
    import pyproj

    fix = "write it as GeoParquet (geopandas' to_parquet, or ogr2ogr with Arrow), or a GeoPackage"
    files = [path]
    if path.is_dir():  # as pyarrow reads a folder: not the hidden files (._x, .x.part-...)
        files = sorted(
            f
            for f in path.rglob("*.parquet")
            if not any(p.startswith((".", "_")) for p in f.relative_to(path).parts)
        )
    for file in files:
        try:
            schema = pq.read_schema(file)
        except (OSError, pa.ArrowException) as exc:
            raise InputError(
                f"cannot read the footprints as GeoParquet: not a Parquet file ({first_line(exc)})",
                where=str(file),
                fix="give a GeoParquet file, or a GeoPackage",
            ) from None
        try:
            geo = json.loads((schema.metadata or {})[b"geo"])
        except (KeyError, ValueError):
            raise InputError(
                "the footprints' Parquet has no GeoParquet metadata ('geo'): which column is "
                "the geometry, in which CRS, is not said",
                where=str(file),
                fix=fix,
            ) from None
        columns = geo.get("columns") if isinstance(geo, dict) else None
        primary = geo.get("primary_column") if isinstance(geo, dict) else None
        if not (isinstance(columns, dict) and primary in columns and primary in schema.names):
            raise InputError(
                "the footprints' GeoParquet metadata ('geo') names no geometry column of the "
                f"file (primary_column {primary!r}, columns {listing(schema.names)})",
                where=str(file),
                fix=fix,
            )
        for name, spec in columns.items():
            if name not in schema.names:
                continue
            encoding = spec.get("encoding") if isinstance(spec, dict) else None
            kind = str(schema.field(name).type).split("<")[0]
            if encoding not in _ENCODINGS or kind not in _ENCODINGS[encoding]:
                raise InputError(
                    f"the footprints' geometry column {name!r} is encoded as {encoding!r} "
                    f"and holds {kind}: GeoParquet reads WKB (binary) or GeoArrow's native "
                    f"encodings ({listing(list(_ENCODINGS)[1:])}), and WKT is not GeoParquet",
                    where=str(file),
                    fix=fix,
                )
            try:
                if spec.get("crs") is not None:
                    pyproj.CRS.from_user_input(spec["crs"])
            except pyproj.exceptions.CRSError as exc:
                raise InputError(
                    f"the footprints' geometry column {name!r} has a CRS that is not one "
                    f"({first_line(exc)})",
                    where=str(file),
                    fix="write the file again with its CRS (e.g. EPSG:27700)",
                ) from None


def _has_building_group(groups: pd.Series) -> np.ndarray:
    """Whether each MasterMap descriptiveGroup (one text, a list of texts, or missing: None or
    NaN) has "Building"."""
    return np.array(
        [
            g == "Building" if isinstance(g, str) else is_list_like(g) and "Building" in list(g)
            for g in groups.values
        ],
        dtype=bool,
    )


def _with_ids(
    frame: gpd.GeoDataFrame, id_field: str | None, where: str
) -> tuple[gpd.GeoDataFrame, str | None]:
    """Move the id field (or the feature id) to a text column ``id`` placed first; the field
    moved (None: the feature id)."""
    columns = [c for c in frame.columns if c != frame.geometry.name]
    if id_field is None:
        lower = {str(c).lower(): c for c in reversed(columns)}
        id_field = next((lower[name] for name in _ID_FIELDS if name in lower), None)
    elif id_field not in columns and id_field.lower() == "fid":
        id_field = None  # GDAL's feature id itself (QGIS lists it as a field "fid")
    elif id_field not in columns:
        raise MissingColumnError([id_field], where=where, have=columns)
    ids = frame.index.to_series() if id_field is None else frame[id_field]
    others = [c for c in columns if c != id_field and str(c).lower() == "id"]
    if others:
        raise InputError(
            f"the layer has a column {others[0]!r} besides the id field {id_field!r}",
            where=where,
            fix=f"use --id-field {others[0]} or rename that column",
        )
    name = id_field or "feature id"
    text = _id_text(ids, name, where)
    frame = frame.drop(columns=[id_field]) if id_field is not None else frame
    frame = frame.reset_index(drop=True)
    frame.insert(0, "id", text.to_numpy())
    repeated = text[text.duplicated()].unique()
    if repeated.size:
        raise InputError(
            f"{repeated.size} duplicate id(s) in '{user_text(name)}': {listing(repeated)}",
            where=where,
            fix="give each footprint its own id, or choose another --id-field",
        )
    return frame, id_field


def _output_name(field: str | None, mastermap: bool) -> str:
    """The name the outputs give the id of footprints whose ids came from ``field``."""
    if field is None or (field.lower() == "fid" and not mastermap):
        return "id"
    return "toid" if mastermap and field in ("fid", "gml_id") else field


def _id_text(ids: pd.Series, name: str, where: str) -> pd.Series:
    """The ids as text; an :class:`InputError` naming the features (row of the source, from 0)
    whose id is missing, blank or holds a NUL (:func:`~gnss_citygml.files.ids.missing_ids`)."""
    missing = missing_ids(ids)
    if missing.any():
        rows = np.flatnonzero(missing)
        raise InputError(
            f"{rows.size} feature(s) without an id (missing, blank or with a NUL character)"
            f" in '{user_text(name)}': rows {listing(rows)}",
            where=where,
            fix="fill in the ids or choose another --id-field",
        )
    return id_text(ids)


def _looks_like_degrees(bounds: np.ndarray) -> bool:
    west, south, east, north = bounds
    return bool(-180 <= west and east <= 180 and -90 <= south and north <= 90)


def _to_bng(frame: gpd.GeoDataFrame, where: str, grid_dir) -> gpd.GeoDataFrame:
    """The footprints in EPSG:27700, through :func:`~gnss_citygml.geodesy.to_bng` only."""
    crs, bounds = frame.crs, frame.total_bounds
    degrees = _looks_like_degrees(bounds)
    if crs is None:
        code = "EPSG:4326" if degrees else _BNG
        looks = " and coordinates that look like longitude/latitude" if degrees else ""
        raise InputError(
            f"the footprints have no CRS{looks}",
            where=where,
            fix=f"assign it, e.g. ogr2ogr -a_srs {code} fixed.gpkg INPUT",
        )
    if crs.is_projected and degrees:
        raise InputError(
            f"the footprints' coordinates look like degrees but their CRS is {crs.name}",
            where=where,
            fix="assign the right CRS, e.g. ogr2ogr -a_srs EPSG:4326 fixed.gpkg INPUT",
        )
    if crs.is_geographic and not degrees:
        raise InputError(
            f"the footprints' CRS is {crs.name} (degrees) but their coordinates look like metres",
            where=where,
            fix="assign the right CRS, e.g. ogr2ogr -a_srs EPSG:27700 fixed.gpkg INPUT",
        )
    if is_bng(crs):
        return frame.set_crs(_BNG, allow_override=True)
    geoms = frame.geometry.to_numpy()
    xy, owner = shapely.get_coordinates(geoms, return_index=True)
    ids = frame["id"].to_numpy(dtype=object)

    def labels(index):  # made only for the vertices an error names
        return [f"footprint {i}" for i in ids[owner[index]]]

    try:
        e, n = to_bng(xy[:, 0], xy[:, 1], crs, grid_dir=grid_dir, labels=labels)
    except (CrsError, OutsideExtentError) as exc:  # name the file too
        raise type(exc)(exc.what, where=f"{where}: {exc.where}", fix=exc.fix) from None
    geoms = shapely.set_coordinates(geoms.copy(), np.column_stack([e, n]))
    return gpd.GeoDataFrame(frame.drop(columns=frame.geometry.name), geometry=geoms, crs=_BNG)


def check_polygonal(geoms: np.ndarray, ids: np.ndarray, where: str) -> None:
    """Raise an :class:`InputError` naming the features unless every geometry is a non-empty
    Polygon or MultiPolygon (footprints read here, and buildings handed to the terrain)."""
    polygonal = np.isin(shapely.get_type_id(geoms), [3, 6]) & ~shapely.is_empty(geoms)
    if not polygonal.all():
        kinds = sorted({"missing" if g is None else g.geom_type for g in geoms[~polygonal]})
        raise InputError(
            f"{(~polygonal).sum()} feature(s) are not polygons ({', '.join(kinds)}):"
            f" {listing(ids[~polygonal].tolist())}",
            where=where,
            fix="choose the polygon layer (--layer) or remove those features",
        )


def _repaired(frame: gpd.GeoDataFrame, where: str) -> gpd.GeoDataFrame:
    """Repair the invalid footprints with a warning; drop (with a warning) those left empty,
    unless that is all of them: an error, not an empty table."""
    geoms = frame.geometry.to_numpy()
    invalid = ~shapely.is_valid(geoms)
    if not invalid.any():
        return frame
    ids = frame["id"].to_numpy()
    geoms = geoms.copy()
    geoms[invalid] = shapely.make_valid(geoms[invalid], method="structure", keep_collapsed=False)
    empty = shapely.is_empty(geoms)
    if empty.all():
        raise InputError(
            f"none of the {empty.size} footprint(s) has an area: {listing(ids)}",
            where=where,
            fix="give polygons with an area (not collapsed to lines or points)",
        )
    repaired = invalid & ~empty  # one message per footprint: repaired, or dropped
    if repaired.any():
        warnings.warn(
            f"repaired {repaired.sum()} invalid footprint(s) with make_valid: "
            f"{listing(ids[repaired])} ({where})",
            UserWarning,
            stacklevel=3,
        )
    frame = frame.set_geometry(geoms)
    if empty.any():
        warnings.warn(
            f"dropped {empty.sum()} footprint(s) with no area: {listing(ids[empty])} ({where})",
            UserWarning,
            stacklevel=3,
        )
        frame = frame[~empty].reset_index(drop=True)
    return frame
