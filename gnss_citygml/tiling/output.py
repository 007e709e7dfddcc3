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
``location`` (its file, relative to the folder: a GDAL tile index). The folder appears
whole or not at all (:func:`~gnss_citygml.files.paths.atomic_folder`); on a cluster of several
machines it must be on a file system every worker writes to, as a partition folder must be
one every worker reads.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import geopandas as gpd
import numpy as np
import pandas as pd
import shapely

from ..errors import InputError
from ..files.names import check_utf8_name
from ..files.paths import StrPath, check_new_folder
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
    "tile_index_frame",
    "write_index",
]

#: The tile index, in the folder (a GeoPackage with the layer ``tiles``).
INDEX = "tiles.gpkg"
#: The folder of the tiles' heights, in the folder.
HEIGHTS = "heights"


def check_tile_folder(folder: StrPath, tiling: Tiling, *, overwrite: bool) -> Path:
    """Refuse, before any work, a folder of tiles that cannot be written: in a run that is not
    in tiles (``tiling``), or a file, an existing folder without ``overwrite``, one that is
    not a folder of tiles (no :data:`INDEX`: it is never replaced), a missing parent
    (:func:`~gnss_citygml.files.paths.check_new_folder`). Returns it as an absolute path."""
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
        location = Path(HEIGHTS) / f"tile={name}" / "part-0.parquet"
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
        point = shapely.point_on_surface(buildings.geometry.to_numpy()[:1])
        ix, iy = tile_index(shapely.get_x(point), shapely.get_y(point), self.size)
        return {
            "tile": name,
            "buildings": len(heights),
            "with_height": int(heights["converged"].sum()),
            "failed": failed,
            "location": location.as_posix(),
            "ix": int(ix[0]),
            "iy": int(iy[0]),
        }


def tile_index_frame(rows: list[dict[str, Any]], size: float) -> gpd.GeoDataFrame:
    """The tile index of the rows :meth:`TileFolder.write` returned: one square per tile, in
    name order."""
    table = pd.DataFrame(
        rows, columns=["tile", "buildings", "with_height", "failed", "location", "ix", "iy"]
    ).sort_values("tile", ignore_index=True)
    x0 = table.pop("ix").to_numpy(dtype=float) * size
    y0 = table.pop("iy").to_numpy(dtype=float) * size
    squares = shapely.box(x0, y0, x0 + size, y0 + size)
    return gpd.GeoDataFrame(table, geometry=np.asarray(squares), crs="EPSG:27700")


def write_index(index: gpd.GeoDataFrame, folder: Path) -> None:
    """Write the tile index into the folder being written."""
    write_layer(index, folder / INDEX, "tiles")
