"""Where the official schemas are: the schema folder, the CityGML 2.0 tree, CityJSON's files
(CityJSON 2.0's by default the copy bundled with the package), the 3D Tiles 1.1 folder (by
default the copy bundled with the package)."""

from __future__ import annotations

import gzip
import json
import os
import re
from functools import lru_cache
from pathlib import Path

from ..errors import InputError, first_line, user_text
from ..files.paths import StrPath

__all__ = [
    "BUNDLED_CITYJSON_SCHEMAS",
    "BUNDLED_TILES3D_SCHEMAS",
    "PACKED_SCHEMAS",
    "SCHEMA_DIR_ENV",
    "TILES3D_SCHEMA_DIR_ENV",
    "TILES3D_SCHEMA_SUBFOLDER",
    "citygml_schema_folder",
    "cityjson_schema_file",
    "has_schema",
    "packed_schemas",
    "schema_bytes",
    "schema_folder",
    "tiles3d_schema_folder",
    "tiles3d_schema_source",
]

#: Environment variable naming the folder of the official schemas.
SCHEMA_DIR_ENV = "GNSS_CITYGML_SCHEMA_DIR"
#: Environment variable naming the folder of the 3D Tiles 1.1 JSON schemas (the folder
#: ``specification/schema`` of github.com/CesiumGS/3d-tiles, holding ``tileset.schema.json``).
TILES3D_SCHEMA_DIR_ENV = "GNSS_CITYGML_3DTILES_SCHEMA_DIR"
#: Where the 3D Tiles 1.1 JSON schemas are by default: this sub-folder of the schema folder.
TILES3D_SCHEMA_SUBFOLDER = "3dtiles-1.1"
#: The file a schema set shipped with the package is packed in (``tools/pack_schemas.py``): a
#: gzip-compressed JSON object holding each schema's text, unchanged, under its path relative
#: to the set's folder. One small file instead of 25 (or 617 kB of CityJSON's inlined schemas).
PACKED_SCHEMAS = "schemas.json.gz"
#: The 3D Tiles 1.1 JSON schemas shipped with the package (the files validation needs, with
#: their licence and source: README.md there).
BUNDLED_TILES3D_SCHEMAS = Path(__file__).resolve().parents[1] / "data" / TILES3D_SCHEMA_SUBFOLDER
#: The CityJSON 2.0.2 and CityJSONFeature 2.0.2 schemas shipped with the package, each one file
#: with its references inlined (CC0; README.md there): the CityJSON 2.0 files' default.
BUNDLED_CITYJSON_SCHEMAS = Path(__file__).resolve().parents[1] / "data" / "cityjson-2.0.2"


@lru_cache(maxsize=8)
def packed_schemas(folder: Path) -> dict[str, bytes]:
    """The schemas packed in ``folder`` (:data:`PACKED_SCHEMAS`) by relative path, {} if none;
    a pack that cannot be read (a user's folder may hold any file of that name) is an
    InputError naming it."""
    pack = folder / PACKED_SCHEMAS
    if not pack.is_file():
        return {}
    try:
        texts = json.loads(gzip.decompress(pack.read_bytes()))
        if not isinstance(texts, dict) or not all(isinstance(t, str) for t in texts.values()):
            raise TypeError("not a JSON object of schema texts")
    except (OSError, EOFError, ValueError, TypeError) as exc:  # (BadGzipFile: an OSError)
        raise unusable_schema(exc, pack) from None
    return {relative: text.encode("utf-8") for relative, text in texts.items()}


def has_schema(folder: Path, name: str) -> bool:
    """Whether ``folder`` holds the schema ``name`` (a relative path): as a file, or packed."""
    return (folder / name).is_file() or name in packed_schemas(folder)


def schema_bytes(path: Path) -> bytes:
    """A schema's bytes: the file at ``path``, else its text packed in the folder it names."""
    if path.is_file():
        return path.read_bytes()
    return packed_schemas(path.parent)[path.name]


def schema_folder(schema_dir: StrPath | None) -> Path | None:
    """The schema folder given, else ``$GNSS_CITYGML_SCHEMA_DIR`` (None if neither)."""
    if schema_dir is None:
        schema_dir = os.environ.get(SCHEMA_DIR_ENV) or None
        if schema_dir is None:
            return None
    folder = Path(schema_dir)
    if not folder.is_dir():
        raise InputError(
            "schema folder not found",
            where=str(folder),
            fix=f"give the folder of the official schemas (--schema-dir, ${SCHEMA_DIR_ENV})",
        )
    return folder


def citygml_schema_folder(schema_dir: Path | None) -> Path:
    """The folder with ``schemas.opengis.net``: ``schema_dir`` when it has it, else citysmith's."""
    if schema_dir is not None and (schema_dir / "schemas.opengis.net/citygml/2.0").is_dir():
        return schema_dir
    try:
        from citysmith.schema import bundled_schema_dir
    except ImportError:
        raise InputError(
            "the CityGML 2.0 schemas are not available",
            where="validate",
            fix="pip install citysmith (bundles the official schemas), or give --schema-dir "
            "holding a schemas.opengis.net tree",
        ) from None
    return Path(bundled_schema_dir())


def cityjson_schema_file(folder: Path, version: str | None, kind: str) -> Path | None:
    """The newest ``<kind>.min.schema.json`` for ``version`` (any version if None)."""
    name = f"{kind}.min.schema.json"
    direct = folder / name
    if has_schema(folder, name):
        text = schema_bytes(direct)[:2000].decode("utf-8", errors="replace")
        found = re.search(r"/schemas/(\d+\.\d+)", text)
        return direct if version is None or (found and found.group(1) == version) else None
    candidates = [
        p
        for base in (folder, folder / "cityjson")
        for p in base.glob(f"*/{name}")
        if version is None or p.parent.name == version or p.parent.name.startswith(version + ".")
    ]
    if not candidates:
        return None
    return max(candidates, key=lambda p: tuple(int(v) for v in re.findall(r"\d+", p.parent.name)))


def tiles3d_schema_folder(schema_dir: StrPath | None = None) -> Path:
    """The folder of the 3D Tiles 1.1 JSON schemas, the one holding ``tileset.schema.json``.

    A folder named for them must hold them: ``$GNSS_CITYGML_3DTILES_SCHEMA_DIR``, or a
    ``schema_dir`` that does not exist (an :class:`InputError` naming the folders looked at).
    A general schema folder, ``schema_dir`` (the ``--schema-dir`` of the command line) else
    ``$GNSS_CITYGML_SCHEMA_DIR``, is used when it holds them, itself or its sub-folder
    ``3dtiles-1.1``; otherwise (it holds the CityJSON schemas only, say) and by default, the
    copy bundled with the package, :data:`BUNDLED_TILES3D_SCHEMAS`.
    """
    if schema_dir is not None:  # the folder itself, or the schema folder holding it
        tried = [Path(schema_dir), Path(schema_dir) / TILES3D_SCHEMA_SUBFOLDER]
        required = not Path(schema_dir).is_dir()
    elif os.environ.get(TILES3D_SCHEMA_DIR_ENV):
        tried, required = [Path(os.environ[TILES3D_SCHEMA_DIR_ENV])], True
    else:
        base = os.environ.get(SCHEMA_DIR_ENV)
        tried, required = ([Path(base) / TILES3D_SCHEMA_SUBFOLDER] if base else []), False
    for folder in tried:
        if has_schema(folder, "tileset.schema.json"):
            return folder
    if not required:
        return BUNDLED_TILES3D_SCHEMAS
    raise InputError(
        "the 3D Tiles 1.1 JSON schemas (tileset.schema.json and the files it refers to) "
        "are not found",
        where=", ".join(map(str, tried)),
        fix=f"give their folder (--schema-dir, ${TILES3D_SCHEMA_DIR_ENV}), the folder "
        "specification/schema of github.com/CesiumGS/3d-tiles (version 1.1), or leave both "
        "unset to use the copy bundled with gnss-citygml",
    )


def tiles3d_schema_source(folder: Path) -> str:
    """How a report names the schema folder in use: the folder, and whether it is the copy
    bundled with the package."""
    bundled = folder.resolve() == BUNDLED_TILES3D_SCHEMAS.resolve()
    return f"{folder} (bundled with gnss-citygml)" if bundled else str(folder)


def unusable_schema(exc: Exception, where: StrPath) -> InputError:
    """One line for a schema of the folder given that cannot be used (not JSON, nested too
    deep, not a schema): the folder is the user's, so this is a user's mistake."""
    return InputError(
        f"the schema cannot be used ({type(exc).__name__}: {user_text(first_line(exc))})",
        where=str(where),
        fix=f"give the folder of the official schemas as published (--schema-dir, "
        f"${SCHEMA_DIR_ENV})",
    )
