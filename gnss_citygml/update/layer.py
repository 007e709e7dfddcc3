"""The map's footprint layer as SQL sees it: its table's name, the column of building ids, the
estimate columns (:data:`COLUMNS`, and on ``estimate``'s heights layer its own of
:data:`ESTIMATE_COLUMNS`) as they are and as they will be written, by building id.
The columns are written with SQL on the layer's own table, so every other column, feature and
style stays, and the feature ids do not change."""

from __future__ import annotations

import contextlib
import datetime as dt
import sqlite3
from pathlib import Path

import numpy as np
import pandas as pd

from ..errors import InputError
from ..files.geopackage import connect, quoted
from ..files.ids import id_text

__all__ = ["COLUMNS", "current_values", "key_column", "layer_name", "new_values", "write_columns"]

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

#: The columns of ``estimate``'s heights layer that come from the fit besides :data:`COLUMNS`
#: (each from the estimate's column of its name; ``ground`` the DEM's the heights stand on),
#: with their GeoPackage types. On that layer
#: an update writes them too: left as they were, a row would say ``converged`` 0 beside
#: ``status`` ok and an old height, which the layer's style colours by and ``convert`` writes.
ESTIMATE_COLUMNS = {
    "ground": "REAL",
    "height": "REAL",
    "relative_height": "REAL",
    "a": "REAL",
    "b": "REAL",
    "c": "REAL",
    "d": "REAL",
    "iterations": "INTEGER",
    "status": "TEXT",
}

#: The columns that together make a layer ``estimate``'s heights layer, with one of
#: :data:`ESTIMATE_OWN` (on a map, columns of these names one by one may be the user's own, and
#: are left alone).
ESTIMATE_LAYER = ("converged", "height", "status")
#: Columns only ``estimate`` writes: one of them beside :data:`ESTIMATE_LAYER` is enough, so
#: that its layer with a column dropped (relative_height, say) is still updated whole.
ESTIMATE_OWN = ("relative_height", "iterations")

_KINDS = {**COLUMNS, **ESTIMATE_COLUMNS}


def layer_name(path: Path, layer: str | None) -> str:
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
    ours (:func:`_written`) that is there with another type is a one-line error."""
    info = {row[1].lower(): row[2] for row in db.execute(f"PRAGMA table_info({quoted(layer)})")}
    for column, kind in _written(info).items():
        if column in info and info[column].upper() != kind:
            raise InputError(
                f"the layer has a column {column!r} of type {info[column]}, not {kind}",
                where=f"layer {layer}",
                fix=f"rename that column: the update writes its {column} there",
            )
    return info


def _written(info: dict[str, str]) -> dict[str, str]:
    """The columns an update writes on a layer of columns ``info``: :data:`COLUMNS`, and on
    ``estimate``'s heights layer (:data:`ESTIMATE_LAYER` and one of :data:`ESTIMATE_OWN`)
    those of :data:`ESTIMATE_COLUMNS` it has, so that every row agrees with itself."""
    if not set(ESTIMATE_LAYER) <= set(info) or not set(ESTIMATE_OWN) & set(info):
        return dict(COLUMNS)
    return {**COLUMNS, **{c: kind for c, kind in ESTIMATE_COLUMNS.items() if c in info}}


def current_values(path: Path, layer: str, key: str, ids: pd.Series) -> pd.DataFrame:
    """The columns the update writes on the layer (:func:`_written`) as they are now, by
    building id (NaN/None where absent)."""
    with contextlib.closing(sqlite3.connect(path)) as db:
        have = _column_types(db, layer)
        written = list(_written(have))
        present = [c for c in written if c in have]
        query = ", ".join(quoted(c) for c in [key, *present])
        rows = db.execute(f"SELECT {query} FROM {quoted(layer)}").fetchall()
    table = pd.DataFrame(rows, columns=["id", *present])
    table["id"] = id_text(pd.Series(table["id"].tolist()))
    return table.set_index("id").reindex(ids.astype(str), columns=written)


def key_column(path: Path, layer: str, candidates: list, ids: pd.Series) -> tuple[str, pd.Series]:
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


def new_values(
    estimate: pd.DataFrame, current: pd.DataFrame, min_signals: int
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """The values to write (every column of ``current``, :func:`current_values`'s, by id) and
    the per-building table of :class:`~gnss_citygml.update.UpdateResult`."""
    ids = estimate["id"].astype(str).to_numpy()
    fitted = [c for c in current.columns if c != "updated_utc"]
    new = pd.DataFrame({c: estimate[_FROM.get(c, c)].to_numpy() for c in fitted}, index=ids)
    enough = new["n_signals"].to_numpy() >= min_signals
    old = current.reindex(pd.Index(ids))
    same = np.ones(len(ids), dtype=bool)
    for column in fitted:
        same &= _equal(old[column].to_numpy(), new[column].to_numpy(), column)
    changed = enough & ~same
    now = dt.datetime.now(dt.UTC)
    stamp = now.strftime("%Y-%m-%dT%H:%M:%S.") + f"{now.microsecond // 1000:03d}Z"  # GeoPackage
    new["updated_utc"] = np.where(changed, stamp, old["updated_utc"].to_numpy(dtype=object))
    skipped = np.where(enough, "", f"fewer than {min_signals} signals")
    # estimate's layer had its heights in height before an update added height_gnss
    was = old["height"] if "height" in old.columns else old["height_gnss"]
    before = pd.to_numeric(was, errors="coerce").to_numpy(float)
    after = np.where(changed, new["height_gnss"].to_numpy(float), before)
    table = pd.DataFrame(
        {"id": ids, "before": before, "after": after, "changed": changed, "skipped": skipped}
    )
    return new.reset_index(names="id"), table


def _equal(old: np.ndarray, new: np.ndarray, column: str) -> np.ndarray:
    """Element-wise: the layer's value equals the new one (NaN/None equal to each other)."""
    kind = _KINDS[column]
    if kind == "REAL":
        a, b = pd.to_numeric(old, errors="coerce").astype(float), new.astype(float)
        return (a == b) | (np.isnan(a) & np.isnan(b))
    if kind in ("INTEGER", "BOOLEAN"):
        a = pd.to_numeric(old, errors="coerce").astype(float)
        return a == new.astype(float)
    return np.array([o == n for o, n in zip(old, new, strict=True)])


def write_columns(path: Path, layer: str, key: str, values: pd.DataFrame) -> None:
    """Add the missing columns of :data:`COLUMNS` to the layer's table and write ``values``
    (:func:`new_values`'s) by building id."""
    with contextlib.closing(connect(path)) as db, db:
        info = _column_types(db, layer)
        for column, kind in COLUMNS.items():
            if column not in info:
                db.execute(f"ALTER TABLE {quoted(layer)} ADD COLUMN {quoted(column)} {kind}")
        columns = list(_written(info))
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
