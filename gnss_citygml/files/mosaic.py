"""A folder of raster tiles as one raster: the XML of a GDAL virtual raster (VRT) that mosaics
them, which rasterio opens as it opens a file.

A national DEM ships as tiles (OS Terrain 5: a GeoTIFF or ASCII grid per 5 km square), and a
run in tiles needs only the ground where its buildings and receivers are. GDAL reads a VRT's
sources only where a window touches them, so the mosaic costs one look at each tile's header
when it is made, and then only the reads that land on a tile. The tiles must share one grid
(cell size, alignment, CRS), one data type, nodata value, scale, offset and unit: a mosaic of
different grids would have to be resampled, which :mod:`gnss_citygml.terrain` never does. No
two tiles may cover the same cell: GDAL would take the later one's heights there, and which is
later would depend on the files' names.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from xml.sax.saxutils import escape

import numpy as np
from affine import Affine

from ..errors import InputError, user_text
from .names import native_name, os_text

__all__ = ["MOSAIC_FOLDER", "SUFFIXES", "TileGrid", "mosaic_vrt", "raster_tiles"]

#: The suffixes of the raster files a folder of DEM tiles is read from (GeoTIFF, ESRI ASCII
#: grid: what OS Terrain 5 and 50 ship).
SUFFIXES = (".tif", ".tiff", ".asc")

#: The key of the mosaic's metadata that names its folder (for messages: the dataset's own
#: name is the VRT's XML).
MOSAIC_FOLDER = "GNSS_CITYGML_FOLDER"

#: How far (in cells) a tile's origin may be from the mosaic's grid and still be on it.
_ALIGNED = 1e-6


@dataclass(frozen=True)
class TileGrid:
    """One tile's file and the grid of the band read from it (from its header)."""

    path: str
    transform: Affine
    width: int
    height: int
    dtype: str
    nodata: float | None
    scale: float
    offset: float
    unit: str
    crs_wkt: str | None


def raster_tiles(folder: Path) -> list[Path]:
    """The raster files of a folder of tiles (and its sub-folders), in name order; hidden files
    (``.x``, ``._x``) left out, and an :class:`InputError` if there is none."""
    files = sorted(
        path
        for path in folder.rglob("*")
        if path.suffix.lower() in SUFFIXES
        and path.is_file()
        and not any(part.startswith(".") for part in path.relative_to(folder).parts)
    )
    if not files:
        raise InputError(
            f"the DEM folder holds no raster tile ({', '.join(SUFFIXES)})",
            where=str(folder),
            fix="give the folder of the DEM's tiles (e.g. OS Terrain 5's GeoTIFFs), or one file",
        )
    return files


def mosaic_vrt(tiles: list[TileGrid], folder: str, band: int) -> str:
    """The VRT XML of one band mosaicking the band ``band`` of ``tiles``, or an
    :class:`InputError` naming the first tile that is not on the first one's grid or does not
    store its heights as it does, or two tiles that overlap."""
    first = tiles[0]
    a, e = first.transform.a, first.transform.e
    for tile in tiles[1:]:
        _check_same(first, tile, folder)
    x0 = min(t.transform.c for t in tiles)
    y0 = max(t.transform.f for t in tiles)
    x1 = max(t.transform.c + t.width * a for t in tiles)
    y1 = min(t.transform.f + t.height * e for t in tiles)
    width, height = round((x1 - x0) / a), round((y1 - y0) / e)
    _check_no_overlap(tiles, x0, y0, folder)
    nodata = first.nodata if first.nodata is not None else _no_value(first.dtype)
    sources = "".join(_source(tile, x0, y0, band) for tile in tiles)
    srs = "" if first.crs_wkt is None else f"<SRS>{escape(first.crs_wkt)}</SRS>"
    return (
        f'<VRTDataset rasterXSize="{width}" rasterYSize="{height}">{srs}'
        f"<GeoTransform>{x0!r}, {a!r}, 0, {y0!r}, 0, {e!r}</GeoTransform>"
        f'<Metadata><MDI key="{MOSAIC_FOLDER}">{escape(os_text(folder))}</MDI></Metadata>'
        f'<VRTRasterBand dataType="{_GDAL_TYPES[first.dtype]}" band="1">'
        f"<NoDataValue>{nodata!r}</NoDataValue><UnitType>{escape(first.unit)}</UnitType>"
        f"<Offset>{first.offset!r}</Offset><Scale>{first.scale!r}</Scale>"
        f"{sources}</VRTRasterBand></VRTDataset>"
    )


def _check_same(first: TileGrid, tile: TileGrid, folder: str) -> None:
    """Refuse a tile whose grid or stored values differ from the first tile's."""
    where = f"{folder}: {_name(tile.path, folder)} against {_name(first.path, folder)}"
    a, e = first.transform.a, first.transform.e
    steps = ((tile.transform.c - first.transform.c) / a, (tile.transform.f - first.transform.f) / e)
    problems = [
        ((tile.transform.a, tile.transform.e) != (a, e), "cell size"),
        (tile.transform.b or tile.transform.d, "a rotated grid"),
        (any(abs(s - round(s)) > _ALIGNED for s in steps), "grid alignment"),
        (tile.crs_wkt != first.crs_wkt, "CRS"),
        (tile.dtype != first.dtype, "data type"),
        (not _same_value(tile.nodata, first.nodata), "nodata value"),
        ((tile.scale, tile.offset, tile.unit) != (first.scale, first.offset, first.unit), "units"),
    ]
    for differs, what in problems:
        if differs:
            raise InputError(
                f"the DEM's tiles differ in {what}: a mosaic would need resampling",
                where=where,
                fix="give tiles of one grid (as OS Terrain 5 ships them), or mosaic and "
                "resample them first (gdalbuildvrt, then gdalwarp to one GeoTIFF)",
            )


def _cells(tile: TileGrid, x0: float, y0: float) -> tuple[int, int, int, int]:
    """The tile's first column and row on the mosaic's grid (origin ``x0``, ``y0``), and its
    end column and row."""
    col = round((tile.transform.c - x0) / tile.transform.a)
    row = round((tile.transform.f - y0) / tile.transform.e)
    return col, row, col + tile.width, row + tile.height


def _check_no_overlap(tiles: list[TileGrid], x0: float, y0: float, folder: str) -> None:
    """Refuse two tiles that cover the same cells (an older copy of a tile beside the new
    one, or tiles cut with a margin): which one's heights a cell gets would depend on the
    files' names. Tiles that share an edge or a corner do not overlap."""
    boxes = np.array([_cells(tile, x0, y0) for tile in tiles])
    for i in range(len(tiles) - 1):
        c0, r0, c1, r1 = boxes[i]
        rest = boxes[i + 1 :]
        cols = np.minimum(rest[:, 2], c1) - np.maximum(rest[:, 0], c0)
        rows = np.minimum(rest[:, 3], r1) - np.maximum(rest[:, 1], r0)
        over = np.flatnonzero((cols > 0) & (rows > 0))
        if over.size:
            j = over[0]
            first, other = (_name(tiles[k].path, folder) for k in (i, i + 1 + j))
            raise InputError(
                f"the DEM's tiles overlap: {cols[j]} x {rows[j]} cells are in both, and "
                "which one's heights they would get would depend on the files' names",
                where=f"{folder}: {first} and {other}",
                fix="remove one of them from the folder (e.g. an older copy of the same "
                "tile), or cut them so that each cell is in one tile (gdal_translate -srcwin)",
            )


def _name(path: str, folder: str) -> str:
    """A tile's file as a message names it: its path in the folder of tiles."""
    return user_text(Path(path).relative_to(folder).as_posix(), 120)


def _same_value(x: float | None, y: float | None) -> bool:
    """Whether two nodata values are the same (None: none; NaN is NaN)."""
    if x is None or y is None:
        return x is y
    return x == y or (math.isnan(x) and math.isnan(y))


def _source(tile: TileGrid, x0: float, y0: float, band: int) -> str:
    """A tile's band as the VRT's source, placed on the mosaic's grid."""
    col, row = _cells(tile, x0, y0)[:2]
    size = f'xSize="{tile.width}" ySize="{tile.height}"'
    nodata = "" if tile.nodata is None else f"<NODATA>{tile.nodata!r}</NODATA>"
    return (
        f'<ComplexSource><SourceFilename relativeToVRT="0">{escape(native_name(tile.path))}'
        f"</SourceFilename><SourceBand>{band}</SourceBand>"
        f'<SrcRect xOff="0" yOff="0" {size}/><DstRect xOff="{col}" yOff="{row}" {size}/>'
        f"{nodata}</ComplexSource>"
    )


def _no_value(dtype: str) -> float:
    """The mosaic's nodata where its tiles have none (the cells between tiles): NaN for
    floats, the type's lowest value for integers (what GDAL's tools use)."""
    if dtype.startswith("float"):
        return math.nan
    return float(np.iinfo(dtype).min)


#: GDAL's names of the data types rasterio reports.
_GDAL_TYPES = {
    "uint8": "Byte",
    "int8": "Int8",
    "uint16": "UInt16",
    "int16": "Int16",
    "uint32": "UInt32",
    "int32": "Int32",
    "float32": "Float32",
    "float64": "Float64",
}
