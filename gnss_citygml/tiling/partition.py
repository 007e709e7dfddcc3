"""Observations as Parquet partitioned by tile: the input of a national run in tiles.

No machine of a national run can read every observation. ``gnss-citygml partition`` reads the
observation files one at a time and does the stages that need no footprints: the elevation
mask, the receivers in British National Grid + ODN with grid bearings
(:func:`~gnss_citygml.pipeline.receivers`), which rows share one position error
(:func:`~gnss_citygml.pipeline.recordings`, named once: a recording may span tiles) and each
signal's number over all the files. It writes the rows under the tile that holds the
receiver, in the hive layout that Dask, pyarrow, DuckDB and GDAL read::

    FOLDER/partition.json                       what was done, the tiles, their files
    FOLDER/receivers/tile=TQ2982/part-00000.parquet   rows of file 0 in TQ2982

A run in tiles (:func:`gnss_citygml.tiling.run.partitioned_heights`) then has each tile read only
the partitions its rays can come from. A recording must lie in one file (the position-error
groups are found per file); each file's signals are numbered after the previous file's.

The index lists every file with its rows, size and SHA-256, and a run reads only a partition
that matches it (:func:`read_index`), so a sync tool's stray copy, a file deleted, cut short
or replaced, a tile folder renamed or added, or an index edited by hand is refused by name,
never read as other data: the folder's listing and each file's size are checked on the
client before any work (a few ``stat`` calls per tile), each file's SHA-256 by the workers
before any tile is cast (:func:`check_digests`: each file is read once more, where it is).
The index is sealed by the SHA-256 of its own content (``"sha256"``): every part of it decides
what a worker reads or how its rows were made (a tile's square or extent, its files, the
elevation mask, the ids' name), so an edit that keeps its sums and the folder in agreement (a
file moved to another tile with its entry, a tile's bounds) is refused too.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
from collections.abc import Callable, Sequence
from dataclasses import asdict
from numbers import Real
from pathlib import Path
from typing import Any

import geopandas as gpd
import numpy as np
import pandas as pd

from ..errors import InputError, first_line, listing, user_text
from ..files.folders import atomic_folder
from ..files.names import check_utf8_name
from ..files.paths import StrPath, check_not_input, file_digest
from ..files.provenance import PARTITION_INDEX
from ..files.userjson import parse_json
from ..observations import read_observations, repeated_signals
from ..settings import (
    DEFAULT_TILE_SIZE,
    PositionError,
    Rays,
    ReceiverHeights,
    RunSettings,
    Tiling,
    check_tile_size,
)
from ..settings.checks import finite
from ..stages import in_mask, recordings, run_receivers
from ..terrain import Dem
from .buildings import (
    BUILDINGS,
    Footprints,
    building_files,
    files_shared_id,
    partition_buildings,
    read_buildings,
    refuse_shared,
)
from .dem_probes import check_dem, dem_probes
from .grid import check_reach, check_tile_count, tile_index, tile_names

__all__ = [
    "INDEX",
    "RECEIVERS",
    "check_digests",
    "check_holds_buildings",
    "listed_sha256",
    "check_partition",
    "partition_footprints",
    "partition_observations",
    "partition_run",
    "read_index",
    "read_receivers",
    "refuse_changed",
    "refuse_shared_ids",
    "tile_files",
]

#: The partition's index, in its folder (the name provenance records know it by).
INDEX = PARTITION_INDEX
#: The folder of the receivers' partitions, in the partition's folder.
RECEIVERS = "receivers"
#: The index's format version: 2 lists each tile's files (with rows, size and SHA-256), 3 seals
#: the index with its own digest.
VERSION = 3
#: The name of a tile's file: its observation file's number.
_PART = re.compile(r"part-\d{5}\.parquet")
#: How to mend a partition that does not match its index.
_AGAIN = "write the partition again (gnss-citygml partition)"


def partition_observations(
    observations: Sequence[StrPath],
    folder: StrPath,
    dem: Dem | None = None,
    settings: RunSettings | None = None,
    *,
    tile_size: float | None = None,
    footprints: Footprints | None = None,
    overwrite: bool = False,
    progress: Callable[[str], None] | None = None,
    **changes: Any,
) -> dict[str, Any]:
    """Write the ``observations`` files' receivers into ``folder``, partitioned by tile of
    ``tile_size`` metres (default :data:`~gnss_citygml.settings.DEFAULT_TILE_SIZE`), and the
    ``footprints``, if given, with their ground (:mod:`gnss_citygml.tiling.buildings`): a run
    then needs nothing but the folder. Returns the index (also ``folder/partition.json``).

    The folder appears whole or not at all: it is written beside, under another name, and
    renamed into place at the end (replacing an old one only with ``overwrite``, keeping the
    files of the user's in it: :func:`~gnss_citygml.files.folders.atomic_folder`).
    The ``settings`` (:class:`~gnss_citygml.settings.RunSettings`, and their parts by name in
    ``changes``) the partition applies are the elevation mask, the receiver heights (with the
    grids and the DEM's CRS) and the position error's window or distance, which decides the
    position-error groups here: the run in tiles must use the same (it checks). ``progress`` is
    told each file's name as it starts.
    """
    settings = RunSettings.of(settings, **changes)
    tile_size = DEFAULT_TILE_SIZE if tile_size is None else tile_size
    check_tile_size(tile_size)
    given = [] if footprints is None else [footprints.path]
    check_not_input(folder, [*observations, dem, *given])  # (it is replaced whole)
    check_utf8_name(folder, "partition folder")  # (Arrow writes its files)
    say = progress or (lambda text: None)
    tiles: dict[str, dict[str, Any]] = {}
    signals = 0
    with atomic_folder(folder, overwrite=overwrite, mark=INDEX) as work:
        for k, path in enumerate(observations):
            say(str(path))
            signals += _write_receivers(work, k, path, dem, settings, tile_size, tiles, signals)
        _refuse_repeats(work, tiles, observations)
        index: dict[str, Any] = {
            "format": "gnss-citygml partition",
            "version": VERSION,
            "crs": "EPSG:27700",
            "tile_size": float(tile_size),
            "rays": {
                "min_elevation": settings.rays.min_elevation,
                "max_elevation": settings.rays.max_elevation,
            },
            "receiver_heights": asdict(settings.receiver_heights),
            "position_window": settings.position_error.window,
            "position_distance": settings.position_error.distance,
            "observations": [str(p) for p in observations],
            "signals": signals,
            "tiles": dict(sorted(tiles.items())),
        }
        if footprints is not None:
            index[BUILDINGS] = partition_buildings(
                footprints, work, dem, tile_size, settings.grid_dir, settings.dem_crs, say
            )
        if dem is not None:  # (what a run given a DEM checks it against)
            built = index[BUILDINGS]["tiles"] if BUILDINGS in index else {}
            tops = [(work / RECEIVERS, index["tiles"]), (work / BUILDINGS, built)]
            index["dem"] = dem_probes(tops, dem, settings.dem_crs)
        index = json.loads(json.dumps(index))  # (as it is read back: its digest is of that)
        index["sha256"] = _index_digest(index)
        (work / INDEX).write_text(json.dumps(index, indent=1))
    return index


def _index_digest(index: dict[str, Any]) -> str:
    """The SHA-256 of an index's content (all but its ``"sha256"``), in a canonical form."""
    content = {key: value for key, value in index.items() if key != "sha256"}
    text = json.dumps(content, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()


def _write_receivers(work, k, path, dem, settings, tile_size, tiles, signals) -> int:
    """The receivers of the observation file ``path`` (the ``k``-th), numbered from
    ``signals``, written under their tiles (recorded in ``tiles``); returns how many."""
    rx = run_receivers(in_mask(read_observations(path), settings.rays), dem, settings)
    rx.insert(0, "signal", signals + np.arange(len(rx), dtype=np.int64))
    if not settings.position_error.exact:
        rx["recording"] = np.asarray(recordings(rx, settings.position_error), dtype=object)
    ix, iy = tile_index(rx["e"], rx["n"], tile_size)
    new = np.unique(np.stack([ix, iy]), axis=1)  # counted before a folder is made
    check_tile_count(new.shape[1], tile_size)
    had = {(spec["ix"], spec["iy"]) for spec in tiles.values()}
    check_tile_count(len(had | set(map(tuple, new.T.tolist()))), tile_size)
    names = tile_names(ix, iy, tile_size) if len(rx) else np.empty(0, dtype=object)
    for name, rows in rx.groupby(names, sort=True):
        part = work / RECEIVERS / f"tile={name}"
        part.mkdir(parents=True, exist_ok=True)
        file = part / f"part-{k:05d}.parquet"
        rows.to_parquet(file, index=False)
        entry = tiles.setdefault(
            str(name),
            {"ix": int(ix[rows.index[0]]), "iy": int(iy[rows.index[0]]), "rows": 0},
        )
        entry["rows"] += len(rows)
        size, digest = file_digest(file)
        entry.setdefault("files", {})[file.name] = {
            "rows": len(rows),
            "bytes": size,
            "sha256": digest,
        }
    return len(rx)


def _refuse_repeats(work: Path, tiles: dict[str, dict[str, Any]], observations) -> None:
    """Refuse a signal (receiver, satellite, time) in two of the ``observations`` files: each
    file is read alone (its own repeats are counted once), so a repeat across files would count
    twice in the fits, and two values of one signal would contradict each other. A signal's
    rows are all in its receiver's tile: each tile written from two files or more is read back,
    its keys only."""
    for name, spec in tiles.items():
        if len(spec["files"]) < 2:
            continue
        folder = work / RECEIVERS / f"tile={name}"
        keys = pd.concat(
            [
                pd.read_parquet(folder / file, columns=_SIGNAL_KEY).assign(
                    file=int(Path(file).stem.removeprefix("part-"))
                )
                for file in sorted(spec["files"])
            ],
            ignore_index=True,
        )
        first, second = repeated_signals(keys)
        of = keys["file"].to_numpy()
        across = np.flatnonzero(of[first] != of[second])
        if across.size:
            a, b = keys.iloc[first[across[0]]], keys.iloc[second[across[0]]]
            raise InputError(
                f"{across.size} signal(s) in two of the files, e.g. receiver "
                f"{user_text(a['receiver'])}, satellite {a['constellation']}{a['svid']:02d} at "
                f"{a['time_utc']:%Y-%m-%dT%H:%M:%S.%f}Z",
                where=f"{observations[a['file']]} and {observations[b['file']]}",
                fix="give each recording once (two recordings with one receiver name? rename "
                "the receiver in one of them)",
            )


#: The columns that name a signal (:func:`~gnss_citygml.observations.repeated_signals`).
_SIGNAL_KEY = ["receiver", "constellation", "svid", "time_utc"]


def read_index(folder: StrPath) -> dict[str, Any]:
    """The index of a partition folder, checked against the folder (every file and tile
    folder it lists is there with its size, nothing else is under ``receivers``), or a
    one-line error naming what is wrong and how to mend it. The files' SHA-256 are checked
    where they are read (:func:`check_digests`)."""
    path = Path(folder) / INDEX
    try:
        index = parse_json(path.read_bytes())
    except (OSError, ValueError) as exc:
        raise InputError(
            f"not a partition folder: cannot read {INDEX} ({user_text(first_line(exc))})",
            where=str(folder),
            fix="give a folder written by gnss-citygml partition",
        ) from None
    if not isinstance(index, dict) or index.get("format") != "gnss-citygml partition":
        raise InputError(
            f"not a partition folder: {INDEX} is not gnss-citygml's",
            where=str(path),
            fix="give a folder written by gnss-citygml partition",
        )
    if type(index.get("version")) is not int or index["version"] != VERSION:
        raise InputError(
            f"partition format version {index.get('version')!r}, this toolkit reads {VERSION} "
            "(which lists every file, to check the folder against)",
            where=str(path),
            fix="write the partition again with this version (gnss-citygml partition)",
        )
    problem = _index_problem(index)
    if problem:
        raise InputError(f"damaged {INDEX}: {problem}", where=str(path), fix=_AGAIN)
    if index.get("sha256") != _index_digest(index):
        raise InputError(
            f"damaged partition: {INDEX} is not the index partition wrote (its content's "
            "SHA-256 differs from the one it records: edited after it was written?)",
            where=str(path),
            fix=_AGAIN,
        )
    _check_files(Path(folder), index)
    return index


def _index_problem(index: dict[str, Any]) -> str | None:
    """What is wrong with an index's content (keys, types, sums, names), or None."""
    kinds: dict[str, Any] = {
        "tile_size": Real,
        "rays": dict,
        "receiver_heights": dict,
        "position_window": (Real, type(None)),
        "signals": int,
        "tiles": dict,
    }
    if index.get("crs") != "EPSG:27700":  # (the receivers' e, n; what every tile is cut in)
        return f"'crs' is {index.get('crs')!r}, not 'EPSG:27700'"
    for key, kind in kinds.items():
        if key not in index:
            return f"no {key!r}"
        if not isinstance(index[key], kind) or isinstance(index[key], bool):
            return f"{key!r} is {index[key]!r}"
    if not all(isinstance(index["rays"].get(k), Real) for k in ("min_elevation", "max_elevation")):
        return f"'rays' is {index['rays']!r}"
    try:
        check_tile_size(index["tile_size"])
    except InputError as exc:
        return exc.what
    problem, total = _tiles_problem(index["tiles"], index["tile_size"], "tile")
    if problem:
        return problem
    if index["signals"] != total:
        return f"{index['signals']} signals, its tiles hold {total}"
    return _buildings_problem(index)


def _buildings_problem(index: dict[str, Any]) -> str | None:
    """What is wrong with an index's buildings (:mod:`gnss_citygml.tiling.buildings`), or None
    (also when it has none)."""
    if BUILDINGS not in index:
        return None
    entry = index[BUILDINGS]
    kinds = {"id_field": str, "rows": int, "tiles": dict}
    if not isinstance(entry, dict) or not all(
        isinstance(entry.get(k), t) for k, t in kinds.items()
    ):
        return f"{BUILDINGS!r} is {entry!r}"
    problem, total = _tiles_problem(entry["tiles"], index["tile_size"], "buildings' tile")
    if problem:
        return problem
    for name, spec in entry["tiles"].items():
        bounds = spec.get("bounds")
        if not (isinstance(bounds, list) and len(bounds) == 4 and all(map(finite, bounds))):
            return f"buildings' tile {name} has bounds {bounds!r}"
    return None if entry["rows"] == total else f"{entry['rows']} buildings, its tiles hold {total}"


def _tiles_problem(tiles: dict[str, Any], size: float, what: str) -> tuple[str | None, int]:
    """What is wrong with the tiles of an index (their files, rows and places), or None; and
    the rows they hold."""
    total = 0
    for name, spec in tiles.items():
        for key in ("ix", "iy", "rows", "files"):
            if not isinstance(spec, dict) or key not in spec:
                return f"no {key!r} in {what} {name}", total
        files = spec["files"]
        if not (isinstance(files, dict) and files and all(map(_PART.fullmatch, files))):
            return f"{what} {name}'s files are {listing(files)}", total
        for file, entry in files.items():
            kinds = {"rows": int, "bytes": int, "sha256": str}
            if not isinstance(entry, dict) or not all(
                isinstance(entry.get(k), t) for k, t in kinds.items()
            ):
                return f"{what} {name}'s {file} is {entry!r}", total
        rows = sum(entry["rows"] for entry in files.values())
        if spec["rows"] != rows:
            return f"{what} {name} has {spec['rows']!r} rows, its files {rows}", total
        total += rows
        if not all(isinstance(spec[k], int) for k in ("ix", "iy")):
            return f"{what} {name} is at {spec['ix']!r}, {spec['iy']!r}", total
        try:
            at = tile_names([spec["ix"]], [spec["iy"]], size)[0]
        except InputError as exc:
            return exc.what, total
        if at != name:
            return f"{what} {name} is at the place of tile {at}", total
    return None, total


def _check_files(folder: Path, index: dict[str, Any]) -> None:
    """Refuse a partition folder whose files are not its index's (:func:`_check_listed`), its
    receivers' and its buildings'; a folder of buildings the index does not have."""
    _check_listed(folder / RECEIVERS, index["tiles"])
    if BUILDINGS in index:
        _check_listed(folder / BUILDINGS, index[BUILDINGS]["tiles"])
    elif (folder / BUILDINGS).exists():
        raise InputError(
            f"damaged partition: {BUILDINGS}/ is not in {INDEX}",
            where=str(folder / BUILDINGS),
            fix=f"remove it if it is a stray copy, or {_AGAIN}",
        )


def _check_listed(top: Path, tiles: dict[str, Any]) -> None:
    """Refuse a folder of tiles (``top``) whose files are not its index's ``tiles``: a file or
    tile folder the index does not list (a sync tool's copy, a tile taken out of the index),
    one it lists that is missing, or one of another size."""
    what = top.name
    listed = {f"tile={name}": spec["files"] for name, spec in tiles.items()}
    found = _entries(top)
    for entry in sorted(found.keys() - listed.keys()):
        raise InputError(
            f"damaged partition: {what}/{entry} is not in {INDEX}",
            where=str(top / entry),
            fix=f"remove it if it is a stray copy, or {_AGAIN}",
        )
    for tile, files in listed.items():
        if tile not in found:
            raise InputError(
                f"damaged partition: {what}/{tile} of {INDEX} is missing",
                where=str(top / tile),
                fix=_AGAIN,
            )
        sizes = _entries(top / tile)
        for name in sorted(sizes.keys() - files.keys()):
            raise InputError(
                f"damaged partition: {tile}/{name} is not in {INDEX}",
                where=str(top / tile / name),
                fix=f"remove it if it is a stray copy, or {_AGAIN}",
            )
        for name, entry in files.items():
            if name not in sizes:
                raise InputError(
                    f"damaged partition: {tile}/{name} of {INDEX} is missing",
                    where=str(top / tile / name),
                    fix=_AGAIN,
                )
            if sizes[name] != entry["bytes"]:
                raise InputError(
                    f"damaged partition: {tile}/{name} has {sizes[name]} bytes, not the "
                    f"{entry['bytes']} of {INDEX}",
                    where=str(top / tile / name),
                    fix=_AGAIN,
                )


def _entries(folder: Path) -> dict[str, int]:
    """The names in ``folder`` with their sizes (-1 for a folder); none if it is missing."""
    try:
        with os.scandir(folder) as entries:
            return {e.name: -1 if e.is_dir() else e.stat().st_size for e in entries}
    except FileNotFoundError:
        return {}
    except OSError as exc:
        raise InputError(
            f"cannot read the partition's folder ({exc.strerror})",
            where=str(folder),
            fix="check its permissions",
        ) from None


def check_digests(files: Sequence[tuple[StrPath, str]]) -> list[str]:
    """The ``files`` (path, SHA-256 of the index) whose content is not the file the partition
    wrote, each as ``path``: run on the workers, where the files are, before a run reads them
    (each file once), so a file replaced by another of the same size is refused by name."""
    bad = []
    for path, expected in files:
        try:
            digest = file_digest(path)[1]
        except OSError as exc:
            digest = f"unreadable ({exc.strerror})"
        if digest != expected:
            bad.append(str(path))
    return bad


def refuse_changed(bad: Sequence[str]) -> None:
    """Refuse a run whose partition files :func:`check_digests` found changed, naming them."""
    if bad:
        raise InputError(
            f"damaged partition: {Path(bad[0]).parent.name}/{Path(bad[0]).name} is not the file "
            f"partition wrote (its SHA-256 differs from {INDEX}'s)"
            + (f"; {len(bad) - 1} more files too" if len(bad) > 1 else ""),
            where=str(bad[0]),
            fix=_AGAIN,
        )


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
    dem: Dem | None = None,
    dem_crs: Any = None,
) -> None:
    """Refuse a run whose elevation mask, position-error groups (window or distance) or (if
    given) receiver heights or DEM are not the partition's: they were applied when it was
    written (the DEM gave the receivers' heights and the buildings' ground: one given again
    must give the same heights where it did, :func:`~gnss_citygml.terrain.check_same_ground`);
    and tiles too small for the run's rays (:func:`~gnss_citygml.tiling.grid.check_reach`)."""
    check_reach(index["tile_size"], rays.max_range)
    if dem is not None and "dem" in index:
        check_dem(index["dem"], dem, dem_crs)
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
    # (a partition written before the distance was asked for grouped a whole recording)
    made = _grouping(index["position_window"], index.get("position_distance"))
    if made != _grouping(position_error.window, position_error.distance):
        raise InputError(
            f"the partition grouped position errors by {made}, not by "
            f"{_grouping(position_error.window, position_error.distance)}",
            fix="give the partition's --position-window or --position-distance, or partition again",
        )


def _grouping(window: float | None, distance: float | None) -> str:
    """How a moving receiver's rows share position errors, in words."""
    if window is not None:
        return f"windows of {window:g} s"
    return "whole recordings" if distance is None else f"stretches of {distance:g} m"


def tile_files(folder: StrPath, index: dict[str, Any]) -> dict[str, list[Path]]:
    """The Parquet files of each tile of the partition's ``index`` (checked against the
    folder by :func:`read_index`), in file order."""
    top = Path(folder) / RECEIVERS
    return {
        name: [top / f"tile={name}" / file for file in sorted(spec["files"])]
        for name, spec in index["tiles"].items()
    }


def check_holds_buildings(folder: StrPath, index: dict[str, Any]) -> None:
    """Refuse a run without footprints from a partition written without them."""
    if BUILDINGS not in index:
        raise InputError(
            "the partition holds no footprints",
            where=str(folder),
            fix="give the footprints too (estimate FOLDER FOOTPRINTS), or partition again "
            "with --footprints",
        )


def listed_sha256(index: dict[str, Any], path: Path) -> str:
    """The SHA-256 the index lists for a file of the partition (its receivers' or buildings')."""
    tiles = index[BUILDINGS]["tiles"] if path.parent.parent.name == BUILDINGS else index["tiles"]
    return str(tiles[path.parent.name.removeprefix("tile=")]["files"][path.name]["sha256"])


def partition_footprints(folder: StrPath, index: dict[str, Any]) -> gpd.GeoDataFrame:
    """The buildings a partition holds (written with footprints), with their ``ground`` and
    the footprints' id name, each file first checked against the index's SHA-256 (as the
    workers check the receivers'); an :class:`InputError` if it holds none."""
    check_holds_buildings(folder, index)
    files = [f for tile in building_files(folder, index).values() for f in tile]
    refuse_changed(check_digests([(f, listed_sha256(index, f)) for f in files]))
    refuse_shared_ids(folder, files_shared_id(files))
    return read_buildings(folder, index[BUILDINGS])


def refuse_shared_ids(folder: StrPath, found: tuple[int, str, str, str] | None) -> None:
    """Refuse a partition whose buildings share an id (:func:`~.buildings.shared_id`), naming
    it with both its tiles: its run would hold one building twice."""
    refuse_shared(
        found,
        "buildings of the partition",
        str(Path(folder) / BUILDINGS),
        f"{_AGAIN}, from footprints whose ids are unique",
    )


def read_receivers(files: Sequence[StrPath]) -> pd.DataFrame:
    """The receivers of some partitions' files, in signal order (the order of a single run's
    rows, which a tile's fits keep for rows of equal height)."""
    frames = [pd.read_parquet(f) for f in files]
    if not frames:
        return pd.DataFrame()
    return pd.concat(frames, ignore_index=True).sort_values("signal", kind="stable")
