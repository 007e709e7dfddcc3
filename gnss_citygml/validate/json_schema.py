"""CityJSON validation against the official JSON schemas, each CityObject against its type's."""

from __future__ import annotations

from collections.abc import Iterator
from functools import lru_cache
from pathlib import Path

from ..files.userjson import parse_json
from .report import Issue, Report
from .schemas import SCHEMA_DIR_ENV, cityjson_schema_file, schema_bytes, unusable_schema

__all__ = ["json_schema"]


class _JsonSchema:
    """An official CityJSON JSON schema, checking each CityObject against its type's branch.

    The schema's ``CityObjects`` property is a ``oneOf`` over every CityObject type, and each
    type's ``geometry`` items a ``oneOf`` over the geometry types; an object (a geometry) can
    only match the branch of its own type, so validating it against that branch alone gives
    the same verdict, with errors that name the object, 6 to 20 times faster (about 1 ms per
    LOD1 building instead of 7 to 20).
    """

    def __init__(self, path: Path):
        import jsonschema

        schema = parse_json(schema_bytes(path))
        self.cls = jsonschema.validators.validator_for(schema)
        any_object = schema["properties"]["CityObjects"]["additionalProperties"]
        self.any_object = self.cls(any_object)
        self.by_type = {}  # CityObject type: (validator, geometry validators by type, any)
        for branch in any_object.get("oneOf", []):
            geometry = _geometry_items(branch)
            by_geometry = {
                kind: self.cls(item)
                for item in geometry.get("oneOf", [])
                for kind in _branch_types(item)
            }
            entry = (self.cls(branch), by_geometry, self.cls(geometry))
            for kind in _branch_types(branch):
                self.by_type[kind] = entry
        top = dict(schema)
        top["properties"] = {**schema["properties"], "CityObjects": {"type": "object"}}
        self.top = self.cls(top)

    def errors(self, doc: dict, where: str) -> Iterator[Issue]:
        for error in self.top.iter_errors(doc):
            yield Issue(None, "json-schema", where + _schema_message(error))
        objects = doc.get("CityObjects")
        if not isinstance(objects, dict):
            return
        for key, obj in objects.items():
            for path, error in self._object_errors(obj):
                yield Issue(key, "json-schema", where + _schema_message(error, path))

    def _object_errors(self, obj) -> Iterator[tuple[str, object]]:
        kind = obj.get("type") if isinstance(obj, dict) else None
        if isinstance(kind, str) and kind.startswith("+"):
            kind = "+"
        entry = self.by_type.get(kind) if isinstance(kind, str) else None
        geometries = obj.get("geometry") if isinstance(obj, dict) else None
        if entry is None or not isinstance(geometries, list):
            validator = entry[0] if entry else self.any_object
            yield from (("", e) for e in validator.iter_errors(obj))
            return
        validator, by_geometry, any_geometry = entry
        rest = {k: v for k, v in obj.items() if k != "geometry"}
        yield from (("", e) for e in validator.iter_errors(rest))
        for i, geometry in enumerate(geometries):
            kind = geometry.get("type") if isinstance(geometry, dict) else None
            checker = by_geometry.get(kind, any_geometry) if isinstance(kind, str) else any_geometry
            yield from ((f"geometry/{i}", e) for e in checker.iter_errors(geometry))


def _geometry_items(branch: dict) -> dict:
    """The schema of the items of a CityObject branch's ``geometry`` array ({} if none)."""
    stack = [branch]
    while stack:
        item = stack.pop()
        geometry = (item.get("properties") or {}).get("geometry")
        if isinstance(geometry, dict) and isinstance(geometry.get("items"), dict):
            return geometry["items"]
        stack.extend(item.get("allOf") or [])
    return {}


def _branch_types(branch: dict) -> list[str]:
    stack = [branch]
    while stack:
        item = stack.pop()
        kind = (item.get("properties") or {}).get("type") or {}
        if "enum" in kind:
            return list(kind["enum"])
        if "const" in kind:  # schemas 2.0.2 and later
            return [kind["const"]]
        if "pattern" in kind:
            return ["+"]
        stack.extend(item.get("allOf") or [])
    return []


def _schema_message(error, prefix: str = "") -> str:
    path = "/".join([prefix, *map(str, error.absolute_path)]).strip("/") or "(root)"
    if error.validator in ("oneOf", "anyOf"):
        kind = error.instance.get("type") if isinstance(error.instance, dict) else None
        what = f"a {kind!r}" if kind else "it"
        return f"{path}: {what} matches none of the schemas allowed here"
    text = error.message if len(error.message) <= 200 else error.message[:200] + "..."
    return f"{path}: {text}"


def json_schema(
    schema_dir: Path | None, version: object, kind: str, report: Report
) -> _JsonSchema | None:
    """The schema of this CityJSON version found under ``schema_dir`` (None: a note says why)."""
    if schema_dir is None:
        report.notes.append(
            f"JSON Schema check left out: no schema folder (--schema-dir, ${SCHEMA_DIR_ENV}); "
            "`gnss-citygml validate FILE` checks it against the schemas bundled with the package"
        )
        return None
    path = cityjson_schema_file(schema_dir, None if version is None else str(version), kind)
    if path is None:
        report.notes.append(
            f"JSON Schema check left out: no {kind} schema for version {version} in {schema_dir}"
        )
        return None
    report.checks.append("json-schema")
    return _load_schema(path)


@lru_cache(maxsize=8)
def _load_schema(path: Path) -> _JsonSchema:
    """The schema at ``path``; one that cannot be used (the user's folder) is an InputError."""
    import jsonschema

    try:
        return _JsonSchema(path)
    except (ValueError, LookupError, TypeError, AttributeError, jsonschema.SchemaError) as exc:
        raise unusable_schema(exc, path) from None  # (NotJSON is a ValueError)
