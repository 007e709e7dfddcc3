"""CityJSON (1.0 to 2.0) and CityJSONSeq validation: structure, JSON Schema, geometry.

The spec's structural rules (:mod:`.cityjson_rules`: vertex indices in range, boundary nesting
per geometry type, ``transform``, CityObject types, ``lod`` values, parent/child links,
semantics and appearance indices, Extension names) and, when the official JSON schemas are found
(``schema_dir`` or ``$GNSS_CITYGML_SCHEMA_DIR``: a folder with ``cityjson.min.schema.json``, or
with one sub-folder per version such as ``2.0.1/``), JSON Schema validation with ``jsonschema``
(:mod:`.json_schema`), each CityObject against its own type's schema.
"""

from __future__ import annotations

import contextlib
import gc
import json
from pathlib import Path

from .cityjson_rules import CityJSONRules
from .geometry import BATCH, Shells
from .json_schema import json_schema
from .report import Issue, Report

__all__ = ["validate_cityjson"]


def validate_cityjson(path: Path, schema_dir: Path | None) -> Report:
    """A CityJSON or CityJSONSeq file's report: structure, JSON Schema, geometry."""
    report = Report(str(path), "CityJSON", checks=["json", "structure"])
    with open(path, encoding="utf-8-sig", errors="replace") as f:
        first = f.readline()
        try:
            with _collector_paused():  # a one-line CityJSON file is all here
                header = json.loads(first)
            rest = f.read(1)
            while rest and rest.isspace():
                rest = f.read(1)
        except json.JSONDecodeError:
            header, rest = None, ""
        if header is not None and rest and isinstance(header, dict):
            f.seek(0)
            return _validate_seq(f, report, schema_dir)
        if header is None:
            f.seek(0)
            try:
                with _collector_paused():
                    header = json.load(f)
            except json.JSONDecodeError as exc:
                report.errors.append(Issue(None, "json-syntax", _json_message(exc)))
                return report
    if not isinstance(header, dict):
        report.errors.append(Issue(None, "cityjson-type", "the file is not a JSON object"))
        return report
    kind = header.get("type")
    if kind not in ("CityJSON", "CityJSONFeature"):
        report.errors.append(
            Issue(None, "cityjson-type", f"type is {kind!r}, not 'CityJSON' or 'CityJSONFeature'")
        )
        return report
    rules = CityJSONRules(header if kind == "CityJSON" else {}, report)
    report.format = f"{kind} {rules.version or '(no version)'}"
    shells = Shells(closed=False)
    if kind == "CityJSON":
        report.errors.extend(rules.header(header, ""))
    else:
        report.notes.append("a lone CityJSONFeature: no header, vertices taken as they are")
        report.errors.extend(rules.feature(header, ""))
    report.errors.extend(rules.objects(header, "", shells))
    report.n_objects = len(header.get("CityObjects") or {})
    schema = json_schema(schema_dir, rules.version, kind.lower(), report)
    if schema is not None:
        report.errors.extend(schema.errors(header, ""))
    report.checks.append("geometry")
    report.errors.extend(shells.check())
    return report


@contextlib.contextmanager
def _collector_paused():
    """Pause Python's cyclic garbage collector, which slows json.loads of millions of lists
    fourfold (it scans them again and again while they are built)."""
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if enabled:
            gc.enable()


def _validate_seq(lines, report: Report, schema_dir: Path | None) -> Report:
    report.checks.append("geometry")
    shells, rules, schema, errors = Shells(closed=False), None, None, []
    for number, line in enumerate(lines, start=1):
        if not line.strip():
            continue
        where = f"line {number}: "
        try:
            doc = json.loads(line)
        except json.JSONDecodeError as exc:
            errors.append(Issue(None, "json-syntax", where + _json_message(exc)))
            continue
        if not isinstance(doc, dict):
            errors.append(Issue(None, "cityjson-type", where + "not a JSON object"))
            continue
        if rules is None:
            rules = CityJSONRules(doc, report)
            report.format = f"CityJSONSeq {rules.version or '(no version)'}"
            errors.extend(rules.header(doc, where, sequence=True))
            schema = json_schema(schema_dir, rules.version, "cityjsonfeature", report)
            continue
        errors.extend(rules.feature(doc, where))
        errors.extend(rules.objects(doc, where, shells))
        report.n_objects += len(doc.get("CityObjects") or {})
        if schema is not None:
            errors.extend(schema.errors(doc, where))
        if len(shells) >= BATCH:
            errors.extend(shells.check())
            shells = Shells(closed=False)
    report.errors = errors + shells.check()
    return report


def _json_message(exc: json.JSONDecodeError) -> str:
    return f"line {exc.lineno}, column {exc.colno}: not valid JSON: {exc.msg}"
