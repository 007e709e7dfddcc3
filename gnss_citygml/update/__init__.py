"""Batch updates of a GeoPackage map as new GNSS data arrives, without ever risking the map.

:func:`update_map` adds or updates the estimate columns (:data:`COLUMNS`) of a footprint layer
of a GeoPackage, for the buildings with enough signals. Every other column, feature, layer and
style of the file is kept, and the layer's feature ids do not change: the columns are written
with SQL on the layer's own table, by building id.

- **Never a damaged map.** The work is done on a copy beside the map, which is renamed over it
  only when complete (:func:`gnss_citygml.files.paths.atomic_path`); the map as it was is kept as
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
import os
import shutil
import sqlite3
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from ..errors import InputError
from ..files.geopackage import (
    check_geopackage,
    check_no_triggers,
    check_table_layer,
    connect,
    quoted,
    refused,
)
from ..files.ids import id_text
from ..files.paths import StrPath, atomic_path, check_not_input, input_file
from ..settings import Estimator, Rays, ReceiverHeights
from .evidence import (
    CAST,
    EVIDENCE,
    EVIDENCE_COLUMNS,
    INTERSECTIONS,
    SIGNAL_COLUMNS,
    append_evidence,
    cast_settings,
    check_cast_with,
    check_receiver_heights,
    read_evidence,
    signal_keys,
)

__all__ = ["COLUMNS", "EVIDENCE", "UpdateResult", "update_map"]

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
    from ..files.ids import id_field as source_id_field
    from ..jobs import read_buildings
    from ..observations import read_observation_files
    from ..pipeline import fit_heights
    from ..stages import in_mask, intersections, receivers

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
        from ..compare import check_truth
        from ..files.ids import with_id_field
        from ..files.tables import read_table
        from ..pipeline import Run
        from ..report import check_report, write_report

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
    # the phones' levels and the mixture learn from every signal cast (the open sky)
    sky_needed = estimator.levels_phones or estimator.signal_model == "mixture"
    before = read_evidence(path, name, with_signals=report is not None or sky_needed)
    settings = cast_settings(rays, receiver_heights)
    check_cast_with(path, before, settings)
    check_receiver_heights(before.cast, dem, receiver_heights, dem_crs)
    stored, cast_before = before.intersections, before.cast
    gone = ~stored["building"].isin(buildings["id"].astype(str)).to_numpy()
    stored = stored[~gone].reset_index(drop=True)  # footprints deleted since: their evidence
    obs = in_mask(read_observation_files(observations), rays)  # each signal once (it warns)
    keys = signal_keys(obs)
    unseen = ~keys.isin(cast_before["signal_key"]).to_numpy()
    new = obs[unseen].reset_index(drop=True)
    fresh, signals = stored.iloc[:0], pd.DataFrame(columns=SIGNAL_COLUMNS)
    if len(new):
        say("casting", 0.25)
        rx = receivers(new, dem, heights=receiver_heights, grid_dir=grid_dir, dem_crs=dem_crs)
        rx["signal_key"] = signal_keys(rx).to_numpy()
        cast = intersections(rx, buildings, rays=rays)
        fresh = cast.assign(
            signal_key=rx["signal_key"].to_numpy()[cast["signal"].to_numpy()],
            building=cast["building"].astype(str),
            satellite=cast["satellite"].astype(str),
            recording=cast["recording"].astype(str),
        )[EVIDENCE_COLUMNS]
        signals = rx.drop_duplicates("signal_key")[SIGNAL_COLUMNS]
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
    # every signal cast, once each (a damaged store's repeats would break the lookups), where
    # the open sky or the report needs them
    everything = signals.iloc[:0]
    if sky_needed or report is not None:
        everything = pd.concat([cast_before, signals], ignore_index=True)
        everything = everything.drop_duplicates("signal_key", ignore_index=True)
    sky = None
    if sky_needed:
        signal_elevations = everything.set_index("signal_key")["elevation"]
        model["elevation"] = signal_elevations.reindex(evidence["signal_key"]).to_numpy()
        sky = everything[~everything["signal_key"].isin(evidence["signal_key"])]
    estimate, classifier = fit_heights(model, buildings, estimator, open_sky=sky)
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
        run = Run(
            heights=with_id_field(estimate, id_column),
            receivers=everything.drop(columns="z"),
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
            append_evidence(tmp, name, INTERSECTIONS, fresh, outlines, settings)
        if len(signals):
            append_evidence(tmp, name, CAST, signals, outlines, settings)
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
