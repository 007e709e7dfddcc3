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

import warnings
from collections.abc import Iterator

import geopandas as gpd
import numpy as np
import pandas as pd
import shapely
from pandas.api.types import is_list_like

from .errors import InputError, MissingColumnError, listing, user_text
from .files.ids import id_text, missing_ids, with_id_field
from .files.paths import StrPath
from .files.sources import Source
from .geodesy import CrsError, OutsideExtentError, is_bng, to_bng

__all__ = ["BATCH", "check_polygonal", "footprint_batches", "read_footprints"]

_BNG = "EPSG:27700"
_ID_FIELDS = ("toid", "id", "fid")

#: Features read at once by :func:`footprint_batches`.
BATCH = 65_536


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
    source = Source.of(path, layer)
    return _prepared(_buildings_only(source.read(), source), source, id_field, grid_dir)


def footprint_batches(
    path: StrPath,
    *,
    layer: str | None = None,
    id_field: str | None = None,
    grid_dir: StrPath | None = None,
    size: int = BATCH,
) -> Iterator[gpd.GeoDataFrame]:
    """:func:`read_footprints` in batches of at most ``size`` features, never the whole source
    in memory (a national map): each batch is the buildings table of its features, by the same
    rules. Ids are unique within a batch; across batches the caller checks them (e.g.
    :func:`gnss_citygml.tiling.buildings.partition_buildings`). An empty source is an error, a
    batch left empty (MasterMap features that are not buildings) is skipped."""
    source = Source.of(path, layer)
    rows = 0  # the features before a batch: where its rows are in the source, for messages
    for frame in source.batches(size):
        frame = _buildings_only(frame, source)
        if not frame.empty:
            yield _prepared(frame, source, id_field, grid_dir, first_row=rows)
            rows += len(frame)
    if rows == 0:
        _prepared(source.empty(), source, id_field, grid_dir)  # (says what is missing)


def _buildings_only(frame: gpd.GeoDataFrame, source: Source) -> gpd.GeoDataFrame:
    """The features of a MasterMap source whose descriptiveGroup has "Building" (the others:
    every feature)."""
    if source.kind == "mastermap" and "descriptiveGroup" in frame.columns:
        return frame[_has_building_group(frame["descriptiveGroup"])]
    return frame


def _prepared(frame, source: Source, id_field, grid_dir, first_row: int = 0) -> gpd.GeoDataFrame:
    """The buildings table of the (building) features ``frame`` of ``source`` (see
    :func:`read_footprints`), the first of them the ``first_row``-th of the source's."""
    where = source.named
    if source.kind == "mastermap" and id_field is None:
        id_field = next((c for c in ("fid", "gml_id") if c in frame.columns), None)
    if frame.empty:
        what = "no building features" if source.kind == "mastermap" else "the layer has no features"
        raise InputError(what, where=where, fix="give a layer with building footprints")
    frame, field = _with_ids(frame, id_field, where, first_row)
    check_polygonal(frame.geometry.to_numpy(), frame["id"].to_numpy(), where)
    frame = _repaired(_to_bng(frame, where, grid_dir), where)
    return with_id_field(frame, _output_name(field, source.kind == "mastermap"))


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
    frame: gpd.GeoDataFrame, id_field: str | None, where: str, first_row: int = 0
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
    text = _id_text(ids, name, where, first_row)
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


def _id_text(ids: pd.Series, name: str, where: str, first_row: int = 0) -> pd.Series:
    """The ids as text; an :class:`InputError` naming the features (row of the source, from 0)
    whose id is missing, blank or holds a NUL (:func:`~gnss_citygml.files.ids.missing_ids`)."""
    missing = missing_ids(ids)
    if missing.any():
        rows = first_row + np.flatnonzero(missing)
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
