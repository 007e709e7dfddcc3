"""SQL on a GeoPackage's own tables, where GDAL's layer interface cannot do the job: a style row
(:mod:`gnss_citygml.files.styles`), columns updated in place and the evidence of
:mod:`gnss_citygml.update`."""

from __future__ import annotations

import contextlib
import re
import sqlite3
from collections.abc import Iterator

from ..errors import InputError, first_line
from .paths import StrPath, write_error

__all__ = [
    "check_geopackage",
    "check_no_triggers",
    "check_table_layer",
    "connect",
    "has_table",
    "quoted",
    "refused",
]

#: A statement of a trigger's body that writes a table, and the table (quoted or not).
_WRITES = re.compile(
    r"\b(?:INSERT(?:\s+OR\s+\w+)?\s+INTO|REPLACE\s+INTO|DELETE\s+FROM|UPDATE(?:\s+OR\s+\w+)?)"
    r"""\s+("(?:[^"]|"")*"|`[^`]*`|\[[^\]]*\]|'(?:[^']|'')*'|[\w$]+)""",
    re.IGNORECASE,
)
_BEGIN = re.compile(r"\bBEGIN\b", re.IGNORECASE)
_RAISE = re.compile(r"\bRAISE\s*\(", re.IGNORECASE)
#: SQL's tokens that hide statements from a search: a quoted identifier (kept: it may hold a
#: quote of the other kind, as a layer named ``foot'prints``), a string (a message's words are
#: no statement) and a comment (none either, and it may hold a lone quote).
_TOKENS = re.compile(
    r"""("(?:[^"]|"")*"|`[^`]*`|\[[^\]]*\])|('(?:[^']|'')*')|--[^\n]*|/\*.*?(?:\*/|$)""",
    re.DOTALL,
)
#: The GeoPackage tables whose constraints the standard checks with RAISE-only triggers.
_CHECKED = {"gpkg_tile_matrix", "gpkg_metadata_reference"}
#: The body of such a check (its strings read as ``'_'``): one RAISE(ABORT) on a condition.
_CHECK = re.compile(r"\s*SELECT\s+RAISE\s*\(\s*ABORT\s*,\s*'_'\s*\)\s*WHERE\b[^;]+;\s*END\s*", re.I)


#: The first bytes of every SQLite database (and so of every GeoPackage).
_SQLITE = b"SQLite format 3\x00"


def check_geopackage(path: StrPath, *, empty_ok: bool = True) -> None:
    """Refuse a file named .gpkg that is no SQLite database (a text file, another format, an
    empty file unless ``empty_ok``) in one line: SQLite's "file is not a database" surfaced as
    an internal error or as a lock held by another program."""
    with open(path, "rb") as file:
        head = file.read(len(_SQLITE))
    if head != _SQLITE and (head or not empty_ok):
        raise InputError(
            "not a GeoPackage: the file is " + ("empty" if not head else "no SQLite database"),
            where=str(path),
            fix="give a GeoPackage (.gpkg, as QGIS or ogr2ogr -f GPKG write), or another file name",
        )


def check_no_triggers(path: StrPath) -> None:
    """Refuse a GeoPackage that holds a trigger other than GeoPackage's and GDAL's own,
    before anything writes to it: a user's trigger runs on the writes of the toolkit (and of
    GDAL, which cannot be confined) and could change other tables silently, or abort.

    Known triggers are told by what they do, not only by their name (which anyone can
    give): an R-tree index's (``rtree_T_...``) writes only an R-tree table of its table T;
    GDAL's feature count (``trigger_..._feature_count_T``) only ``gpkg_ogr_contents``; the
    standard's checks on ``gpkg_tile_matrix`` and ``gpkg_metadata_reference`` write nothing
    and are one ``SELECT RAISE(ABORT, '...') WHERE ...`` (a RAISE(IGNORE) would drop a row
    silently, one without a condition every row). What no reading of SQL can tell (a check
    whose condition is always true) the writer finds by reading back what it wrote.
    """
    check_geopackage(path)
    with contextlib.closing(sqlite3.connect(path)) as db:
        rows = db.execute(
            "SELECT name, tbl_name, sql FROM sqlite_master WHERE type = 'trigger' ORDER BY name"
        ).fetchall()
    strange = [str(name) for name, table, sql in rows if not _known(name, table, sql or "")]
    if strange:
        names = ", ".join(repr(n) for n in strange[:5]) + (" ..." if len(strange) > 5 else "")
        raise InputError(
            f"the GeoPackage has triggers of its own ({names}), which would run on this "
            "command's writes",
            where=str(path),
            fix="drop them (DROP TRIGGER name, e.g. in sqlite3 or QGIS's DB Manager) in a copy, "
            "or write to another file",
        )


def _known(name: str, table: str, sql: str) -> bool:
    """Whether a trigger is one of GeoPackage's or GDAL's own (see :func:`check_no_triggers`)."""
    body = sql[m.end() :] if (m := _BEGIN.search(sql)) else sql
    body = _TOKENS.sub(_token, body)
    written = {_unquoted(t).lower() for t in _WRITES.findall(body)}
    raises = bool(_RAISE.search(body))
    name, table = name.lower(), table.lower()
    if name.startswith(f"rtree_{table}_"):
        return not raises and all(t.startswith(f"rtree_{table}_") for t in written)
    if name in (f"trigger_insert_feature_count_{table}", f"trigger_delete_feature_count_{table}"):
        return not raises and written <= {"gpkg_ogr_contents"}
    return table in _CHECKED and name.startswith(table) and bool(_CHECK.fullmatch(body))


def _token(match: re.Match) -> str:
    """An identifier as it is, a string as ``'_'`` (a table so named still counts as written),
    a comment as a space."""
    return match.group(1) or ("'_'" if match.group(2) else " ")


def _unquoted(name: str) -> str:
    if name[:1] in "\"'`[":
        return name[1:-1].replace(name[0] * 2, name[0]) if name[0] != "[" else name[1:-1]
    return name


def check_table_layer(path: StrPath, layer: str) -> None:
    """Refuse a layer that is not a table of the GeoPackage (a view: its rows cannot take
    columns or values of their own)."""
    with contextlib.closing(sqlite3.connect(path)) as db:
        row = db.execute(
            "SELECT type FROM sqlite_master WHERE lower(name) = lower(?) "
            "AND type IN ('table', 'view')",
            (layer,),
        ).fetchone()
    if row is not None and row[0] != "table":
        raise InputError(
            f"the layer {layer!r} is a {row[0]}, not a table: its rows cannot be updated",
            where=str(path),
            fix="give the layer of the table it shows (--layer)",
        )


@contextlib.contextmanager
def refused(path: StrPath) -> Iterator[None]:
    """Turn SQLite's refusal of a write to the GeoPackage ``path`` (a constraint of the
    user's schema: NOT NULL, UNIQUE, CHECK; a trigger's RAISE) into a one-line error; a full
    disk is left to :func:`gnss_citygml.files.paths.atomic_path`."""
    try:
        yield
    except sqlite3.DatabaseError as exc:
        if write_error(exc, str(path)) is not None:
            raise
        raise InputError(
            f"the GeoPackage refused the write: {first_line(exc)}",
            where=str(path),
            fix="drop the constraint or trigger of the layer that refuses it, or write to "
            "another file",
        ) from None


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
    """Whether the database has a table ``name``, in any letter case (as SQLite names tables:
    ``Layer_Styles`` is ``layer_styles``)."""
    query = "SELECT count(*) FROM sqlite_master WHERE type = 'table' AND name = ? COLLATE NOCASE"
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
