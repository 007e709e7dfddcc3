"""Building footprints and the ground under them: the *buildings* table of DESIGN.md.

Footprints come from any polygon layer pyogrio reads (GeoPackage, Shapefile, GeoJSON, ...) or
from OS MasterMap Topography Layer GML; they leave :func:`read_footprints` as a GeoDataFrame in
EPSG:27700 with a text ``id``, valid Polygon/MultiPolygon geometries and the input attributes.
Terrain comes from any raster rasterio reads (an OS Terrain 5 GeoTIFF, an OS Terrain 50 ESRI
ASCII grid, also inside a zip as ``zip://tiles.zip!/NG33.asc``): :func:`building_ground` adds
the ``ground`` height under each footprint and :func:`sample_ground` interpolates the ground at
receiver positions. The DEM is read in windows of at most about ``_BLOCK`` x ``_BLOCK`` cells,
never once per building or per point.

Rules
-----
- **id**: ``id_field`` if given; else the first column named ``toid``, ``id`` or ``fid`` (in
  that order, any letter case); else the source's feature id (the GeoPackage ``fid``, the row
  number of a Shapefile). MasterMap features use their TOID (the ``fid`` attribute, or
  ``gml_id`` in newer schemas). The id field *moves* to the text column ``id``; every other
  attribute is kept untouched. Ids must be present and unique.
- **geometry**: every feature must be a Polygon or MultiPolygon: a missing geometry, a point,
  a line or a collection is an error naming the features (pick a polygon layer or filter the
  source), never a silently dropped building. Z coordinates are dropped. Invalid polygons are
  repaired with ``shapely.make_valid`` keeping only their polygonal parts, with a warning that
  lists their ids; a polygon with no area left is dropped, with a warning.
- **CRS**: footprints in another CRS are transformed to EPSG:27700 by
  :func:`gnss_citygml.geodesy.to_bng`, the toolkit's one path (OSTN15 + OSGM15 for ETRS89 and
  WGS 84, a conversion for OSGB36); a CRS on any other datum, or missing grids, is an error,
  never PROJ's 2 m Helmert transformation. Footprints without a CRS, or whose coordinates
  contradict their CRS (degrees in a projected CRS, metres in a geographic one), are an error.
- **DEM**: it must be in EPSG:27700: it is not resampled here, as a DEM's heights would need
  the geoid too; reproject it through the OSTN15 grid and keep ODN heights. A DEM without a
  CRS (an ESRI ASCII grid without ``.prj``) is taken as EPSG:27700 only when the caller says
  so with ``assume_crs``. A building or receiver off the DEM, or over its nodata
  cells, is a :class:`DemCoverageError` listing them.
"""

from __future__ import annotations

import contextlib
import gzip
import os
import tempfile
import warnings
import xml.parsers.expat
import zlib
from collections.abc import Iterator, Sequence
from pathlib import Path

import geopandas as gpd
import numpy as np
import pandas as pd
import pyogrio
import rasterio
import rasterio.features
import shapely
from pandas.api.types import is_list_like
from pyproj.exceptions import CRSError
from rasterio.io import DatasetReader
from rasterio.windows import Window

from .errors import InputError, MissingColumnError
from .geodesy import CrsError, OutsideExtentError, is_bng, to_bng
from .paths import input_file

__all__ = [
    "STATISTICS",
    "DemCoverageError",
    "building_ground",
    "read_footprints",
    "sample_ground",
]

#: The ground statistics :func:`building_ground` offers.
STATISTICS = ("median", "min", "mean")

_BNG = "EPSG:27700"
_ID_FIELDS = ("toid", "id", "fid")
_MASTERMAP_NAMESPACES = (
    b"ordnancesurvey.co.uk/xml/namespaces/osgb",
    b"namespaces.os.uk/mastermap/topography",
)
#: What makes GDAL read an XML file (starting with "<", after a UTF-8 byte order mark) with
#: its GML driver, which writes a .gfs sidecar unless told not to (ogrgmldatasource.cpp).
_GML_MARKERS = (b"opengis.net/gml", b"<csw:GetRecordsResponse")
#: Ids or indices shown in one error or warning message.
_SHOWN = 10
#: Side (cells) of the DEM blocks read at once.
_BLOCK = 1024


class DemCoverageError(InputError):
    """Buildings or receivers off the DEM or over its nodata cells.

    ``items`` holds all of them (ids or indices); the message shows the first few.
    """

    def __init__(self, what: str, items: Sequence, *, where: str, fix: str):
        self.items = list(items)
        super().__init__(f"{len(self.items)} {what}: {_listing(self.items)}", where=where, fix=fix)


def _listing(items: Sequence) -> str:
    shown = ", ".join(str(item) for item in list(items)[:_SHOWN])
    return shown + (f" and {len(items) - _SHOWN} more" if len(items) > _SHOWN else "")


# --- footprints ---------------------------------------------------------------------------------


def read_footprints(path, *, layer: str | None = None, id_field: str | None = None, grid_dir=None):
    """Read building footprints as the *buildings* table (without ``ground``).

    Parameters
    ----------
    path
        A GeoPackage or any polygon source pyogrio reads, or an OS MasterMap Topography Layer
        GML file (``.gml`` or ``.gml.gz``; its TopographicArea features whose descriptiveGroup
        includes ``Building`` are read). GML is read with ``WRITE_GFS=NO``: no ``.gfs`` sidecar
        is written next to it. It is checked to be well-formed XML first: GDAL reads no
        feature at all from a file cut short, without an error.
    layer
        The layer to read. By default: the only polygon layer of the source, or
        ``TopographicArea`` for MasterMap.
    id_field
        The column holding the building ids (default: see the module's rules).
    grid_dir
        Folder of the OSTN15/OSGM15 grids, for footprints in another CRS than EPSG:27700
        (see :mod:`gnss_citygml.geodesy`; default ``$GNSS_CITYGML_GRID_DIR``, then PROJ's).

    Returns
    -------
    geopandas.GeoDataFrame
        ``id`` (str), the input attributes, and ``geometry`` (Polygon/MultiPolygon, valid)
        in EPSG:27700.

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
    frame = _with_ids(frame, id_field, where)
    _check_polygonal(frame.geometry.to_numpy(), frame["id"].to_numpy(), where)
    return _repaired(_to_bng(frame, where, grid_dir), where)


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
    """A gzipped file opened for reading; a damaged one (while read too) is an InputError."""
    try:
        with gzip.open(path, "rb") as unzipped:
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
    first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
    return InputError(
        f"cannot read the footprints: {first}",
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


def _with_ids(frame: gpd.GeoDataFrame, id_field: str | None, where: str) -> gpd.GeoDataFrame:
    """Move the id field (or the feature id) to a text column ``id`` placed first."""
    columns = [c for c in frame.columns if c != frame.geometry.name]
    if id_field is None:
        lower = {str(c).lower(): c for c in reversed(columns)}
        id_field = next((lower[name] for name in _ID_FIELDS if name in lower), None)
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
            f"{repeated.size} duplicate id(s) in {name!r}: {_listing(repeated)}",
            where=where,
            fix="give each footprint its own id, or choose another --id-field",
        )
    return frame


def _id_text(ids: pd.Series, name: str, where: str) -> pd.Series:
    missing = ids.isna().to_numpy()
    if missing.any():
        rows = np.flatnonzero(missing)
        raise InputError(
            f"{rows.size} feature(s) without an id in {name!r}: rows {_listing(rows)}",
            where=where,
            fix="fill in the ids or choose another --id-field",
        )
    if pd.api.types.is_float_dtype(ids) and np.all(np.mod(ids.to_numpy(), 1) == 0):
        ids = ids.astype(np.int64)
    return ids.astype(str)


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


def _check_polygonal(geoms: np.ndarray, ids: np.ndarray, where: str) -> None:
    """Every geometry must be a non-empty Polygon or MultiPolygon."""
    polygonal = np.isin(shapely.get_type_id(geoms), [3, 6]) & ~shapely.is_empty(geoms)
    if not polygonal.all():
        kinds = sorted({"missing" if g is None else g.geom_type for g in geoms[~polygonal]})
        raise InputError(
            f"{(~polygonal).sum()} feature(s) are not polygons ({', '.join(kinds)}):"
            f" {_listing(ids[~polygonal].tolist())}",
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
            f"none of the {empty.size} footprint(s) has an area: {_listing(ids)}",
            where=where,
            fix="give polygons with an area (not collapsed to lines or points)",
        )
    repaired = invalid & ~empty  # one message per footprint: repaired, or dropped
    if repaired.any():
        warnings.warn(
            f"repaired {repaired.sum()} invalid footprint(s) with make_valid: "
            f"{_listing(ids[repaired])} ({where})",
            UserWarning,
            stacklevel=3,
        )
    frame = frame.set_geometry(geoms)
    if empty.any():
        warnings.warn(
            f"dropped {empty.sum()} footprint(s) with no area: {_listing(ids[empty])} ({where})",
            UserWarning,
            stacklevel=3,
        )
        frame = frame[~empty].reset_index(drop=True)
    return frame


# --- DEM ---------------------------------------------------------------------------------------


@contextlib.contextmanager
def _open_dem(dem, assume_crs, band: int) -> Iterator[DatasetReader]:
    """An open DEM (the caller's own, or opened and closed here), checked to be in BNG."""
    if isinstance(dem, DatasetReader):
        _check_dem(dem, assume_crs, band)
        yield dem
        return
    name = os.fspath(dem)
    try:
        dataset = rasterio.open(name)
    except rasterio.errors.RasterioIOError as exc:
        raise InputError(
            f"cannot open the DEM: {str(exc).splitlines()[0]}",
            where=name,
            fix="give a raster GDAL reads (GeoTIFF, ESRI ASCII grid; zip://tiles.zip!/NG33.asc)",
        ) from None
    with dataset:
        _check_dem(dataset, assume_crs, band)
        yield dataset


def _check_dem(ds: DatasetReader, assume_crs, band: int) -> None:
    if not 1 <= band <= ds.count:
        raise InputError(
            f"the DEM has no band {band}", where=ds.name, fix=f"choose a band from 1 to {ds.count}"
        )
    crs = ds.crs if ds.crs is not None else assume_crs
    if crs is None:
        raise InputError(
            "the DEM has no CRS",
            where=ds.name,
            fix="if it is in British National Grid (as OS Terrain ASCII grids are),"
            " say so with assume_crs='EPSG:27700' (--dem-crs EPSG:27700)",
        )
    try:
        bng = is_bng(crs.to_wkt() if hasattr(crs, "to_wkt") else crs)
    except CRSError as exc:
        raise InputError(
            f"unknown DEM CRS {crs!r} ({exc})", where=ds.name, fix="give an EPSG code"
        ) from None
    if not bng:
        raise InputError(
            "the DEM is not in EPSG:27700 (British National Grid)",
            where=ds.name,
            fix="reproject it with the OSTN15 grid, keeping ODN heights: gdalwarp -t_srs "
            "EPSG:27700 dem.tif dem_bng.tif with the grids installed (gnss-citygml grids "
            "--fetch; without them PROJ silently takes a 2 m Helmert transformation)",
        )
    if ds.transform.b or ds.transform.d:
        raise InputError(
            "the DEM grid is rotated",
            where=ds.name,
            fix="resample it north up, e.g. gdalwarp dem.tif dem_north_up.tif",
        )


def _to_pixel(ds: DatasetReader, x, y):
    """Fractional (column, row) of points: cell (r, c) spans [c, c + 1) x [r, r + 1)."""
    inverse = ~ds.transform
    return inverse.a * x + inverse.b * y + inverse.c, inverse.d * x + inverse.e * y + inverse.f


def _read(ds: DatasetReader, band: int, window: Window) -> np.ndarray:
    """One window of the DEM as float64, with NaN for nodata (masked) cells."""
    values = ds.read(band, window=window, masked=True)
    return np.ma.filled(values.astype(np.float64), np.nan)


def _block_groups(rows: np.ndarray, cols: np.ndarray) -> list[np.ndarray]:
    """Indices of the items grouped by the ``_BLOCK``-cell block holding (rows, cols)."""
    keys = (rows // _BLOCK) * (1 + cols.max() // _BLOCK) + cols // _BLOCK
    order = np.argsort(keys, kind="stable")
    splits = np.flatnonzero(np.diff(keys[order])) + 1
    return np.split(order, splits)


def _cells(ds: DatasetReader, band: int, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """The DEM's values at integer cell indices (NaN for nodata), read block by block."""
    out = np.empty(rows.size)
    if rows.size == 0:
        return out
    for group in _block_groups(rows, cols):
        r, c = rows[group], cols[group]
        r0, c0 = r.min(), c.min()
        block = _read(ds, band, Window(c0, r0, c.max() - c0 + 1, r.max() - r0 + 1))
        out[group] = block[r - r0, c - c0]
    return out


def _bilinear(ds: DatasetReader, band: int, x: np.ndarray, y: np.ndarray):
    """Bilinear interpolation between cell centres; (values, off the DEM, over nodata)."""
    col, row = _to_pixel(ds, x, y)
    off = ~((col >= 0) & (col <= ds.width) & (row >= 0) & (row <= ds.height))
    col, row = np.where(off, 0.0, col) - 0.5, np.where(off, 0.0, row) - 0.5
    cf, rf = np.clip(col, 0, ds.width - 1), np.clip(row, 0, ds.height - 1)
    c0 = np.floor(cf).astype(np.int64)
    r0 = np.floor(rf).astype(np.int64)
    c1, r1 = np.minimum(c0 + 1, ds.width - 1), np.minimum(r0 + 1, ds.height - 1)
    tx, ty = cf - c0, rf - r0
    rows = np.concatenate([r0, r0, r1, r1])
    cols = np.concatenate([c0, c1, c0, c1])
    corners = _cells(ds, band, rows, cols).reshape(4, -1)
    weights = np.stack([(1 - tx) * (1 - ty), tx * (1 - ty), (1 - tx) * ty, tx * ty])
    used = weights > 0
    nodata = (np.isnan(corners) & used).any(axis=0) & ~off
    values = np.where(used, weights * np.nan_to_num(corners), 0.0).sum(axis=0)
    values[off | nodata] = np.nan
    return values, off, nodata


def sample_ground(
    dem, e, n, *, assume_crs=None, band: int = 1, labels: Sequence | None = None
) -> np.ndarray:
    """Ground heights at points by bilinear interpolation of a DEM.

    Heights are interpolated between the four nearest cell centres; in the outer half cell of
    the DEM the edge cells' values are used along that axis.

    Parameters
    ----------
    dem
        A raster path rasterio opens (also ``"zip://tiles.zip!/NG33.asc"``, as a str) or an
        open dataset, in EPSG:27700.
    e, n
        Easting and northing of the points (m, EPSG:27700).
    assume_crs
        The CRS of a DEM that has none (e.g. ``"EPSG:27700"`` for OS Terrain ASCII grids);
        ignored when the DEM has one.
    band
        The raster band holding the heights.
    labels
        Names of the points for error messages (default: their positions 0, 1, ...).

    Returns
    -------
    numpy.ndarray
        The ground height of each point (the DEM's units, m ODN for OS Terrain).

    Raises
    ------
    DemCoverageError
        Points off the DEM or next to its nodata cells, listed.

    Examples
    --------
    >>> from rasterio.io import MemoryFile
    >>> from rasterio.transform import from_origin
    >>> z = np.array([[10.0, 12.0], [14.0, 16.0]])  # north row first, 5 m cells
    >>> with MemoryFile() as mem:
    ...     with mem.open(driver="GTiff", width=2, height=2, count=1, dtype="float64",
    ...                   crs="EPSG:27700", transform=from_origin(500000, 200010, 5, 5)) as ds:
    ...         ds.write(z, 1)
    ...     with mem.open() as dem:
    ...         sample_ground(dem, [500002.5, 500005.0], [200007.5, 200005.0])
    array([10., 13.])
    """
    e, n = np.asarray(e, dtype=float).ravel(), np.asarray(n, dtype=float).ravel()
    if e.shape != n.shape:
        raise InputError(f"{e.size} eastings but {n.size} northings", where="sample_ground")
    labels = np.arange(e.size) if labels is None else np.asarray(labels)
    if e.size == 0:
        return np.array([])
    with _open_dem(dem, assume_crs, band) as ds:
        heights, off, nodata = _bilinear(ds, band, e, n)
        if off.any():
            raise DemCoverageError(
                "point(s) off the DEM",
                labels[off].tolist(),
                where=ds.name,
                fix="use a DEM that covers every receiver position, or drop those observations",
            )
        if nodata.any():
            raise DemCoverageError(
                "point(s) over nodata cells of the DEM",
                labels[nodata].tolist(),
                where=ds.name,
                fix="fill the DEM's gaps (e.g. gdal_fillnodata) or drop those observations",
            )
    return heights


def building_ground(
    buildings: gpd.GeoDataFrame,
    dem,
    statistic: str = "median",
    *,
    assume_crs=None,
    band: int = 1,
) -> gpd.GeoDataFrame:
    """The buildings with their ``ground`` height: a statistic of the DEM under each footprint.

    The cells under a footprint are those whose centres it contains (``rasterio.features.
    rasterize``, one burn per window of DEM blocks; overlapping footprints are burnt in separate
    passes so each gets all its cells). A footprint that contains no cell centre (smaller or
    thinner than a cell) gets the bilinear height at a point inside it
    (``shapely.point_on_surface``).

    Parameters
    ----------
    buildings
        The buildings table (``id``, ``geometry`` in EPSG:27700), e.g. from
        :func:`read_footprints`.
    dem
        A raster path rasterio opens or an open dataset, in EPSG:27700.
    statistic
        ``"median"`` (default), ``"min"`` or ``"mean"`` of the cells under the footprint.
    assume_crs
        The CRS of a DEM that has none (e.g. ``"EPSG:27700"``); ignored when it has one.
    band
        The raster band holding the heights.

    Returns
    -------
    geopandas.GeoDataFrame
        A copy of ``buildings`` with the column ``ground`` (float, the DEM's units).

    Raises
    ------
    DemCoverageError
        Buildings not wholly on the DEM, or with nodata cells under them, listed by id.

    Examples
    --------
    >>> from rasterio.io import MemoryFile
    >>> from rasterio.transform import from_origin
    >>> z = np.arange(16.0).reshape(4, 4)  # 1 m cells
    >>> houses = gpd.GeoDataFrame({"id": ["a", "b"]}, crs="EPSG:27700",
    ...     geometry=[shapely.box(0.2, 0.2, 1.8, 1.8), shapely.box(3.4, 3.4, 3.6, 3.6)])
    >>> with MemoryFile() as mem:
    ...     with mem.open(driver="GTiff", width=4, height=4, count=1, dtype="float64",
    ...                   crs="EPSG:27700", transform=from_origin(0, 4, 1, 1)) as ds:
    ...         ds.write(z, 1)
    ...     with mem.open() as dem:
    ...         building_ground(houses, dem)["ground"].tolist()
    [10.5, 3.0]
    """
    if statistic not in STATISTICS:
        raise InputError(
            f"unknown ground statistic {statistic!r}",
            where="building_ground",
            fix="use one of " + ", ".join(STATISTICS),
        )
    if "id" not in buildings.columns:
        raise MissingColumnError(["id"], where="buildings", have=list(buildings.columns))
    if buildings.crs is None or not is_bng(buildings.crs):
        raise InputError(
            f"the buildings are in {buildings.crs or 'no CRS'}, not EPSG:27700",
            where="buildings",
            fix="read them with read_footprints, which transforms them",
        )
    out = buildings.copy()
    if buildings.empty:
        out["ground"] = np.array([], dtype=float)
        return out
    geoms = buildings.geometry.to_numpy()
    ids = buildings["id"].astype(str).to_numpy()
    _check_polygonal(geoms, ids, "buildings")
    with _open_dem(dem, assume_crs, band) as ds:
        row0, row1, col0, col1 = _pixel_bounds(ds, shapely.bounds(geoms))
        off = (row0 < 0) | (col0 < 0) | (row1 > ds.height) | (col1 > ds.width)
        if off.any():
            raise DemCoverageError(
                "building(s) not wholly on the DEM",
                ids[off].tolist(),
                where=ds.name,
                fix="use a DEM that covers every footprint, or drop those footprints",
            )
        index, values = _cells_under(ds, band, geoms, row0, row1, col0, col1)
        nodata = np.unique(index[np.isnan(values)])
        inside = shapely.point_on_surface(geoms)
        fallback = np.bincount(index, minlength=len(geoms)) == 0
        heights, _, small_nodata = _bilinear(
            ds, band, shapely.get_x(inside[fallback]), shapely.get_y(inside[fallback])
        )
        nodata = np.union1d(nodata, np.flatnonzero(fallback)[small_nodata])
        if nodata.size:
            raise DemCoverageError(
                "building(s) over nodata cells of the DEM",
                ids[nodata].tolist(),
                where=ds.name,
                fix="fill the DEM's gaps (e.g. gdal_fillnodata) or drop those footprints",
            )
    ground = _grouped(index, values, statistic, len(geoms))
    ground[fallback] = heights
    out["ground"] = ground
    return out


def _pixel_bounds(ds: DatasetReader, bounds: np.ndarray):
    """Rows and columns (start, stop) of the cells each bounding box touches."""
    cols, rows = _to_pixel(ds, bounds[:, [0, 2]].T, bounds[:, [1, 3]].T)
    row0 = np.floor(rows.min(axis=0)).astype(np.int64)
    row1 = np.ceil(rows.max(axis=0)).astype(np.int64)
    col0 = np.floor(cols.min(axis=0)).astype(np.int64)
    col1 = np.ceil(cols.max(axis=0)).astype(np.int64)
    return row0, row1, col0, col1


def _cells_under(ds, band, geoms, row0, row1, col0, col1):
    """(building index, DEM value) for every cell whose centre a footprint contains."""
    layer = _overlap_layers(geoms)
    found_index, found_values = [], []
    for group in _block_groups(row0, col0):
        r0, c0 = row0[group].min(), col0[group].min()
        window = Window(c0, r0, col1[group].max() - c0, row1[group].max() - r0)
        block = _read(ds, band, window)
        transform = ds.window_transform(window)
        for pass_ in np.unique(layer[group]):
            members = group[layer[group] == pass_]
            burnt = rasterio.features.rasterize(
                zip(geoms[members], members + 1, strict=True),
                out_shape=block.shape,
                transform=transform,
                fill=0,
                dtype="int32",
            )
            under = burnt > 0
            found_index.append(burnt[under] - 1)
            found_values.append(block[under])
    return np.concatenate(found_index).astype(np.int64), np.concatenate(found_values)


def _overlap_layers(geoms: np.ndarray) -> np.ndarray:
    """A pass number per footprint such that footprints of one pass do not overlap."""
    tree = shapely.STRtree(geoms)
    pairs = np.concatenate(
        [tree.query(geoms, predicate="overlaps"), tree.query(geoms, predicate="contains")], axis=1
    )
    later, earlier = pairs.max(axis=0), pairs.min(axis=0)
    keep = later > earlier  # each overlapping pair once, the later footprint first
    later, earlier = later[keep], earlier[keep]
    layer = np.zeros(len(geoms), dtype=np.int64)
    for i in np.unique(later):  # only footprints that overlap earlier ones: usually none
        taken = set(layer[earlier[later == i]].tolist())
        layer[i] = next(k for k in range(len(taken) + 1) if k not in taken)
    return layer


def _grouped(index: np.ndarray, values: np.ndarray, statistic: str, size: int) -> np.ndarray:
    """A statistic of ``values`` per group ``index`` (NaN for groups with no values)."""
    order = np.lexsort((values, index))
    index, values = index[order], values[order]
    counts = np.bincount(index, minlength=size)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    has = counts > 0
    out = np.full(size, np.nan)
    if statistic == "median":
        low = values[starts[has] + (counts[has] - 1) // 2]
        high = values[starts[has] + counts[has] // 2]
        out[has] = (low + high) / 2
    elif statistic == "min":
        out[has] = values[starts[has]]
    else:
        out[has] = np.bincount(index, weights=values, minlength=size)[has] / counts[has]
    return out
