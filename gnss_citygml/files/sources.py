"""Where footprints are read from: a GDAL source (GeoPackage, Shapefile, GeoJSON, OS MasterMap
Topography GML, ...) or GeoParquet (a file or a hive folder), checked before GDAL or pyarrow
sees it, read whole or streamed in batches (:class:`Source`). The rules that make the features
the *buildings* table are :mod:`gnss_citygml.footprints`'.

- A GML file is sniffed from its first 64 kB (MasterMap or other GML) and checked to be
  well-formed XML first: GDAL reads no feature at all from a file cut short, without an error;
  it is read with ``WRITE_GFS=NO``, so no ``.gfs`` sidecar is written next to it, and GDAL's
  VFK driver writes its database into a temporary folder, never beside the input.
- GeoParquet is checked from its files' footers (``geo`` metadata, encodings) before GeoPandas
  reads it: its own errors on metadata it does not expect are not one line.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
import xml.parsers.expat
import zlib
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import geopandas as gpd
import numpy as np
import pandas as pd
import pyogrio
import shapely

from ..errors import InputError, first_line, listing, user_text
from .names import native_name
from .paths import StrPath, gunzipped, input_file
from .tables import check_parquet_metadata, check_text
from .userjson import parse_json

__all__ = ["Source"]

_BNG = "EPSG:27700"
_MASTERMAP_NAMESPACES = (
    b"ordnancesurvey.co.uk/xml/namespaces/osgb",
    b"namespaces.os.uk/mastermap/topography",
)
#: What makes GDAL read an XML file (starting with "<", after a UTF-8 byte order mark) with
#: its GML driver, which writes a .gfs sidecar unless told not to (ogrgmldatasource.cpp).
_GML_MARKERS = (b"opengis.net/gml", b"<csw:GetRecordsResponse")


@dataclass(frozen=True)
class Source:
    """A footprint source, checked and sniffed: what to read, and how."""

    path: StrPath
    where: str
    kind: str | None
    layer: str | None
    geoparquet: bool

    @classmethod
    def of(cls, path: StrPath, layer: str | None) -> Source:
        where = os.fspath(path)
        local = not (where.startswith("/vsi") or "://" in where)
        if local and not Path(where).is_dir():  # a folder may hold a Shapefile or a FileGDB
            input_file(where, "footprint file")
        kind = _sniff_gml(Path(where)) if local else None
        if kind:  # GDAL reads no feature at all from a GML file that is not well-formed
            _check_xml(Path(where))
        if local and _is_geoparquet(Path(where)):
            if layer is not None:
                raise InputError(
                    f"GeoParquet has no layers to choose (--layer {layer})",
                    where=where,
                    fix="leave out --layer",
                )
            return cls(path, where, kind, None, True)
        with _nothing_written_beside(where):
            if layer is None:
                layer = "TopographicArea" if kind == "mastermap" else _polygon_layer(where, kind)
        return cls(path, where, kind, layer, False)

    @property
    def named(self) -> str:
        """The source for messages, with its layer."""
        return self.where if self.layer is None else f"{self.where}, layer {self.layer}"

    @property
    def options(self) -> dict[str, str]:
        """GDAL's open options: no ``.gfs`` sidecar beside a GML file."""
        return {"WRITE_GFS": "NO"} if self.kind else {}

    def read(self) -> gpd.GeoDataFrame:
        """All the source's features, indexed by their feature ids (GeoParquet: by row)."""
        if self.geoparquet:
            return _read_geoparquet(Path(self.where))
        with _nothing_written_beside(self.where):
            return _read_layer(self.path, self.layer, self.named, self.options)

    def batches(self, size: int) -> Iterator[gpd.GeoDataFrame]:
        """The source's features, ``size`` at a time, each batch indexed by its features' row
        in the source (GDAL's feature ids: the GeoPackage ``fid``, a Shapefile's row)."""
        if self.geoparquet:
            yield from _geoparquet_batches(Path(self.where), size)
            return
        with _nothing_written_beside(self.where):
            yield from _layer_batches(self.path, self.layer, self.named, self.options, size)

    def empty(self) -> gpd.GeoDataFrame:
        """No feature (for the message an empty source gets)."""
        return gpd.GeoDataFrame(geometry=[], crs=_BNG)


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
        layers = pyogrio.list_layers(native_name(path))
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


#: What reading a source may raise for a source it cannot read: unreadable, no such layer, or a
#: geometry GEOS cannot build (an unclosed ring).
_GDAL_ERRORS = (
    pyogrio.errors.DataSourceError,
    pyogrio.errors.DataLayerError,
    shapely.errors.GEOSException,
)


def _read_layer(path, layer: str | None, where: str, options: dict) -> gpd.GeoDataFrame:
    """The layer (None: the first), or an :class:`InputError` for an unreadable source, a
    source without layers or a geometry GEOS cannot build (e.g. an unclosed ring)."""
    try:
        frame = pyogrio.read_dataframe(
            native_name(path),
            layer=0 if layer is None else layer,
            force_2d=True,
            fid_as_index=True,
            **options,
        )
    except _GDAL_ERRORS as exc:
        raise _unreadable(exc, where) from None
    except UnicodeDecodeError:  # (pyogrio decodes GDAL's text itself, without saying where)
        raise _where_not_utf8(path, layer, where, options) from None
    if not isinstance(frame, gpd.GeoDataFrame):  # a layer without geometry (a CSV table)
        frame = gpd.GeoDataFrame(frame, geometry=np.full(len(frame), None), crs=_BNG)
    return frame


def _layer_batches(path, layer, where: str, options: dict, size: int) -> Iterator[gpd.GeoDataFrame]:
    """The layer's features ``size`` at a time, streamed through GDAL's Arrow interface (one
    pass over the source), indexed by their feature ids; errors as :func:`_read_layer`'s."""
    try:
        with pyogrio.open_arrow(
            native_name(path),
            layer=0 if layer is None else layer,
            batch_size=size,
            return_fids=True,
            use_pyarrow=True,
            **options,
        ) as (meta, reader):
            geometry = meta["geometry_name"] or "wkb_geometry"
            for batch in reader:
                _check_utf8(batch, batch.column(meta["fid_column"]).to_numpy(), where)
                table = batch.to_pandas(date_as_object=False)  # dates as read_dataframe's
                fids = table.pop(meta["fid_column"]).to_numpy()
                wkb = table.pop(geometry).to_numpy() if geometry in table else None
                # (a layer without geometry: every feature's is missing, which the rules name)
                geoms = np.full(len(table), None) if wkb is None else shapely.from_wkb(wkb)
                geoms = shapely.force_2d(geoms)
                yield gpd.GeoDataFrame(table.set_axis(fids), geometry=geoms, crs=meta["crs"])
    except _GDAL_ERRORS as exc:
        raise _unreadable(exc, where) from None
    except UnicodeDecodeError:  # (the values are checked above: a field's name)
        raise _not_utf8("a field's name", where) from None


def _where_not_utf8(path, layer: str | None, where: str, options: dict) -> InputError:
    """The error for a source with text that is not UTF-8: the field and the first feature
    that has it, read again as Arrow's bytes (a field's name, if even that cannot be read)."""
    try:
        meta, table = pyogrio.read_arrow(
            native_name(path),
            layer=0 if layer is None else layer,
            read_geometry=False,
            return_fids=True,
            **options,
        )
    except UnicodeDecodeError:
        return _not_utf8("a field's name", where)
    _check_utf8(table, table.column(meta["fid_column"]).to_numpy(), where)
    return _not_utf8("a text of the source", where)


def _check_utf8(table, fids: np.ndarray, where: str) -> None:
    """Refuse a source whose text (an Arrow table or batch of its features, ``fids`` their
    feature ids) is not all UTF-8, naming the field and the first feature that is not: SQLite
    stores any bytes in a GeoPackage's text, which GDAL passes on unchecked."""
    import pyarrow as pa

    for name, column in zip(table.schema.names, table.columns, strict=True):
        if not (pa.types.is_string(column.type) or pa.types.is_large_string(column.type)):
            continue
        try:
            column.validate(full=True)
        except pa.ArrowInvalid:
            row = next((k for k in range(len(column)) if not _decodes(column[k])), 0)
            feature = f"{where}, feature {fids[row]}"
            raise _not_utf8(f"the field '{user_text(name)}'", feature) from None


def _not_utf8(what: str, where: str) -> InputError:
    return InputError(
        f"{what} is not UTF-8 text",
        where=where,
        fix="save the layer's text as UTF-8 (a GeoPackage's text must be)",
    )


def _decodes(value) -> bool:
    """An Arrow string ``value`` is UTF-8 text."""
    try:
        value.as_py()
    except UnicodeDecodeError:
        return False
    return True


def _geoparquet_batches(path: Path, size: int) -> Iterator[gpd.GeoDataFrame]:
    """A GeoParquet file or hive folder ``size`` rows at a time (its partition keys as text),
    indexed by row, checked as :func:`_read_geoparquet` checks it."""
    import pyarrow.dataset as ds

    _check_geoparquet(path)
    data = ds.dataset(native_name(path), format="parquet", partitioning="hive")
    geo = parse_json(data.schema.metadata[b"geo"], allow_nan=True)  # (checked above)
    column = geo["primary_column"]
    if geo["columns"][column].get("encoding") != "WKB":
        yield from _geoarrow_batches(path, size)
        return
    crs = geo["columns"][column].get("crs", "OGC:CRS84")
    start = 0
    for batch in data.to_batches(batch_size=size):
        table = batch.to_pandas()
        table[column] = shapely.from_wkb(table[column].to_numpy())  # in its place
        for name in table.columns:
            if isinstance(table[name].dtype, pd.CategoricalDtype):
                table[name] = table[name].astype(str)
        frame = gpd.GeoDataFrame(table, geometry=column, crs=crs)
        frame.index = np.arange(start, start + len(frame))
        start += len(frame)
        check_text(frame, str(path))
        yield frame


def _parquet_files(path: Path) -> list[Path]:
    """The Parquet files of a file or hive folder, as pyarrow reads a folder: not the hidden
    files (``._x``, ``.x.part-...``)."""
    if not path.is_dir():
        return [path]
    return sorted(
        f
        for f in path.rglob("*.parquet")
        if not any(p.startswith((".", "_")) for p in f.relative_to(path).parts)
    )


def _geoarrow_batches(path: Path, size: int) -> Iterator[gpd.GeoDataFrame]:
    """GeoParquet whose geometry is in one of GeoArrow's native encodings, which only GeoPandas
    decodes here: each file read whole by it (its hive keys as text columns), ``size`` rows at
    a time, indexed by row in the source."""
    start = 0
    for file in _parquet_files(path):
        frame = gpd.read_parquet(native_name(file))
        for part in file.relative_to(path).parent.parts if path.is_dir() else ():
            key, equals, value = part.partition("=")
            if equals:
                frame[key] = value
        frame.index = np.arange(start, start + len(frame))
        start += len(frame)
        check_text(frame, str(file))
        for at in range(0, len(frame), size):
            yield frame.iloc[at : at + size]


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
        frame = gpd.read_parquet(native_name(path))
    except (
        OSError, ValueError, TypeError, KeyError, AttributeError, IndexError,
        shapely.errors.GEOSException,
    ) as exc:  # fmt: skip
        # pyarrow's errors are these too (KeyError, AttributeError, IndexError: pandas
        # metadata of another shape); GEOS's: WKB it cannot parse
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
    for file in _parquet_files(path):
        try:
            schema = pq.read_schema(native_name(file))
        except (OSError, pa.ArrowException) as exc:
            raise InputError(
                f"cannot read the footprints as GeoParquet: not a Parquet file ({first_line(exc)})",
                where=str(file),
                fix="give a GeoParquet file, or a GeoPackage",
            ) from None
        metadata = schema.metadata or {}
        if b"geo" not in metadata:
            raise InputError(
                "the footprints' Parquet has no GeoParquet metadata ('geo'): which column is "
                "the geometry, in which CRS, is not said",
                where=str(file),
                fix=fix,
            )
        geo = check_parquet_metadata(metadata, str(file))[b"geo"]
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
