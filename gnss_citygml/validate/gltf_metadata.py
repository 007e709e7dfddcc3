"""The glTF extensions of 3D Tiles 1.1 content that Khronos' glTF validator does not check.

The validator (:mod:`.gltf`) knows neither ``EXT_mesh_features`` nor ``EXT_structural_metadata``
(it only says it cannot validate them), so the feature ids and the property tables of a tile,
the buildings' ids and heights, would pass unread. :class:`MetadataRules` checks them:

- the ``EXT_structural_metadata`` schema and property tables against the 3D Metadata JSON
  schemas of 3D Tiles 1.1 (``Schema/schema.schema.json``, ``PropertyTable/``);
- each table against its class (the class and its properties declared, required properties
  given) and against its bytes, as the binary table format lays them out: buffer views that
  exist, start aligned to their component size and are long enough for ``count`` values;
  string offsets that never decrease, stay within the strings and split them into UTF-8;
  floats that are finite;
- each ``EXT_mesh_features`` feature id set: ``featureCount`` at least 1, its attribute
  ``_FEATURE_ID_n`` present in the primitive as a SCALAR accessor, not normalized, its property
  table one that exists.

Bytes in an external buffer (a buffer with a ``uri``) are not read; variable-length arrays are
checked for their offsets only.
"""

from __future__ import annotations

import struct
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from ..files.userjson import parse_json

__all__ = ["MetadataRules", "read_gltf"]

#: Bytes per component, by the 3D Metadata component types.
SIZES = {
    "INT8": 1,
    "UINT8": 1,
    "INT16": 2,
    "UINT16": 2,
    "INT32": 4,
    "UINT32": 4,
    "INT64": 8,
    "UINT64": 8,
    "FLOAT32": 4,
    "FLOAT64": 8,
}
#: Components per value, by the 3D Metadata types of fixed size.
COMPONENTS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
_UNSIGNED = {"UINT8": "<u1", "UINT16": "<u2", "UINT32": "<u4", "UINT64": "<u8"}
_FLOATS = {"FLOAT32": "<f4", "FLOAT64": "<f8"}
_ROOT = "/extensions/EXT_structural_metadata"


def read_gltf(path: Path) -> tuple[dict, bytes | None] | None:
    """The JSON of a GLB or glTF file and the GLB's binary chunk (None: none); None if the file
    cannot be read as either (Khronos' validator says why)."""
    try:
        data = path.read_bytes()
        binary = None
        if data[:4] == b"glTF":
            length, kind = struct.unpack_from("<I4s", data, 12)
            if kind != b"JSON":
                return None
            doc = parse_json(data[20 : 20 + length])
            at = 20 + length
            if len(data) >= at + 8:
                size, kind = struct.unpack_from("<I4s", data, at)
                binary = data[at + 8 : at + 8 + size] if kind == b"BIN\x00" else None
        else:
            doc = parse_json(data)
    except (OSError, ValueError, struct.error):  # (NotJSON is a ValueError)
        return None
    return (doc, binary) if isinstance(doc, dict) else None


class MetadataRules:
    """The checks of the metadata extensions, with the JSON schema validators they use: one
    for the metadata ``schema`` object and one for a property table."""

    def __init__(self, schema_validator: Any, table_validator: Any):
        self.schema_validator = schema_validator
        self.table_validator = table_validator

    def issues(self, doc: dict, binary: bytes | None) -> Iterator[tuple[str, str]]:
        """(JSON pointer, what is wrong) of every error in the glTF ``doc`` with its binary
        chunk ``binary``."""
        yield from _feature_ids(doc)
        extension = (_dict(doc.get("extensions"))).get("EXT_structural_metadata")
        if extension is None:
            return
        if not isinstance(extension, dict):
            yield _ROOT, "not a JSON object"
            return
        schema = extension.get("schema")
        if schema is not None:
            for error in self.schema_validator.iter_errors(schema):
                yield _pointer(f"{_ROOT}/schema", error), _text(error)
            yield from _class_types(_dict(schema))
        tables = extension.get("propertyTables")
        if tables is None:
            return
        if not isinstance(tables, list) or not tables:
            yield f"{_ROOT}/propertyTables", "not a non-empty array"
            return
        known = isinstance(schema, dict) and "schemaUri" not in extension
        binaries = _Bytes(doc, binary)
        for i, table in enumerate(tables):
            at = f"{_ROOT}/propertyTables/{i}"
            errors = list(self.table_validator.iter_errors(table))
            for error in errors:
                yield _pointer(at, error), _text(error)
            if not errors and known:
                yield from _table(table, _dict(schema), binaries, at)


def _dict(value: object) -> dict:
    return value if isinstance(value, dict) else {}


def _pointer(at: str, error: Any) -> str:
    return "/".join([at, *map(str, error.absolute_path)])


def _text(error: Any) -> str:
    return error.message if len(error.message) <= 200 else error.message[:200] + "..."


def _feature_ids(doc: dict) -> Iterator[tuple[str, str]]:
    """The errors of the ``EXT_mesh_features`` of every mesh primitive."""
    extension = _dict(_dict(doc.get("extensions")).get("EXT_structural_metadata"))
    tables = extension.get("propertyTables")
    n_tables = len(tables) if isinstance(tables, list) else 0
    accessors = doc.get("accessors")
    accessors = accessors if isinstance(accessors, list) else []
    meshes = doc.get("meshes")
    for m, mesh in enumerate(meshes if isinstance(meshes, list) else []):
        primitives = _dict(mesh).get("primitives")
        for p, primitive in enumerate(primitives if isinstance(primitives, list) else []):
            primitive = _dict(primitive)
            features = _dict(primitive.get("extensions")).get("EXT_mesh_features")
            if features is None:
                continue
            at = f"/meshes/{m}/primitives/{p}/extensions/EXT_mesh_features"
            ids = _dict(features).get("featureIds")
            if not isinstance(ids, list) or not ids:
                yield f"{at}/featureIds", "not a non-empty array"
                continue
            attributes = _dict(primitive.get("attributes"))
            for k, feature_id in enumerate(ids):
                for problem in _feature_id(_dict(feature_id), attributes, accessors, n_tables):
                    yield f"{at}/featureIds/{k}", problem


def _feature_id(feature_id: dict, attributes: dict, accessors: list, n_tables: int):
    count = feature_id.get("featureCount")
    if not _count(count):
        yield f"featureCount is {count!r}, not an integer of at least 1"
    table = feature_id.get("propertyTable")
    if table is not None and not (_index(table) and table < n_tables):
        yield f"propertyTable {table!r}: no such property table ({n_tables} in the file)"
    if "attribute" not in feature_id:
        return
    n = feature_id["attribute"]
    name = f"_FEATURE_ID_{n}"
    index = attributes.get(name) if _index(n) else None
    if index is None:
        yield f"attribute {n!r}: the primitive has no attribute {name}"
        return
    accessor = _dict(accessors[index]) if _index(index) and index < len(accessors) else {}
    if accessor.get("type") != "SCALAR" or accessor.get("normalized", False):
        yield f"attribute {name}: its accessor is not a SCALAR that is not normalized"


def _count(value: object) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value >= 1


def _index(value: object) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value >= 0


def _class_types(schema: dict) -> Iterator[tuple[str, str]]:
    """The class properties of a metadata schema whose type or component type is not one of
    the specification's (the JSON schema allows any string, for later versions), and the enum
    properties whose enum is not in the schema."""
    enums = _dict(schema.get("enums"))
    for name, definition in _dict(schema.get("classes")).items():
        for key, prop in _dict(_dict(definition).get("properties")).items():
            at = f"{_ROOT}/schema/classes/{name}/properties/{key}"
            prop = _dict(prop)
            kind, component = prop.get("type"), prop.get("componentType")
            if kind not in (*COMPONENTS, "STRING", "BOOLEAN", "ENUM"):
                yield f"{at}/type", f"{kind!r} is not a type of the 3D Metadata Specification"
            elif kind in COMPONENTS and not (isinstance(component, str) and component in SIZES):
                yield (
                    f"{at}/componentType",
                    f"{component!r} is not a component type of the 3D Metadata Specification",
                )
            elif kind == "ENUM" and not (
                isinstance(prop.get("enumType"), str) and prop["enumType"] in enums
            ):
                yield f"{at}/enumType", f"{prop.get('enumType')!r} is not an enum of the schema"


def _table(table: dict, schema: dict, binaries: _Bytes, at: str) -> Iterator[tuple[str, str]]:
    """The errors of a property table (valid against its JSON schema) against its class and
    its bytes."""
    classes = _dict(schema.get("classes"))
    name = table["class"]
    if name not in classes:
        yield f"{at}/class", f"{name!r} is not a class of the schema"
        return
    declared = _dict(_dict(classes[name]).get("properties"))
    columns = _dict(table.get("properties"))
    for key, definition in declared.items():
        if _dict(definition).get("required") and key not in columns:
            yield f"{at}/properties", f"the required property {key!r} of class {name!r} is missing"
    enums = _dict(schema.get("enums"))
    for key, storage in columns.items():
        where = f"{at}/properties/{key}"
        if key not in declared:
            yield where, f"{key!r} is not a property of class {name!r}"
            continue
        for problem in _column(_dict(declared[key]), storage, table["count"], binaries, enums):
            yield where, problem


def _column(prop: dict, storage: dict, count: int, binaries: _Bytes, enums: dict):
    """The errors of one column of a property table: ``prop`` its class property, ``storage``
    where its values are."""
    kind, size = prop.get("type"), SIZES.get(str(prop.get("componentType")), 0)
    if kind not in (*COMPONENTS, "STRING", "BOOLEAN", "ENUM") or (kind in COMPONENTS and not size):
        return  # an error of the class (_class_types)
    if prop.get("array") and "count" not in prop:  # variable-length arrays: their offsets
        yield from binaries.check(
            storage.get("arrayOffsets"),
            "arrayOffsets",
            count + 1,
            SIZES.get(storage.get("arrayOffsetType", "UINT32"), 4),
        )
        return
    n = count * (prop["count"] if prop.get("array") and _count(prop.get("count")) else 1)
    if kind == "STRING":
        yield from _strings(storage, n, binaries)
    elif kind == "BOOLEAN":
        yield from binaries.check(storage["values"], "values", -(-n // 8), 1)
    elif kind == "ENUM":
        enum = _dict(enums.get(str(prop.get("enumType"))))
        yield from binaries.check(
            storage["values"], "values", n, SIZES.get(str(enum.get("valueType", "UINT16")), 2)
        )
    else:
        n *= COMPONENTS[kind]
        yield from binaries.check(storage["values"], "values", n, size)
        values = binaries.data(storage["values"], n * size)
        floats = _FLOATS.get(prop["componentType"])
        if floats is not None and values is not None:
            bad = ~np.isfinite(np.frombuffer(values, floats))
            if bad.any():
                yield f"values: {int(bad.sum())} of {n} values are NaN or infinite"


def _strings(storage: dict, n: int, binaries: _Bytes) -> Iterator[str]:
    """The errors of a STRING column: its offsets and its UTF-8 bytes."""
    if "stringOffsets" not in storage:
        yield "stringOffsets is required for a STRING property"
        return
    offset_type = storage.get("stringOffsetType", "UINT32")
    size = SIZES.get(offset_type, 4)
    problems = list(binaries.check(storage["stringOffsets"], "stringOffsets", n + 1, size))
    problems += binaries.check(storage["values"], "values", 0, 1)
    yield from problems
    raw = binaries.data(storage["stringOffsets"], (n + 1) * size)
    values = binaries.data(storage["values"], 0)
    if problems or raw is None or values is None or offset_type not in _UNSIGNED:
        return
    offsets = np.frombuffer(raw, _UNSIGNED[offset_type]).astype(np.uint64)
    if (np.diff(offsets.astype(np.float64)) < 0).any():
        yield "stringOffsets: the offsets decrease"
    elif int(offsets[-1]) > len(values):
        yield (
            f"stringOffsets: the last offset, {int(offsets[-1])}, is past the {len(values)} "
            "bytes of the strings"
        )
    else:
        text = values[int(offsets[0]) : int(offsets[-1])]
        starts = offsets[:-1][offsets[:-1] < offsets[-1]].astype(np.int64)
        split = (np.frombuffer(values, np.uint8)[starts] & 0xC0) == 0x80
        try:
            text.decode("utf-8")
        except UnicodeDecodeError:
            split[:] = True
        if split.any():
            yield "values: the strings are not UTF-8 (or an offset splits a character)"


class _Bytes:
    """The buffer views of a glTF and the bytes of those in its GLB binary chunk."""

    def __init__(self, doc: dict, binary: bytes | None):
        views = doc.get("bufferViews")
        self.views = views if isinstance(views, list) else []
        buffers = doc.get("buffers")
        first = _dict(buffers[0]) if isinstance(buffers, list) and buffers else {}
        self.binary = binary if "uri" not in first else None  # buffer 0 is the binary chunk

    def view(self, index: object) -> dict | None:
        """Buffer view ``index`` (None: no such view)."""
        if isinstance(index, int) and not isinstance(index, bool) and 0 <= index < len(self.views):
            return _dict(self.views[index])
        return None

    def check(self, index: object, what: str, n: int, size: int) -> list[str]:
        """The errors of buffer view ``index`` holding ``n`` values of ``size`` bytes."""
        view = self.view(index)
        if view is None:
            return [f"{what}: buffer view {index!r} does not exist ({len(self.views)} in the file)"]
        start, length = view.get("byteOffset", 0), view.get("byteLength", 0)
        problems = []
        if isinstance(start, int) and start % size:
            problems.append(
                f"{what}: buffer view {index} starts at byte {start}, not a multiple of its "
                f"component size ({size})"
            )
        if isinstance(length, int) and length < n * size:
            problems.append(
                f"{what}: buffer view {index} holds {length} bytes, fewer than the {n * size} "
                f"of {n} values of {size} byte(s)"
            )
        return problems

    def data(self, index: object, n_bytes: int) -> bytes | None:
        """The first ``n_bytes`` of buffer view ``index`` (0: all), if it is in the binary chunk
        and there whole (else None: checked elsewhere, or not read)."""
        view = self.view(index) or {}
        start, length = view.get("byteOffset", 0), view.get("byteLength")
        if self.binary is None or view.get("buffer") != 0 or not isinstance(length, int):
            return None
        if not isinstance(start, int) or start + length > len(self.binary):
            return None
        return self.binary[start : start + (n_bytes or length)]
