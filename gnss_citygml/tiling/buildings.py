"""The footprints of a partition: each building under the tile of its representative point,
with its ground from the DEM, so that a run in tiles needs neither the footprint file nor the
DEM (``gnss-citygml partition ... --footprints FILE``)::

    FOLDER/buildings/tile=TQ2982/part-00000.parquet    buildings of batch 0 in TQ2982

The footprints are read in batches (:func:`~gnss_citygml.footprints.footprint_batches`), never
whole, each batch grounded on the DEM (which reads only the windows under it) and written out
before the next is read; the ids are checked unique across the whole partition one bucket of
ids at a time (:class:`_Ids`), a repeated id named with both its tiles. The index
(``partition.json``, :mod:`gnss_citygml.tiling.partition`) lists every file with its rows, size
and SHA-256 under ``"buildings"``, with the outputs' name of the id field.
"""

from __future__ import annotations

import shutil
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import geopandas as gpd
import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import shapely

from ..errors import InputError, user_text
from ..files.ids import id_field, with_id_field
from ..files.paths import StrPath, file_digest
from ..footprints import BATCH, footprint_batches, read_footprints
from ..terrain import Dem, building_ground
from .grid import check_tile_count, tile_index, tile_names

__all__ = [
    "BUILDINGS",
    "Footprints",
    "building_files",
    "files_shared_id",
    "partition_buildings",
    "read_building_files",
    "read_building_ids",
    "read_buildings",
    "refuse_shared",
    "shared_id",
]

#: The folder of the buildings' partitions, in the partition's folder.
BUILDINGS = "buildings"


@dataclass(frozen=True)
class Footprints:
    """A footprint source to partition: a path :func:`~gnss_citygml.footprints.read_footprints`
    reads, its layer and its id field (None: as it decides), read ``batch`` features at a time."""

    path: StrPath
    layer: str | None = None
    id_field: str | None = None
    batch: int = BATCH


def partition_buildings(
    footprints: Footprints,
    work: Path,
    dem: Dem | None,
    tile_size: float,
    grid_dir: StrPath | None = None,
    dem_crs: Any = None,
    progress: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """Write the ``footprints`` under ``work/buildings``, each building under the tile of its
    representative point with its ``ground`` (the DEM's median under it, or the footprints' own
    ``ground`` without a DEM); returns the index's ``"buildings"`` entry (the outputs' name of
    the id field, the rows, the tiles and their files). ``progress`` is told each batch."""
    say = progress or (lambda text: None)
    tiles: dict[str, dict[str, Any]] = {}
    ids = _Ids(work / "_ids")
    rows, name = 0, "id"
    batches = footprint_batches(
        footprints.path,
        layer=footprints.layer,
        id_field=footprints.id_field,
        grid_dir=grid_dir,
        size=footprints.batch,
    )
    for k, batch in enumerate(batches):
        say(f"{Path(footprints.path).name}: buildings {rows + 1}-{rows + len(batch)}")
        if "tile" in batch.columns:  # pyarrow would read it back as the folders' key
            raise InputError(
                "the footprints have a column 'tile', the name of the partition's folders",
                where=str(footprints.path),
                fix="rename or drop that column (a run in tiles names each building's tile again)",
            )
        name = id_field(batch)
        if dem is not None:
            batch = building_ground(batch, dem, assume_crs=dem_crs)
        elif "ground" not in batch.columns:
            raise InputError("the buildings' ground needs a DEM", fix="give --dem")
        points = shapely.point_on_surface(batch.geometry.to_numpy())
        ix, iy = tile_index(shapely.get_x(points), shapely.get_y(points), tile_size)
        names = tile_names(ix, iy, tile_size)
        for tile, part in batch.groupby(names, sort=True):
            _write_part(work, str(tile), part, k, tiles, (ix, iy))
        check_tile_count(len(tiles), tile_size)
        ids.add(batch["id"], names)
        rows += len(batch)
    ids.check(str(footprints.path))
    return {"id_field": name, "rows": rows, "tiles": dict(sorted(tiles.items()))}


def _write_part(work: Path, tile: str, part: pd.DataFrame, k: int, tiles, at) -> None:
    """One batch's buildings of one tile, as GeoParquet, recorded in ``tiles``."""
    folder = work / BUILDINGS / f"tile={tile}"
    folder.mkdir(parents=True, exist_ok=True)
    file = folder / f"part-{k:05d}.parquet"
    part.reset_index(drop=True).to_parquet(file, index=False)
    first = part.index[0]
    entry = tiles.setdefault(
        tile, {"ix": int(at[0][first]), "iy": int(at[1][first]), "rows": 0, "files": {}}
    )
    entry["rows"] += len(part)
    x0, y0, x1, y1 = part.geometry.total_bounds.tolist()  # the tile's extent: its plan
    was = entry.get("bounds", [x0, y0, x1, y1])
    entry["bounds"] = [min(was[0], x0), min(was[1], y0), max(was[2], x1), max(was[3], y1)]
    size, digest = file_digest(file)
    entry["files"][file.name] = {"rows": len(part), "bytes": size, "sha256": digest}


class _Ids:
    """Every building's id with its tile, written in buckets by the id's hash: a repeated id
    is in one bucket, found reading one bucket at a time, never every id at once."""

    BUCKETS = 32

    def __init__(self, folder: Path):
        self.folder = folder
        self.writers: dict[int, pq.ParquetWriter] = {}

    def add(self, ids: pd.Series, tiles: np.ndarray) -> None:
        frame = pd.DataFrame({"id": ids.to_numpy(dtype=object), "tile": tiles})
        bucket = pd.util.hash_pandas_object(frame["id"], index=False).to_numpy() % self.BUCKETS
        self.folder.mkdir(parents=True, exist_ok=True)
        for b in np.unique(bucket).tolist():
            table = pa.Table.from_pandas(frame[bucket == b], preserve_index=False)
            if b not in self.writers:
                self.writers[b] = pq.ParquetWriter(self.folder / f"{b:02d}.parquet", table.schema)
            self.writers[b].write_table(table)

    def check(self, where: str) -> None:
        """Refuse an id held by two buildings (in two batches: one batch's own repeats are
        refused when it is read), naming it with both tiles; then remove the buckets."""
        for writer in self.writers.values():
            writer.close()
        try:
            for b in sorted(self.writers):
                frame = pd.read_parquet(self.folder / f"{b:02d}.parquet")
                refuse_shared(
                    shared_id(frame["id"], frame["tile"]),
                    "footprints",
                    where,
                    "give each footprint its own id, or choose another --id-field",
                )
        finally:
            shutil.rmtree(self.folder, ignore_errors=True)


def shared_id(ids: Any, tiles: Any) -> tuple[int, str, str, str] | None:
    """How many ``ids`` are held by two buildings, with the first of them and its two
    ``tiles``; None if every id is unique."""
    frame = pd.DataFrame({"id": np.asarray(ids, dtype=object), "tile": np.asarray(tiles)})
    repeated = frame[frame["id"].duplicated(keep=False)]
    if repeated.empty:
        return None
    first = repeated[repeated["id"] == repeated["id"].iloc[0]]
    return (
        int(repeated["id"].nunique()),
        str(first["id"].iloc[0]),
        str(first["tile"].iloc[0]),
        str(first["tile"].iloc[1]),
    )


def refuse_shared(found: tuple[int, str, str, str] | None, held: str, where: str, fix: str) -> None:
    """Refuse ids :func:`shared_id` found held by two ``held`` (footprints, buildings of a
    partition), naming the first with both its tiles."""
    if found is not None:
        count, building, a, b = found
        raise InputError(
            f"{count} building id(s) held by two {held}, e.g. {user_text(building)} in tiles "
            f"{a} and {b}",
            where=where,
            fix=fix,
        )


def files_shared_id(files: list[Path]) -> tuple[int, str, str, str] | None:
    """:func:`shared_id` of the buildings in some of a partition's ``files`` (their tiles
    named by their folders): run by a tile's worker on its own files and its halo's."""
    if not files:
        return None
    ids = [read_building_ids([f]) for f in files]
    tiles = [
        np.full(len(i), f.parent.name.removeprefix("tile="))
        for i, f in zip(ids, files, strict=True)
    ]
    return shared_id(np.concatenate(ids), np.concatenate(tiles))


def building_files(folder: StrPath, index: dict[str, Any]) -> dict[str, list[Path]]:
    """The GeoParquet files of each tile of the buildings a partition holds, in file order."""
    top = Path(folder) / BUILDINGS
    return {
        name: [top / f"tile={name}" / file for file in sorted(spec["files"])]
        for name, spec in index[BUILDINGS]["tiles"].items()
    }


def read_building_files(files: list[Path], columns: list[str] | None = None) -> gpd.GeoDataFrame:
    """The buildings of some of a partition's files, in file order (their ``columns``, the
    geometry among them)."""
    frames = [gpd.read_parquet(f, columns=columns) for f in files]
    return gpd.GeoDataFrame(pd.concat(frames, ignore_index=True), crs=frames[0].crs)


def read_building_ids(files: list[Path]) -> np.ndarray:
    """The ids of the buildings of some of a partition's files, in file order."""
    ids = [pd.read_parquet(f, columns=["id"])["id"] for f in files]
    return pd.concat(ids, ignore_index=True).to_numpy(dtype=object)


def read_buildings(folder: StrPath, entry: dict[str, Any]) -> gpd.GeoDataFrame:
    """All the buildings a partition holds (its index's ``"buildings"`` entry), with their
    ``ground``, the id named as the footprints' was: the buildings table a run in one
    process, or its client, starts from."""
    frame = read_footprints(Path(folder) / BUILDINGS, id_field="id").drop(columns="tile")
    return with_id_field(frame, entry["id_field"])
