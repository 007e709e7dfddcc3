"""SQL on a GeoPackage's own tables, where GDAL's layer interface cannot do the job: a style row
(:mod:`gnss_citygml.styles`), columns updated in place and the evidence of
:mod:`gnss_citygml.update`."""

from __future__ import annotations

import sqlite3

from .paths import StrPath

__all__ = ["connect", "has_table", "quoted"]


def connect(path: StrPath) -> sqlite3.Connection:
    """A connection to a GeoPackage with the SQL functions its R-tree triggers call
    (``ST_IsEmpty``, ``ST_MinX`` ...), which GDAL defines and plain SQLite lacks: an UPDATE of
    a layer's table compiles those triggers even when no geometry changes."""
    db = sqlite3.connect(path)
    db.create_function("ST_IsEmpty", 1, _is_empty, deterministic=True)
    for k, name in enumerate(("ST_MinX", "ST_MinY", "ST_MaxX", "ST_MaxY")):
        db.create_function(name, 1, lambda blob, k=k: _bounds(blob)[k], deterministic=True)
    return db


def has_table(db: sqlite3.Connection, name: str) -> bool:
    """Whether the database has a table ``name``."""
    query = "SELECT count(*) FROM sqlite_master WHERE type = 'table' AND name = ?"
    return bool(db.execute(query, (name,)).fetchone()[0])


def quoted(name: str) -> str:
    """An SQL identifier, quoted.

    >>> quoted('a"b')
    '"a""b"'
    """
    return '"' + name.replace('"', '""') + '"'


def _is_empty(blob: bytes | None) -> int | None:
    """GeoPackage geometry blob: its header's empty flag (bit 4 of the flags byte)."""
    return None if blob is None else int(bool(blob[3] & 0x10))


def _bounds(blob: bytes | None) -> tuple[float, ...]:
    """The bounds of a GeoPackage geometry blob (its WKB after the header and envelope)."""
    import shapely

    if blob is None:
        return (float("nan"),) * 4
    envelope = (0, 32, 48, 48, 64)[(blob[3] >> 1) & 0x07]
    return tuple(shapely.from_wkb(bytes(blob[8 + envelope :])).bounds)
