"""Batch updates of a GeoPackage map as new GNSS data arrives, without ever risking the map.

:func:`update_map` adds or updates the estimate columns (:data:`COLUMNS`) of a footprint layer
of a GeoPackage, for the buildings with enough signals. Every other column, feature, layer and
style of the file is kept, and the layer's feature ids do not change: the columns are written
with SQL on the layer's own table, by building id.

- **Never a damaged map.** The work is done on a copy beside the map, which is renamed over it
  only when complete (:func:`gnss_citygml.paths.atomic_path`); the map as it was is kept as
  ``MAP.bak.gpkg`` (unless ``backup=False``). A crash, Ctrl-C or ``kill -9`` at any moment
  leaves the map byte-identical. A map that another program is writing to (a write lock, or
  a write-ahead log that is not empty: QGIS editing a layer) is refused.
- **Evidence kept.** Every intersection cast so far (signal, building, height, C/N0, the
  height error that its receiver's position error gives and which rows share that error, ...) is
  kept in the table ``gnss_evidence`` of the GeoPackage, keyed by its signal (receiver, time,
  satellite). A later update casts only the observations not in it yet, and refits the
  model on all of the evidence, so its result is that of one run over all the observations.
  The model is refitted whole, not only for the buildings the new signals touch: 4PL-B
  co-trains one signal classifier on every building's signals, so new signals anywhere move
  the labels, and with them the fits, everywhere. The evidence is the layer's as SQLite names
  it (in any letter case), and records what it was cast with: a later update with other
  settings (elevation mask, receiver heights) or a DEM that gives other antenna heights where
  signals were cast from is refused, never mixed in. A damaged evidence table is a one-line
  error. A map given as a symbolic link is the file it names (updated; the link stays).
- **Idempotent.** The same observations again add no evidence and change no value; a
  building's ``updated_utc`` changes only when one of its values does, and a run that
  changes nothing writes nothing.
"""

from __future__ import annotations

import contextlib
import datetime as dt
import json
import os
import shutil
import sqlite3
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from .errors import InputError
from .geopackage import (
    check_geopackage,
    check_no_triggers,
    check_table_layer,
    connect,
    quoted,
    refused,
)
from .ids import id_text
from .paths import StrPath, atomic_path, check_not_input, input_file
from .settings import Estimator, Rays, ReceiverHeights

__all__ = ["COLUMNS", "EVIDENCE", "UpdateResult", "update_map"]

#: The attribute table of the GeoPackage that keeps the evidence: one row per update and kind,
#: its rows as Parquet (read at once by Arrow; GDAL's row by row reading of millions of rows
#: was 22 s of a 64 s update). Kind ``intersections``: every (signal, building its ray
#: enters); kind ``cast``: the keys of every signal cast (most enter no footprint: they leave
#: no evidence, but are not cast again).
EVIDENCE = "gnss_evidence"
INTERSECTIONS, CAST = "intersections", "cast"

#: The 16 bytes that key the hash of a signal's receiver, time and satellite (a signal key is
#: a 64-bit hash of them: 1 in 10^8 chances of one collision among 6 million signals).
_HASH_KEY = "gnss-citygml-sig"

#: The columns written on the layer, with their GeoPackage types.
COLUMNS = {
    "height_gnss": "REAL",
    "height_lower": "REAL",
    "height_upper": "REAL",
    "height_paper": "REAL",
    "c_gnss": "REAL",
    "n_signals": "INTEGER",
    "converged": "BOOLEAN",
    "method": "TEXT",
    "status_gnss": "TEXT",
    "updated_utc": "DATETIME",
}

#: The estimate's columns each of them is taken from.
_FROM = {
    "height_gnss": "height",
    "height_lower": "height_lower",
    "height_upper": "height_upper",
    "height_paper": "height_paper",
    "c_gnss": "c",
    "n_signals": "n_signals",
    "converged": "converged",
    "method": "method",
    "status_gnss": "status",
}

#: The evidence's columns (the intersections table's, the signal by its key).
_EVIDENCE_COLUMNS = [
    "signal_key",
    "building",
    "height",
    "distance",
    "order",
    "cn0",
    "receiver",
    "satellite",
    "height_sd",
    "recording",
]

#: What the evidence keeps of every signal cast: for the report's skyplots and tracks, and
#: the antenna's height ``z`` it was cast from (checked against the DEM of a later update).
_SIGNAL_COLUMNS = [
    "signal_key", "receiver", "time_utc", "e", "n", "azimuth", "elevation", "cn0", "z"
]  # fmt: skip

#: The columns of the evidence table that every update reads.
_TABLE_COLUMNS = ["id", "layer", "kind", "footprints", "data"]

#: The types of the evidence's columns (for an empty table).
_DTYPES = {
    "signal_key": "int64",
    "building": "object",
    "height": "float64",
    "distance": "float64",
    "order": "int64",
    "cn0": "float64",
    "receiver": "object",
    "satellite": "object",
    "height_sd": "float64",
    "recording": "object",
    "time_utc": "datetime64[ns, UTC]",
    "e": "float64",
    "n": "float64",
    "azimuth": "float64",
    "elevation": "float64",
    "z": "float64",
}


@dataclass
class UpdateResult:
    """What an update did (or, with ``dry_run``, would do)."""

    #: Observations cast this time (those not in the evidence yet), and the evidence rows
    #: they added.
    new_signals: int
    new_evidence: int
    #: Every building: ``id``, the height before and after (m ODN, NaN for none), whether
    #: its values changed, and why it was skipped (empty if it was not).
    buildings: pd.DataFrame
    #: The height change (m) above which a building is listed as changed.
    threshold: float
    #: The buildings the new signals' rays enter.
    touched: frozenset[str] = frozenset()
    #: Whether the map was written (False for a dry run or when nothing changed).
    written: bool = False
    backup: Path | None = None
    notes: list[str] = field(default_factory=list)

    @property
    def updated(self) -> pd.DataFrame:
        return self.buildings[self.buildings["changed"]]

    @property
    def skipped(self) -> pd.DataFrame:
        return self.buildings[self.buildings["skipped"] != ""]

    def lines(self) -> list[str]:
        """The change report: counts, the buildings that moved by more than the threshold,
        the skipped ones by reason."""
        table = self.buildings
        delta = (table["after"] - table["before"]).abs()
        moved = table[table["changed"] & (delta > self.threshold)]
        gained = table[table["changed"] & table["before"].isna() & table["after"].notna()]
        lost = table[table["changed"] & table["before"].notna() & table["after"].isna()]
        lines = [
            f"{self.new_signals} new signals cast, {self.new_evidence} new intersections in "
            f"{len(self.touched)} buildings; "
            f"{len(self.updated)} of {len(table)} buildings updated, {len(moved)} by more "
            f"than {self.threshold:g} m, {len(gained)} with a first height, {len(lost)} "
            "without one now"
        ]
        for row in moved.itertuples(index=False):
            lines.append(f"  {row.id}: {row.before:.2f} -> {row.after:.2f} m")
        for reason, n in self.skipped["skipped"].value_counts().items():
            lines.append(f"skipped {n}: {reason}")
        return lines + self.notes


def update_map(
    path: StrPath,
    observations: Sequence[StrPath],
    dem: StrPath,
    *,
    layer: str | None = None,
    id_field: str | None = None,
    min_signals: int = 1,
    threshold: float = 0.5,
    dry_run: bool = False,
    backup: bool = True,
    rays: Rays = Rays(),
    receiver_heights: ReceiverHeights = ReceiverHeights(),
    estimator: Estimator = Estimator(),
    grid_dir: StrPath | None = None,
    dem_crs: str | None = None,
    report: StrPath | None = None,
    truth: StrPath | None = None,
    progress: Callable[[str, float], None] | None = None,
) -> UpdateResult:
    """Update the estimate columns of ``layer`` of the GeoPackage ``path`` with new
    ``observations`` (observations tables, CSV or Parquet); see the module's notes.

    A building gets values when it has at least ``min_signals`` signals in the evidence;
    ``threshold`` (m) is the height change above which it is listed in the change report.
    ``report`` is a folder for the report of the fit over all the evidence
    (:mod:`gnss_citygml.report`; ``truth``, a simulator's truth table, adds the true heights).
    """
    from .ids import id_field as source_id_field
    from .jobs import read_buildings
    from .observations import read_observation_files
    from .pipeline import fit_heights, in_mask, intersections, receivers

    say = progress or (lambda what, done: None)
    path = _check_map(path)
    check_no_triggers(path)
    inputs = [path, *observations, dem, truth]
    if backup:  # (the map itself is written through a copy: a new layer's columns, not a file)
        check_not_input(_backup_path(path), inputs, what="backup")
    if truth is not None and report is None:
        raise InputError(
            "a truth table is for the report, and no report was asked for",
            where=str(truth),
            fix="give a report folder too (--report DIR), or leave the truth out",
        )
    true = None
    if report is not None:
        from .compare import check_truth
        from .ids import with_id_field
        from .pipeline import Run
        from .report import check_report, write_report
        from .tables import read_table

        check_report(report, overwrite=True, inputs=inputs)
        true = None if truth is None else check_truth(read_table(truth), str(truth))
    if min_signals < 1:
        raise InputError(f"min_signals must be 1 or more, not {min_signals}", fix="give N >= 1")
    if not (np.isfinite(threshold) and threshold >= 0):
        raise InputError(
            f"the change threshold must be a number of metres, 0 or more, not {threshold}",
            fix="give --threshold in metres, e.g. 0.5",
        )
    say("reading", 0.0)
    read_at = _stamp(path)
    name = _layer_name(path, layer)  # (as the database names it: the evidence's key)
    check_table_layer(path, name)
    buildings = read_buildings(
        path,
        layer=None if layer is None else name,
        id_field=id_field,
        dem=dem,
        dem_crs=dem_crs,
        grid_dir=grid_dir,
    )
    id_column = source_id_field(buildings)
    outlines = _outlines(buildings)
    key, stored_ids = _key_column(path, name, [id_column, id_field, "fid"], buildings["id"])
    current = _current_values(path, name, key, buildings["id"])  # (checks our columns' types)
    before = _read_evidence(path, name, with_signals=report is not None)
    settings = _cast_settings(rays, receiver_heights)
    _check_cast_with(path, before, settings)
    _check_receiver_heights(before.cast, dem, receiver_heights, dem_crs)
    stored, cast_before = before.intersections, before.cast
    gone = ~stored["building"].isin(buildings["id"].astype(str)).to_numpy()
    stored = stored[~gone].reset_index(drop=True)  # footprints deleted since: their evidence
    obs = in_mask(read_observation_files(observations), rays)  # each signal once (it warns)
    keys = _keys(obs)
    unseen = ~keys.isin(cast_before["signal_key"]).to_numpy()
    new = obs[unseen].reset_index(drop=True)
    fresh, signals = stored.iloc[:0], pd.DataFrame(columns=_SIGNAL_COLUMNS)
    if len(new):
        say("casting", 0.25)
        rx = receivers(new, dem, heights=receiver_heights, grid_dir=grid_dir, dem_crs=dem_crs)
        rx["signal_key"] = _keys(rx).to_numpy()
        cast = intersections(rx, buildings, rays=rays)
        fresh = cast.assign(
            signal_key=rx["signal_key"].to_numpy()[cast["signal"].to_numpy()],
            building=cast["building"].astype(str),
            satellite=cast["satellite"].astype(str),
            recording=cast["recording"].astype(str),
        )[_EVIDENCE_COLUMNS]
        signals = rx.drop_duplicates("signal_key")[_SIGNAL_COLUMNS]
    evidence = pd.concat([stored, fresh], ignore_index=True)
    if evidence.empty:
        raise InputError(
            "no evidence: no signal's ray enters a footprint of the map",
            where=str(path),
            fix="give observations made among the map's buildings",
        )
    say("fitting", 0.5)
    model = evidence.assign(
        signal=pd.factorize(evidence["signal_key"])[0],
        building=pd.Categorical(evidence["building"], categories=buildings["id"].astype(str)),
    ).drop(columns="signal_key")
    estimate, classifier = fit_heights(model, buildings, estimator)
    values, table = _new_values(estimate, current, min_signals)
    result = UpdateResult(
        len(new), len(fresh), table, threshold, frozenset(fresh["building"].astype(str))
    )
    if gone.any():
        result.notes.append(
            f"{int(gone.sum())} intersections with footprints no longer in the layer left out"
        )
    if before.outlines not in (None, outlines):
        result.notes.append(
            "the footprints changed since the evidence was cast; signals cast before are "
            "not cast again against new or edited outlines (to cast everything again, delete "
            f"the table {EVIDENCE})"
        )
    if report is not None:
        say("report", 0.6)
        everything = pd.concat([cast_before, signals], ignore_index=True).drop(columns="z")
        run = Run(
            heights=with_id_field(estimate, id_column),
            receivers=everything,
            intersections=model.assign(
                signal=pd.Index(everything["signal_key"]).get_indexer(evidence["signal_key"]),
                building=evidence["building"].to_numpy(),
            ),
            buildings=buildings,
            classifier=classifier,
        )
        write_report(run, report, truth=true)
    if dry_run or (signals.empty and not table["changed"].any()):
        if not dry_run:
            result.notes.append("nothing changed: the map is untouched")
        return result
    say("writing", 0.75)
    if _stamp(path) != read_at:  # (from here on, atomic_path watches the file)
        raise InputError(
            "the map changed while this update ran (another update?)",
            where=str(path),
            fix="run again once the other program has finished with it",
        )
    with atomic_path(path, overwrite=True, update=True) as tmp, refused(path):
        if len(fresh):
            _append_evidence(tmp, name, INTERSECTIONS, fresh, outlines, settings)
        if len(signals):
            _append_evidence(tmp, name, CAST, signals, outlines, settings)
        changed = values[table["changed"].to_numpy()]
        _write_columns(tmp, name, key, changed.assign(id=changed["id"].map(stored_ids)))
        if backup:
            result.backup = _backup(path)
    result.written = True
    say("done", 1.0)
    return result


def _check_map(path: StrPath) -> Path:
    """The map: an existing GeoPackage that no other program is writing to; the file itself
    when ``path`` is a symbolic link (the update replaces the file, and the link stays)."""
    path = Path(os.path.realpath(input_file(path, "map")))
    if path.suffix.lower() != ".gpkg":
        raise InputError(
            "the map must be a GeoPackage (.gpkg): only there can the evidence and the columns "
            "be added in place",
            where=str(path),
            fix="convert it first (ogr2ogr -f GPKG map.gpkg ...)",
        )
    check_geopackage(path, empty_ok=False)
    for suffix in ("-wal", "-shm"):
        side = path.with_name(path.name + suffix)
        if side.exists():
            raise InputError(
                f"the map is open in another program ({side.name} is beside it: SQLite's "
                "write-ahead log of an open connection, whose later writes would damage the "
                "updated file)",
                where=str(path),
                fix="close it there (QGIS: remove the layer from the project, or quit), then "
                "run again",
            )
    try:
        with contextlib.closing(sqlite3.connect(path, timeout=0.1)) as db:
            db.execute("BEGIN IMMEDIATE")  # a write lock: fails while another one holds it
            db.rollback()
    except sqlite3.DatabaseError as exc:
        raise InputError(
            f"the map cannot be locked for writing ({exc})",
            where=str(path),
            fix="another program is writing to it: let it finish or close it, then run again",
        ) from None
    return path


def _outlines(buildings: pd.DataFrame) -> str:
    """A digest of the footprints' ids and outlines, kept with the evidence cast against them."""
    import hashlib

    import shapely

    order = np.argsort(buildings["id"].astype(str).to_numpy(), kind="stable")
    digest = hashlib.sha256()
    for building, wkb in zip(
        buildings["id"].astype(str).to_numpy()[order],
        shapely.to_wkb(buildings.geometry.to_numpy()[order]),
        strict=True,
    ):
        digest.update(building.encode() + b"\0" + wkb)
    return digest.hexdigest()


def _stamp(path: Path) -> tuple[int, int, int]:
    """The file's inode, size and modification time: what changes when it is written."""
    info = path.stat()
    return info.st_ino, info.st_size, info.st_mtime_ns


def _layer_name(path: Path, layer: str | None) -> str:
    """The footprint layer's table: ``layer`` as the database names it (SQLite's names are
    the same in any letter case: ``FOOTPRINTS`` is the table ``footprints``, and its evidence
    is that table's), or the file's only polygon layer."""
    import pyogrio

    if layer is not None:
        with contextlib.closing(sqlite3.connect(path)) as db:
            row = db.execute(
                "SELECT table_name FROM gpkg_contents WHERE table_name = ? COLLATE NOCASE "
                "UNION ALL SELECT name FROM sqlite_master WHERE name = ? COLLATE NOCASE",
                (layer, layer),
            ).fetchone()
        return layer if row is None else str(row[0])  # (none: read_footprints says so)
    layers = pyogrio.list_layers(path)
    spatial = [str(n) for n, kind in layers if kind is not None]
    polygons = [n for n, kind in layers if kind and "Polygon" in str(kind)]
    return str((polygons or spatial)[0])  # (read_footprints has refused a file with several)


def _keys(rows: pd.DataFrame) -> pd.Series:
    """Each observation's signal key: a 64-bit hash of its receiver, time and satellite."""
    parts = pd.DataFrame(
        {
            "receiver": rows["receiver"].astype(str).to_numpy(),
            "time": pd.to_datetime(rows["time_utc"], utc=True).astype("int64").to_numpy(),
            "satellite": (rows["constellation"].astype(str) + rows["svid"].astype(str)).to_numpy(),
        }
    )
    hashed = pd.util.hash_pandas_object(parts, index=False, hash_key=_HASH_KEY, categorize=False)
    return pd.Series(hashed.to_numpy().view(np.int64), index=rows.index)


@dataclass
class _Stored:
    """A layer's evidence so far: its intersections, the signals cast, and what the last
    update cast them against (the footprints' digest) and with (:func:`_cast_settings`)."""

    intersections: pd.DataFrame
    cast: pd.DataFrame
    outlines: str | None
    cast_with: str | None


def _read_evidence(path: Path, layer: str, *, with_signals: bool) -> _Stored:
    """The evidence of ``layer`` (every row of the layer in any letter case, as SQLite
    compares names), in the order the updates added it; of the signals cast, their keys and
    positions (all their columns ``with_signals``, for the report). A damaged table is a
    one-line error (:func:`_damaged`), before any work."""
    signal_columns = _SIGNAL_COLUMNS if with_signals else ["signal_key", "e", "n", "z"]
    empty = {
        kind: pd.DataFrame({c: pd.Series(dtype=_DTYPES[c]) for c in columns})
        for kind, columns in ((INTERSECTIONS, _EVIDENCE_COLUMNS), (CAST, signal_columns))
    }
    try:
        with contextlib.closing(sqlite3.connect(path)) as db:
            have = _evidence_columns(db, path)
            if have is None:
                return _Stored(empty[INTERSECTIONS], empty[CAST], None, None)
            cast_with = "cast_with" if "cast_with" in have else "NULL"
            rows = db.execute(
                f"SELECT kind, footprints, {cast_with}, n_rows, data FROM {EVIDENCE} "
                "WHERE layer = ? COLLATE NOCASE ORDER BY id",
                (layer,),
            ).fetchall()
    except sqlite3.DatabaseError as exc:
        raise _damaged(path, f"it cannot be read ({exc})") from None
    parts: dict[str, list[pd.DataFrame]] = {INTERSECTIONS: [], CAST: []}
    for kind, _, _, n_rows, blob in rows:
        if kind in parts:
            columns = _EVIDENCE_COLUMNS if kind == INTERSECTIONS else signal_columns
            parts[kind].append(_parquet_rows(path, blob, columns, n_rows))
    tables = {}
    for kind, frames in parts.items():
        table = pd.concat([empty[kind], *frames], ignore_index=True)
        try:
            tables[kind] = table.astype({c: _DTYPES[c] for c in table.columns})
        except (TypeError, ValueError) as exc:
            raise _damaged(path, f"its {kind} hold values of another type ({exc})") from None
    last = rows[-1] if rows else (None, None, None, None, None)
    return _Stored(
        tables[INTERSECTIONS],
        tables[CAST],
        None if last[1] is None else str(last[1]),
        None if last[2] is None else str(last[2]),
    )


def _evidence_columns(db: sqlite3.Connection, path: Path) -> set[str] | None:
    """The columns of the evidence table (lower case), None if the map has none; a table of
    that name without the evidence's columns is a one-line error."""
    row = db.execute(
        "SELECT type FROM sqlite_master WHERE name = ? COLLATE NOCASE", (EVIDENCE,)
    ).fetchone()
    if row is None:
        return None
    have = {str(r[1]).lower() for r in db.execute(f"PRAGMA table_info({EVIDENCE})")}
    missing = [c for c in [*_TABLE_COLUMNS, "n_rows"] if c not in have]
    if row[0] != "table" or missing:
        what = f"a {row[0]}" if row[0] != "table" else "a table"
        raise _damaged(
            path,
            f"{what} {EVIDENCE} is there without the evidence's column(s) "
            f"{', '.join(missing) or 'of its own'} (damaged, or another program's)",
        )
    return have


def _parquet_rows(path: Path, blob, columns: list[str], n_rows) -> pd.DataFrame:
    """One update's rows of evidence (Parquet in a blob); what is not such a blob, lacks the
    columns every version wrote, or holds another number of rows than recorded is damage."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    if not isinstance(blob, bytes):
        raise _damaged(path, f"a row holds {type(blob).__name__ if blob is not None else 'NULL'}"
                       " where its Parquet data belongs")  # fmt: skip
    try:
        file = pq.ParquetFile(pa.BufferReader(blob))
        names = file.schema_arrow.names
        table = file.read(columns=[c for c in columns if c in names])
    except (pa.ArrowException, OSError, ValueError) as exc:
        raise _damaged(path, f"a row's data is not Parquet ({exc})") from None
    lacking = [c for c in columns if c not in names and c not in _FILLED]
    if lacking:
        raise _damaged(path, f"a row's data has no column {', '.join(lacking)}")
    if isinstance(n_rows, int) and n_rows != table.num_rows:
        raise _damaged(path, f"a row holds {table.num_rows} rows of data, not {n_rows}")
    return _columns(table, columns).to_pandas()


#: The columns that earlier versions did not store (:func:`_columns` fills them).
_FILLED = frozenset({"satellite", "height_sd", "recording", *_SIGNAL_COLUMNS[1:]})


def _damaged(path: Path, why: str) -> InputError:
    """The one-line error for an evidence table that cannot be used as it is."""
    return InputError(
        f"the evidence table {EVIDENCE} is damaged: {why}",
        where=str(path),
        fix=f"restore the map from its backup ({path.stem}.bak{path.suffix}), or delete the "
        f"table {EVIDENCE} (DROP TABLE {EVIDENCE}) and update again with all the observations",
    )


def _columns(table, columns: list[str]):
    """``columns`` of a stored table. A column that an earlier version did not store is filled
    as that version fitted: the satellite empty; the height error 0 and the recording the
    receiver (evidence kept before position errors were modelled by default counts as cast
    from exact positions); a position or antenna height unknown (NaN)."""
    import pyarrow as pa

    for name in columns:
        if name in table.column_names:
            continue
        if name == "height_sd":
            column = pa.array(np.zeros(len(table)))
        elif name == "recording":
            column = table.column("receiver")
        elif _DTYPES[name] == "float64":
            column = pa.array(np.full(len(table), np.nan))
        else:
            column = pa.nulls(len(table), pa.string())
        table = table.append_column(name, column)
    return table.select(columns)


def _cast_settings(rays: Rays, receiver_heights: ReceiverHeights) -> str:
    """What the rays were cast with besides the DEM (checked by :func:`_check_receiver_heights`):
    the elevation mask, reach and curvature, and where the antenna's height came from."""
    settings = {
        "min_elevation": float(rays.min_elevation),
        "max_elevation": float(rays.max_elevation),
        "max_range": float(rays.max_range),
        "earth_curvature": bool(rays.earth_curvature),
        "receiver_height": receiver_heights.source,
    }
    if receiver_heights.source == "dem":
        settings["antenna_height"] = float(receiver_heights.antenna_height)
    return json.dumps(settings, sort_keys=True)


def _check_cast_with(path: Path, before: _Stored, settings: str) -> None:
    """Refuse to add evidence cast with other settings than the evidence so far: the fit
    would mix them silently. (Evidence of versions that did not record them: not checked.)"""
    if before.cast_with is None or before.cast_with == settings:
        return
    try:
        old = json.loads(before.cast_with)
        if not isinstance(old, dict):
            raise ValueError(before.cast_with)
    except ValueError:
        raise _damaged(path, f"its cast settings are not readable ({before.cast_with!r})") from None
    new = json.loads(settings)
    changed = [
        f"{k} {old.get(k, 'unset')} (the evidence) vs {new.get(k, 'unset')} (now)"
        for k in sorted(set(old) | set(new))
        if old.get(k) != new.get(k)
    ]
    raise InputError(
        "the evidence in the map was cast with other settings: " + "; ".join(changed),
        where=str(path),
        fix="update with the settings the evidence was cast with, or delete the table "
        f"{EVIDENCE} and update again with all the observations",
    )


def _check_receiver_heights(
    cast: pd.DataFrame, dem: StrPath, heights: ReceiverHeights, dem_crs: str | None
) -> None:
    """Refuse a DEM that gives other antenna heights than the evidence was cast from (another
    DEM, or the same one edited): the signals cast before would keep the old heights, the new
    ones get the new, and the fit would mix them silently. Each position cast from is sampled
    again (once)."""
    from .terrain import sample_ground

    if heights.source != "dem":
        return
    known = cast.dropna(subset=["e", "n", "z"]).drop_duplicates(["e", "n"])
    if known.empty:
        return
    e, n, z = (known[c].to_numpy(float) for c in ("e", "n", "z"))
    try:
        now = sample_ground(dem, e, n, assume_crs=dem_crs) + heights.antenna_height
    except InputError as exc:
        now, outside = np.full(len(z), np.nan), str(exc)
    else:
        outside = ""
    off = ~(np.abs(now - z) <= 1e-6)
    if off.any():
        worst = np.nanmax(np.abs(now - z)) if np.isfinite(now - z).any() else np.nan
        by = f", by up to {worst:.2f} m" if np.isfinite(worst) else f" ({outside})"
        raise InputError(
            f"the DEM is not the one the evidence in the map was cast with: it gives other "
            f"receiver heights at {int(off.sum())} of {len(z)} positions{by}",
            where=str(dem),
            fix="give the DEM of the earlier updates, or delete the table "
            f"{EVIDENCE} from the map and update again with all the observations",
        )


def _append_evidence(
    path: Path, layer: str, kind: str, rows: pd.DataFrame, outlines: str, cast_with: str
) -> None:
    """Add ``rows`` of one kind of evidence to the GeoPackage (the table made if new, as an
    attribute table that GDAL and QGIS list), with the footprints' digest and the settings
    they were cast with."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    buffer = pa.BufferOutputStream()
    pq.write_table(pa.Table.from_pandas(rows, preserve_index=False), buffer, compression="zstd")
    with contextlib.closing(sqlite3.connect(path)) as db, db:
        have = _evidence_columns(db, path)
        if have is None:
            db.execute(
                f"CREATE TABLE {EVIDENCE} (id INTEGER PRIMARY KEY AUTOINCREMENT NOT NULL, "
                "layer TEXT NOT NULL, kind TEXT NOT NULL, footprints TEXT, created_utc DATETIME, "
                "n_rows INTEGER, data BLOB, cast_with TEXT)"
            )
            db.execute(
                "INSERT INTO gpkg_contents (table_name, data_type, identifier, description, "
                "last_change) VALUES (?, 'attributes', ?, ?, strftime('%Y-%m-%dT%H:%M:%fZ', "
                "'now'))",
                (EVIDENCE, EVIDENCE, "gnss-citygml update: the evidence, as Parquet"),
            )
        elif "cast_with" not in have:  # (kept by an earlier version)
            db.execute(f"ALTER TABLE {EVIDENCE} ADD COLUMN cast_with TEXT")
        db.execute(
            f"INSERT INTO {EVIDENCE} (layer, kind, footprints, created_utc, n_rows, data, "
            "cast_with) VALUES (?, ?, ?, strftime('%Y-%m-%dT%H:%M:%fZ', 'now'), ?, ?, ?)",
            (layer, kind, outlines, len(rows), buffer.getvalue().to_pybytes(), cast_with),
        )


def _column_types(db: sqlite3.Connection, layer: str) -> dict[str, str]:
    """The layer's columns (lower case, as SQLite compares them) and their types; a column of
    ours that is there with another type is a one-line error."""
    info = {row[1].lower(): row[2] for row in db.execute(f"PRAGMA table_info({quoted(layer)})")}
    for column, kind in COLUMNS.items():
        if column in info and info[column].upper() != kind:
            raise InputError(
                f"the layer has a column {column!r} of type {info[column]}, not {kind}",
                where=f"layer {layer}",
                fix=f"rename that column: the update writes its {column} there",
            )
    return info


def _current_values(path: Path, layer: str, key: str, ids: pd.Series) -> pd.DataFrame:
    """The layer's estimate columns now, by building id (NaN/None where absent)."""
    with contextlib.closing(sqlite3.connect(path)) as db:
        have = _column_types(db, layer)
        present = [c for c in COLUMNS if c in have]
        query = ", ".join(quoted(c) for c in [key, *present])
        rows = db.execute(f"SELECT {query} FROM {quoted(layer)}").fetchall()
    table = pd.DataFrame(rows, columns=["id", *present])
    table["id"] = id_text(pd.Series(table["id"].tolist()))
    return table.set_index("id").reindex(ids.astype(str), columns=list(COLUMNS))


def _key_column(path: Path, layer: str, candidates: list, ids: pd.Series) -> tuple[str, pd.Series]:
    """The column of the layer's table that holds the building ids: the first of
    ``candidates`` (the id field, as read and as asked for; GDAL's ``fid``, the primary key)
    whose values are the buildings' ids; and its values as stored, by id (the rows are
    written by them: ``"001"`` is not ``1``). None is a one-line error, never a silent update
    of nothing."""
    with contextlib.closing(sqlite3.connect(path)) as db:
        info = list(db.execute(f"PRAGMA table_info({quoted(layer)})"))
        columns = {row[1].lower(): row[1] for row in info}
        primary = next((row[1] for row in info if row[5]), None)
        wanted = set(ids.astype(str))
        for name in candidates:
            column = columns.get(str(name).lower()) if name else None
            if column is None and name == "fid":
                column = primary
            if column is None:
                continue
            values = [row[0] for row in db.execute(f"SELECT {quoted(column)} FROM {quoted(layer)}")]
            texts = id_text(pd.Series(values))
            if set(texts) == wanted and not texts.duplicated().any():
                return column, pd.Series(values, index=texts.to_numpy(), dtype=object)
    raise InputError(
        "cannot find the column of the layer that holds the building ids",
        where=f"{path.name}, layer {layer}",
        fix="name it with --id-field",
    )


def _new_values(
    estimate: pd.DataFrame, current: pd.DataFrame, min_signals: int
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """The values to write (every column of :data:`COLUMNS`, by id) and the per-building
    table of :class:`UpdateResult`."""
    ids = estimate["id"].astype(str).to_numpy()
    new = pd.DataFrame({col: estimate[src].to_numpy() for col, src in _FROM.items()}, index=ids)
    enough = new["n_signals"].to_numpy() >= min_signals
    old = current.reindex(pd.Index(ids))
    same = np.ones(len(ids), dtype=bool)
    for column in _FROM:
        same &= _equal(old[column].to_numpy(), new[column].to_numpy(), column)
    changed = enough & ~same
    now = dt.datetime.now(dt.UTC)
    stamp = now.strftime("%Y-%m-%dT%H:%M:%S.") + f"{now.microsecond // 1000:03d}Z"  # GeoPackage
    new["updated_utc"] = np.where(changed, stamp, old["updated_utc"].to_numpy(dtype=object))
    skipped = np.where(enough, "", f"fewer than {min_signals} signals")
    before = pd.to_numeric(old["height_gnss"], errors="coerce").to_numpy(float)
    after = np.where(changed, new["height_gnss"].to_numpy(float), before)
    table = pd.DataFrame(
        {"id": ids, "before": before, "after": after, "changed": changed, "skipped": skipped}
    )
    return new.reset_index(names="id"), table


def _equal(old: np.ndarray, new: np.ndarray, column: str) -> np.ndarray:
    """Element-wise: the layer's value equals the new one (NaN/None equal to each other)."""
    kind = COLUMNS[column]
    if kind == "REAL":
        a, b = pd.to_numeric(old, errors="coerce").astype(float), new.astype(float)
        return (a == b) | (np.isnan(a) & np.isnan(b))
    if kind in ("INTEGER", "BOOLEAN"):
        a = pd.to_numeric(old, errors="coerce").astype(float)
        return a == new.astype(float)
    return np.array([o == n for o, n in zip(old, new, strict=True)])


def _write_columns(path: Path, layer: str, key: str, values: pd.DataFrame) -> None:
    """Add the missing columns to the layer's table and write ``values`` by building id."""
    with contextlib.closing(connect(path)) as db, db:
        info = _column_types(db, layer)
        for column, kind in COLUMNS.items():
            if column not in info:
                db.execute(f"ALTER TABLE {quoted(layer)} ADD COLUMN {quoted(column)} {kind}")
        columns = list(COLUMNS)
        assignments = ", ".join(f"{quoted(c)} = ?" for c in columns)
        rows = [
            [_sql(row[c]) for c in columns] + [_sql(row["id"])] for row in values.to_dict("records")
        ]
        done = db.executemany(
            f"UPDATE {quoted(layer)} SET {assignments} WHERE {quoted(key)} = ?", rows
        ).rowcount
        if done != len(rows):  # (the key column was checked: a bug if this happens)
            raise InputError(
                f"{len(rows)} buildings to update, {done} rows found by {key!r}",
                where=f"layer {layer}",
                fix="check that the ids are unique, or name the id column with --id-field",
            )
        db.execute(
            "UPDATE gpkg_contents SET last_change = strftime('%Y-%m-%dT%H:%M:%fZ', 'now') "
            "WHERE table_name = ?",
            (layer,),
        )


def _sql(value):
    """A value as SQLite takes it (numpy scalars, NaN -> NULL)."""
    if value is None or (isinstance(value, float) and np.isnan(value)):
        return None
    if isinstance(value, np.generic):
        return value.item()
    return value


def _backup_path(path: Path) -> Path:
    """Where the map as it was is kept: ``MAP.bak.gpkg``, a GeoPackage QGIS opens."""
    return path.with_name(path.stem + ".bak" + path.suffix)


def _backup(path: Path) -> Path:
    """``MAP.bak.gpkg``: the map as it was, written atomically beside it."""
    target = _backup_path(path)
    with atomic_path(target, overwrite=True) as tmp:
        shutil.copyfile(path, tmp)
    return target
