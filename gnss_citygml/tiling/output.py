"""The heights of a run in tiles written tile by tile, by the workers, with a tile index.

A national run's heights do not fit one machine (47 M buildings are about 10 GB), so a run
in tiles may write them into a folder instead of gathering them: the worker that fitted a
tile joins its heights onto the tile's footprints and writes them as GeoParquet, in the hive
layout that GeoPandas, Dask, pyarrow, DuckDB and GDAL read whole or tile by tile::

    FOLDER/tiles.gpkg                               the tile index (layer "tiles")
    FOLDER/heights/tile=TQ2982/part-0.parquet       the heights layer's rows of tile TQ2982

``geopandas.read_parquet("FOLDER/heights")`` reads every tile, with a ``tile`` column. The
tile index has one square per tile that owns a building: its name, ``buildings``,
``with_height`` (converged), ``failed`` (why its cast failed, empty if it did not) and
``location`` (its file, relative to the folder: a GDAL tile index) with the file's ``sha256``.
The folder appears whole or not at all (:func:`~gnss_citygml.files.folders.atomic_folder`); on a
cluster of several machines it must be on a file system every worker writes to, as a partition
folder must be one every worker reads. It is read back only as its index lists it
(:func:`run_folder_heights`): a tile's folder or file missing, added, cut short or replaced is
refused naming the tile, never read as fewer or other buildings.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NoReturn

import geopandas as gpd
import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import shapely

from ..errors import InputError, user_text
from ..files.folders import MANIFEST, check_new_folder, written_files
from ..files.names import check_utf8_name
from ..files.paths import StrPath, file_digest
from ..files.tables import write_layer
from ..model.estimate import no_heights
from ..settings import Tiling
from ..stages import join_heights
from .buildings import read_building_files
from .grid import tile_index

__all__ = [
    "HEIGHTS",
    "INDEX",
    "TileFolder",
    "check_tile_folder",
    "run_folder_heights",
    "tile_index_frame",
    "write_index",
]

#: The tile index, in the folder (a GeoPackage with the layer ``tiles``).
INDEX = "tiles.gpkg"
#: The folder of the tiles' heights, in the folder.
HEIGHTS = "heights"
#: The file of a tile's heights, in its folder ``HEIGHTS/tile=NAME``.
_PART = "part-0.parquet"
#: How to mend a folder of tiles that is not as its tile index lists it.
_AGAIN = "restore the folder as the run wrote it, or estimate again into a new one"
_STRAY = f"remove it if it is a stray copy, or {_AGAIN}"


def check_tile_folder(folder: StrPath, tiling: Tiling, *, overwrite: bool) -> Path:
    """Refuse, before any work, a folder of tiles that cannot be written: in a run that is not
    in tiles (``tiling``), or a file, a folder that is not empty without ``overwrite``, one that is
    not a folder of tiles (no :data:`INDEX`: it is never replaced), a missing parent
    (:func:`~gnss_citygml.files.folders.check_new_folder`). Returns it as an absolute path."""
    if not tiling.on:
        raise InputError(
            "an output without a suffix is a folder of tiles, which only a run in tiles writes",
            where=str(folder),
            fix="give --scheduler local (or a scheduler's address), or name the output .gpkg, "
            ".fgb or .parquet",
        )
    check_utf8_name(folder, "output folder")  # (GDAL and Arrow write its files)
    return check_new_folder(folder, overwrite=overwrite, mark=INDEX)


@dataclass(frozen=True)
class TileFolder:
    """Where, and how, each worker writes its tiles' heights: the folder being written
    (``path``), the estimator's ``method`` (for buildings without a fit), the name of the
    footprints' id field (``id_name``) and the tile size (m)."""

    path: str
    method: str
    id_name: str
    size: float

    def write(
        self,
        table: pd.DataFrame | None,
        buildings: gpd.GeoDataFrame | list[Path],
        name: str,
        failed: str,
    ) -> dict[str, Any]:
        """Write tile ``name``'s heights (its rows of the heights table, ``table``; None for a
        tile that took no part in the run: no ray reaches its buildings) joined onto
        its own ``buildings`` (or the partition's files that hold them, read here, by the
        worker); return its row of the index. ``failed`` is why its cast failed (empty if it
        did not). Run again (Dask's retry, or a dead worker's task recomputed), it replaces its
        file with the same one."""
        if isinstance(buildings, list):
            buildings = read_building_files(buildings)
        if table is None:
            table = no_heights(np.empty(0, dtype=object), self.method, "")
        heights = join_heights(buildings, table, self.method, self.id_name)
        location = Path(HEIGHTS) / f"tile={name}" / _PART
        target = Path(self.path) / location
        try:
            target.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise InputError(
                f"cannot write tile {name} ({exc.strerror})",
                where=str(target.parent),
                fix="give an output folder every worker can write to, with free space",
            ) from None
        write_layer(heights, target, "heights")
        digest = file_digest(target)[1]
        point = shapely.point_on_surface(buildings.geometry.to_numpy()[:1])
        ix, iy = tile_index(shapely.get_x(point), shapely.get_y(point), self.size)
        return {
            "tile": name,
            "buildings": len(heights),
            "with_height": int(heights["converged"].sum()),
            "failed": failed,
            "location": location.as_posix(),
            "sha256": digest,
            "ix": int(ix[0]),
            "iy": int(iy[0]),
        }


def tile_index_frame(rows: list[dict[str, Any]], size: float) -> gpd.GeoDataFrame:
    """The tile index of the rows :meth:`TileFolder.write` returned: one square per tile, in
    name order."""
    table = pd.DataFrame(
        rows,
        columns=["tile", "buildings", "with_height", "failed", "location", "sha256", "ix", "iy"],
    ).sort_values("tile", ignore_index=True)
    x0 = table.pop("ix").to_numpy(dtype=float) * size
    y0 = table.pop("iy").to_numpy(dtype=float) * size
    squares = shapely.box(x0, y0, x0 + size, y0 + size)
    return gpd.GeoDataFrame(table, geometry=np.asarray(squares), crs="EPSG:27700")


def write_index(index: gpd.GeoDataFrame, folder: Path) -> None:
    """Write the tile index into the folder being written."""
    write_layer(index, folder / INDEX, "tiles")


def run_folder_heights(path: StrPath) -> Path | None:
    """Where to read the heights if ``path`` is a folder of tiles (:data:`INDEX` beside
    :data:`HEIGHTS`), its ``heights`` folder or one tile's folder in that, once checked
    against the tile index: every tile folder and file it lists is there, nothing else, each
    file with its rows and SHA-256 (:func:`_check_tile`). None: it is none of these."""
    path = Path(path)
    if _holds_tiles(path):
        folder, only = path, None
    elif path.name == HEIGHTS and _holds_tiles(path.parent):
        folder, only = path.parent, None
    elif path.parent.name == HEIGHTS and _holds_tiles(path.parent.parent):
        folder, only = path.parent.parent, path.name
    else:
        return None
    listed = _read_tile_index(folder)
    for entry in sorted(_tiles_written(folder) - listed.keys()):
        _refuse(
            folder, entry, f"{HEIGHTS}/{entry}, which the run wrote ({MANIFEST}), is not in {INDEX}"
        )
    found = {e for e in _names(folder / HEIGHTS) if only is None or e == only}
    for entry in sorted(found - listed.keys() | ({only} - listed.keys() if only else set())):
        _refuse(folder, entry, f"{HEIGHTS}/{user_text(entry)} is not in {INDEX}", _STRAY)
    for entry in sorted(listed if only is None else [only]):
        if entry not in found:
            _refuse(folder, entry, f"{HEIGHTS}/{entry} of {INDEX} is missing")
        _check_tile(folder, entry, listed[entry])
    return folder / HEIGHTS if only is None else path


def _tiles_written(folder: Path) -> set[str]:
    """The tile folders (``tile=NAME``) the run wrote, as the folder's list of what it wrote
    says (none if it has no list): a tile removed from the folder and its index alike is
    still named there."""
    names = written_files(folder) or set()
    prefix = f"{HEIGHTS}/"
    folders = (n for n in names if n.startswith(prefix) and n.endswith("/"))
    return {n[len(prefix) : -1] for n in folders if n.count("/") == 2}


def _holds_tiles(folder: Path) -> bool:
    return (folder / INDEX).is_file() and (folder / HEIGHTS).is_dir()


def _read_tile_index(folder: Path) -> dict[str, dict[str, Any]]:
    """The tile index's rows by tile folder name (``tile=NAME``)."""
    import pyogrio

    try:
        table = pyogrio.read_dataframe(folder / INDEX, layer="tiles", read_geometry=False)
        return {f"tile={row['tile']}": row for row in table.to_dict("records")}
    except Exception as exc:  # (GDAL's errors: no layer, no column, not a GeoPackage)
        raise InputError(
            f"damaged folder of tiles: cannot read its tile index {INDEX} ({type(exc).__name__})",
            where=str(folder / INDEX),
            fix=_AGAIN,
        ) from None


def _check_tile(folder: Path, entry: str, row: dict[str, Any]) -> None:
    """Refuse a tile whose folder does not hold exactly its file as the run wrote it: the rows
    the index counts and (an index that has them) its SHA-256."""
    top = folder / HEIGHTS / entry
    for name in sorted(_names(top) - {_PART}):
        _refuse(folder, entry, f"{HEIGHTS}/{entry}/{user_text(name)} is not in {INDEX}", _STRAY)
    file = top / _PART
    if not file.is_file():
        _refuse(folder, entry, f"{HEIGHTS}/{entry}/{_PART} of {INDEX} is missing")
    try:
        rows = pq.read_metadata(file).num_rows
    except (OSError, pa.ArrowException):
        _refuse(
            folder, entry, f"{HEIGHTS}/{entry}/{_PART} is not the whole Parquet file {INDEX} lists"
        )
    if rows != row["buildings"]:
        _refuse(folder, entry, f"{HEIGHTS}/{entry}/{_PART} holds {rows} buildings, not the "
                f"{row['buildings']} of {INDEX}")  # fmt: skip
    if row.get("sha256") is not None and file_digest(file)[1] != row["sha256"]:
        _refuse(folder, entry, f"{HEIGHTS}/{entry}/{_PART} is not the file the run wrote (its "
                f"SHA-256 differs from {INDEX}'s)")  # fmt: skip


def _names(folder: Path) -> set[str]:
    """The names in ``folder`` (none if it is missing)."""
    try:
        return {entry.name for entry in os.scandir(folder)}
    except FileNotFoundError:
        return set()


def _refuse(folder: Path, entry: str, what: str, fix: str = _AGAIN) -> NoReturn:
    """Refuse a folder of tiles that is not as its run wrote it, naming the tile."""
    raise InputError(
        f"damaged folder of tiles: {what}", where=str(folder / HEIGHTS / entry), fix=fix
    )
