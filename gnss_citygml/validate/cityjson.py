"""CityJSON (1.0 to 2.0) and CityJSONSeq validation: structure, JSON Schema, geometry.

The spec's structural rules (:mod:`.cityjson_rules`: vertex indices in range, boundary nesting
per geometry type, ``transform``, CityObject types, ``lod`` values, parent/child links,
semantics and appearance indices, Extension names), the attributes of the toolkit's own
Extension when a file declares it (:mod:`.extensions`, offline) and, when the official JSON
schemas are found
(``schema_dir`` or ``$GNSS_CITYGML_SCHEMA_DIR``: a folder with ``cityjson.min.schema.json``, or
with one sub-folder per version such as ``2.0.1/``), JSON Schema validation with ``jsonschema``
(:mod:`.json_schema`), each CityObject against its own type's schema.
"""

from __future__ import annotations

from pathlib import Path

from ..files.userjson import TOO_DEEP, NotJSON, parse_json
from .cityjson_rules import CityJSONRules
from .geometry import BATCH, Shells
from .json_schema import json_schema
from .report import Issue, Report

__all__ = ["not_json_issue", "validate_cityjson"]


def validate_cityjson(path: Path, schema_dir: Path | None) -> Report:
    """A CityJSON or CityJSONSeq file's report: structure, JSON Schema, geometry.

    Not JSON (a file cut short, text that is not UTF-8, ``NaN``, arrays nested deeper than the
    reader goes) is an error of the report: the file is invalid. A CityJSONSeq cut exactly at
    the end of a line cannot be told from a shorter one; cut anywhere else, its last line is
    not JSON."""
    report = Report(str(path), "CityJSON", checks=["json", "structure"])
    with open(path, "rb") as f:
        try:
            header = parse_json(f.readline())
            rest = f.read(1)
            while rest and rest.isspace():
                rest = f.read(1)
        except NotJSON:
            header, rest = None, b""
        if rest and isinstance(header, dict):
            f.seek(0)
            return _validate_seq(f, report, schema_dir)
        if header is None:  # a JSON document over several lines
            f.seek(0)
            try:
                header = parse_json(f.read())
            except NotJSON as exc:
                report.errors.append(not_json_issue(exc))
                return report
    try:
        _validate_document(header, report, schema_dir)
    except RecursionError:  # a check going as deep as the JSON does
        report.errors.append(Issue(None, "json-nesting", TOO_DEEP))
    return report


def _validate_document(doc, report: Report, schema_dir: Path | None) -> None:
    """The checks of a CityJSON document (or a lone CityJSONFeature), added to ``report``."""
    if not isinstance(doc, dict):
        report.errors.append(Issue(None, "cityjson-type", "the file is not a JSON object"))
        return
    kind = doc.get("type")
    if kind not in ("CityJSON", "CityJSONFeature"):
        report.errors.append(
            Issue(None, "cityjson-type", f"type is {kind!r}, not 'CityJSON' or 'CityJSONFeature'")
        )
        return
    rules = CityJSONRules(doc if kind == "CityJSON" else {}, report)
    report.format = f"{kind} {rules.version or '(no version)'}"
    shells = Shells(closed=False)
    if kind == "CityJSON":
        report.errors.extend(rules.header(doc, ""))
    else:
        report.notes.append("a lone CityJSONFeature: no header, vertices taken as they are")
        report.errors.extend(rules.feature(doc, ""))
    report.errors.extend(rules.objects(doc, "", shells))
    report.n_objects = _n_objects(doc)
    schema = json_schema(schema_dir, rules.version, kind.lower(), report)
    if schema is not None:
        report.errors.extend(schema.errors(doc, ""))
    report.checks.append("geometry")
    report.errors.extend(shells.check())


def not_json_issue(exc: NotJSON, line: int = 0) -> Issue:
    """The report's error for a document that is not JSON; ``line``: the CityJSONSeq line of
    the document read."""
    line = line or exc.line
    where = f"line {line}" if line else ""
    where += f", column {exc.column}" if line and exc.column else ""
    return Issue(None, exc.rule, f"{where}: {exc.reason}" if where else exc.reason)


def _n_objects(doc: dict) -> int:
    objects = doc.get("CityObjects")
    return len(objects) if isinstance(objects, dict) else 0


def _validate_seq(lines, report: Report, schema_dir: Path | None) -> Report:
    report.checks.append("geometry")
    shells, rules, schema, errors = Shells(closed=False), None, None, []
    for number, line in enumerate(lines, start=1):
        if not line.strip():
            continue
        try:
            doc = parse_json(line)
        except NotJSON as exc:
            errors.append(not_json_issue(exc, number))
            continue
        where = f"line {number}: "
        if not isinstance(doc, dict):
            errors.append(Issue(None, "cityjson-type", where + "not a JSON object"))
            continue
        try:
            if rules is None:
                rules = CityJSONRules(doc, report)
                report.format = f"CityJSONSeq {rules.version or '(no version)'}"
                errors.extend(rules.header(doc, where, sequence=True))
                schema = json_schema(schema_dir, rules.version, "cityjsonfeature", report)
                continue
            errors.extend(rules.feature(doc, where))
            errors.extend(rules.objects(doc, where, shells))
            report.n_objects += _n_objects(doc)
            if schema is not None:
                errors.extend(schema.errors(doc, where))
        except RecursionError:  # a check going as deep as the JSON does
            errors.append(Issue(None, "json-nesting", where + TOO_DEEP))
        if len(shells) >= BATCH:
            errors.extend(shells.check())
            shells = Shells(closed=False)
    report.errors = errors + shells.check()
    return report
