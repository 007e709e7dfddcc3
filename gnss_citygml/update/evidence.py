"""The evidence a GeoPackage map keeps of its updates (:mod:`gnss_citygml.update`): the table
``gnss_evidence``, one row per update and kind, its rows as Parquet.

Every intersection cast so far and every signal cast (by its key, a hash of receiver, time and
satellite) are kept, keyed by the layer as SQLite names it, with what they were cast against
(the footprints' digest) and with (the cast settings; each signal's antenna height ``z``): a
later update checks its DEM and settings against them (:func:`check_cast_with`,
:func:`check_receiver_heights`) and is refused rather than mixed. A damaged table is one error
line naming the map and the fix, read and checked before any work (:func:`read_evidence`).
"""

from __future__ import annotations

import contextlib
import json
import sqlite3
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from ..errors import InputError, user_text
from ..files.paths import StrPath
from ..files.tables import check_parquet_metadata
from ..files.userjson import parse_json
from ..settings import Rays, ReceiverHeights

__all__ = [
    "CAST",
    "EVIDENCE",
    "EVIDENCE_COLUMNS",
    "INTERSECTIONS",
    "SIGNAL_COLUMNS",
    "Stored",
    "append_evidence",
    "cast_settings",
    "check_cast_with",
    "check_receiver_heights",
    "read_evidence",
    "signal_keys",
]

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

#: The evidence's columns (the intersections table's, the signal by its key).
EVIDENCE_COLUMNS = [
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
SIGNAL_COLUMNS = [
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


def signal_keys(rows: pd.DataFrame) -> pd.Series:
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
class Stored:
    """A layer's evidence so far: its intersections, the signals cast, and what the last
    update cast them against (the footprints' digest) and with (:func:`cast_settings`)."""

    intersections: pd.DataFrame
    cast: pd.DataFrame
    outlines: str | None
    cast_with: str | None


def read_evidence(path: Path, layer: str, *, with_signals: bool) -> Stored:
    """The evidence of ``layer`` (every row of the layer in any letter case, as SQLite
    compares names), in the order the updates added it; of the signals cast, their keys and
    positions (all their columns ``with_signals``, for the report). A damaged table is a
    one-line error (:func:`_damaged`), before any work."""
    signal_columns = SIGNAL_COLUMNS if with_signals else ["signal_key", "e", "n", "z"]
    empty = {
        kind: pd.DataFrame({c: pd.Series(dtype=_DTYPES[c]) for c in columns})
        for kind, columns in ((INTERSECTIONS, EVIDENCE_COLUMNS), (CAST, signal_columns))
    }
    try:
        with contextlib.closing(sqlite3.connect(path)) as db:
            have = _evidence_columns(db, path)
            if have is None:
                return Stored(empty[INTERSECTIONS], empty[CAST], None, None)
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
            columns = EVIDENCE_COLUMNS if kind == INTERSECTIONS else signal_columns
            parts[kind].append(_parquet_rows(path, blob, columns, n_rows))
    tables = {}
    for kind, frames in parts.items():
        table = pd.concat([empty[kind], *frames], ignore_index=True)
        try:
            tables[kind] = table.astype({c: _DTYPES[c] for c in table.columns})
        except (TypeError, ValueError) as exc:
            raise _damaged(path, f"its {kind} hold values of another type ({exc})") from None
    last = rows[-1] if rows else (None, None, None, None, None)
    return Stored(
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
        check_parquet_metadata(file.schema_arrow.metadata, str(path))
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
_FILLED = frozenset({"satellite", "height_sd", "recording", *SIGNAL_COLUMNS[1:]})


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


def cast_settings(rays: Rays, receiver_heights: ReceiverHeights) -> str:
    """What the rays were cast with besides the DEM (checked by :func:`check_receiver_heights`):
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


def check_cast_with(path: Path, before: Stored, settings: str) -> None:
    """Refuse to add evidence cast with other settings than the evidence so far: the fit
    would mix them silently. (Evidence of versions that did not record them: not checked.)"""
    if before.cast_with is None or before.cast_with == settings:
        return
    try:
        old = parse_json(before.cast_with)
        if not isinstance(old, dict):
            raise ValueError(before.cast_with)
    except ValueError:  # (NotJSON is a ValueError)
        raise _damaged(
            path, f"its cast settings are not readable ({user_text(before.cast_with)})"
        ) from None
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


def check_receiver_heights(
    cast: pd.DataFrame, dem: StrPath, heights: ReceiverHeights, dem_crs: str | None
) -> None:
    """Refuse a DEM that gives other antenna heights than the evidence was cast from (another
    DEM, or the same one edited): the signals cast before would keep the old heights, the new
    ones get the new, and the fit would mix them silently. Each position cast from is sampled
    again (once; :func:`~gnss_citygml.terrain.check_same_ground`)."""
    from ..terrain import check_same_ground

    if heights.source != "dem":
        return
    known = cast.dropna(subset=["e", "n", "z"]).drop_duplicates(["e", "n"])
    e, n, z = (known[c].to_numpy(float) for c in ("e", "n", "z"))
    check_same_ground(
        e,
        n,
        z - heights.antenna_height,
        dem,
        assume_crs=dem_crs,
        what="the DEM is not the one the evidence in the map was cast with",
        fix="give the DEM of the earlier updates, or delete the table "
        f"{EVIDENCE} from the map and update again with all the observations",
    )


def append_evidence(
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
