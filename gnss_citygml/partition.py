"""Observations as Parquet partitioned by tile: the input of a national run in tiles.

No machine of a national run can read every observation. ``gnss-citygml partition`` reads the
observation files one at a time and does the stages that need no footprints: the elevation
mask, the receivers in British National Grid + ODN with grid bearings
(:func:`~gnss_citygml.pipeline.receivers`), which rows share one position error
(:func:`~gnss_citygml.pipeline.recordings`, named once: a recording may span tiles) and each
signal's number over all the files. It writes the rows under the tile that holds the
receiver, in the hive layout that Dask, pyarrow, DuckDB and GDAL read::

    FOLDER/partition.json                       what was done, the tiles and their rows
    FOLDER/receivers/tile=TQ2982/part-00000.parquet   rows of file 0 in TQ2982

A run in tiles (:func:`gnss_citygml.tiled.partitioned_heights`) then has each tile read only
the partitions its rays can come from. A recording must lie in one file (the position-error
groups are found per file); each file's signals are numbered after the previous file's.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from .errors import InputError
from .geodesy import CrsInput
from .observations import read_observations
from .paths import StrPath, atomic_folder, check_not_input
from .pipeline import in_mask, receivers, recordings
from .settings import (
    DEFAULT_TILE_SIZE,
    PositionError,
    Rays,
    ReceiverHeights,
    Tiling,
    check_tile_size,
)
from .terrain import Dem
from .tiles import tile_index, tile_names

__all__ = [
    "INDEX",
    "RECEIVERS",
    "check_partition",
    "partition_observations",
    "partition_run",
    "read_index",
    "read_receivers",
    "tile_files",
]

#: The partition's index, in its folder.
INDEX = "partition.json"
#: The folder of the receivers' partitions, in the partition's folder.
RECEIVERS = "receivers"
#: The index's format version.
VERSION = 1


def partition_observations(
    observations: Sequence[StrPath],
    folder: StrPath,
    dem: Dem | None = None,
    *,
    rays: Rays = Rays(),
    receiver_heights: ReceiverHeights = ReceiverHeights(),
    position_error: PositionError = PositionError(),
    tile_size: float | None = None,
    grid_dir: StrPath | None = None,
    dem_crs: CrsInput | None = None,
    overwrite: bool = False,
    progress: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """Write the ``observations`` files' receivers into ``folder``, partitioned by tile of
    ``tile_size`` metres (default :data:`~gnss_citygml.settings.DEFAULT_TILE_SIZE`); returns
    the index (also ``folder/partition.json``).

    The folder appears whole or not at all: it is written beside, under another name, and
    renamed into place at the end (replacing an old one only with ``overwrite``).
    ``position_error.window`` decides the position-error groups here; the run in tiles must
    use the same (it checks). ``progress`` is told each file's name as it starts.
    """
    tile_size = DEFAULT_TILE_SIZE if tile_size is None else tile_size
    check_tile_size(tile_size)
    check_not_input(folder, [*observations, dem])  # (it is replaced whole)
    say = progress or (lambda text: None)
    tiles: dict[str, dict[str, int]] = {}
    signals = 0
    with atomic_folder(folder, overwrite=overwrite, mark=INDEX) as work:
        for k, path in enumerate(observations):
            say(str(path))
            obs = in_mask(read_observations(path), rays)
            rx = receivers(obs, dem, heights=receiver_heights, grid_dir=grid_dir, dem_crs=dem_crs)
            rx.insert(0, "signal", signals + np.arange(len(rx), dtype=np.int64))
            signals += len(rx)
            if not position_error.exact:
                rx["recording"] = np.asarray(recordings(rx, position_error), dtype=object)
            ix, iy = tile_index(rx["e"], rx["n"], tile_size)
            names = tile_names(ix, iy, tile_size) if len(rx) else np.empty(0, dtype=object)
            for name, rows in rx.groupby(names, sort=True):
                part = work / RECEIVERS / f"tile={name}"
                part.mkdir(parents=True, exist_ok=True)
                rows.to_parquet(part / f"part-{k:05d}.parquet", index=False)
                entry = tiles.setdefault(
                    str(name),
                    {"ix": int(ix[rows.index[0]]), "iy": int(iy[rows.index[0]]), "rows": 0},
                )
                entry["rows"] += len(rows)
        index = {
            "format": "gnss-citygml partition",
            "version": VERSION,
            "crs": "EPSG:27700",
            "tile_size": float(tile_size),
            "rays": {"min_elevation": rays.min_elevation, "max_elevation": rays.max_elevation},
            "receiver_heights": asdict(receiver_heights),
            "position_window": position_error.window,
            "observations": [str(p) for p in observations],
            "signals": signals,
            "tiles": dict(sorted(tiles.items())),
        }
        (work / INDEX).write_text(json.dumps(index, indent=1))
    return index


def read_index(folder: StrPath) -> dict[str, Any]:
    """The index of a partition folder, or a one-line error saying what is wrong with it."""
    path = Path(folder) / INDEX
    try:
        index = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise InputError(
            f"not a partition folder: cannot read {INDEX} ({type(exc).__name__})",
            where=str(folder),
            fix="give a folder written by gnss-citygml partition",
        ) from None
    if not isinstance(index, dict) or index.get("format") != "gnss-citygml partition":
        raise InputError(
            f"not a partition folder: {INDEX} is not gnss-citygml's",
            where=str(path),
            fix="give a folder written by gnss-citygml partition",
        )
    if index.get("version") != VERSION:
        raise InputError(
            f"partition format version {index.get('version')}, this toolkit reads {VERSION}",
            where=str(path),
            fix="write the partition again with this version (gnss-citygml partition)",
        )
    return index


def partition_run(folder: StrPath, tiling: Tiling) -> dict[str, Any]:
    """The index of the partition ``folder`` for a run with ``tiling``, refusing a run that is
    not in tiles (a partition is read tile by tile) or whose tile size is not the partition's.
    """
    index = read_index(folder)
    if not tiling.on:
        raise InputError(
            "a partition folder is read by a run in tiles",
            where=str(folder),
            fix="give --scheduler local (or the address of a Dask scheduler)",
        )
    if tiling.size is not None and tiling.size != index["tile_size"]:
        raise InputError(
            f"the partition's tiles are {index['tile_size']:g} m, not {tiling.size:g}",
            where=str(folder),
            fix="leave out --tile-size, or partition again with it",
        )
    return index


def check_partition(
    index: dict[str, Any],
    rays: Rays,
    position_error: PositionError,
    receiver_heights: ReceiverHeights | None = None,
) -> None:
    """Refuse a run whose elevation mask, position-error window or (if given) receiver
    heights are not the partition's: they were applied when it was written."""
    mask = index["rays"]
    if (mask["min_elevation"], mask["max_elevation"]) != (rays.min_elevation, rays.max_elevation):
        raise InputError(
            f"the partition was written with elevations {mask['min_elevation']:g}-"
            f"{mask['max_elevation']:g} deg, not {rays.min_elevation:g}-{rays.max_elevation:g}",
            fix="give the partition's --min-elevation and --max-elevation, or partition again",
        )
    if receiver_heights is not None and index["receiver_heights"] != asdict(receiver_heights):
        raise InputError(
            f"the partition took the receivers' heights as {index['receiver_heights']}, not "
            f"{asdict(receiver_heights)}",
            fix="give the partition's --receiver-height and --antenna-height, or partition again",
        )
    if index["position_window"] != position_error.window:
        raise InputError(
            f"the partition grouped position errors with window {index['position_window']}, "
            f"not {position_error.window}",
            fix="give the partition's --position-window, or partition again",
        )


def tile_files(folder: StrPath, index: dict[str, Any]) -> dict[str, list[Path]]:
    """The Parquet files of each tile of the partition's ``index``, in file order, each
    folder listed once; a tile of the index without files is a damaged partition."""
    files = {}
    for name in index["tiles"]:
        files[name] = sorted((Path(folder) / RECEIVERS / f"tile={name}").glob("part-*.parquet"))
        if not files[name]:
            raise InputError(
                f"damaged partition: tile {name} of {INDEX} has no files",
                where=str(Path(folder) / RECEIVERS / f"tile={name}"),
                fix="write the partition again (gnss-citygml partition)",
            )
    return files


def read_receivers(files: Sequence[StrPath]) -> pd.DataFrame:
    """The receivers of some partitions' files, in signal order (the order of a single run's
    rows, which a tile's fits keep for rows of equal height)."""
    frames = [pd.read_parquet(f) for f in files]
    if not frames:
        return pd.DataFrame()
    return pd.concat(frames, ignore_index=True).sort_values("signal", kind="stable")
