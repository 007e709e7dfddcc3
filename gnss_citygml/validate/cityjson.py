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

import contextlib
import gc
import json
import sys
from pathlib import Path

from .cityjson_rules import CityJSONRules
from .geometry import BATCH, Shells
from .json_schema import json_schema
from .report import Issue, Report

__all__ = ["validate_cityjson"]


def validate_cityjson(path: Path, schema_dir: Path | None) -> Report:
    """A CityJSON or CityJSONSeq file's report: structure, JSON Schema, geometry.

    Not JSON (a file cut short, text that is not UTF-8, ``NaN``, arrays nested deeper than the
    reader goes) is an error of the report: the file is invalid. A CityJSONSeq cut exactly at
    the end of a line cannot be told from a shorter one; cut anywhere else, its last line is
    not JSON."""
    report = Report(str(path), "CityJSON", checks=["json", "structure"])
    with open(path, "rb") as f:
        try:
            header = _load(f.readline())
            rest = f.read(1)
            while rest and rest.isspace():
                rest = f.read(1)
        except _NotJson:
            header, rest = None, b""
        if rest and isinstance(header, dict):
            f.seek(0)
            return _validate_seq(f, report, schema_dir)
        if header is None:  # a JSON document over several lines
            f.seek(0)
            try:
                header = _load(f.read())
            except _NotJson as exc:
                report.errors.append(exc.issue())
                return report
    try:
        _validate_document(header, report, schema_dir)
    except RecursionError:  # a check going as deep as the JSON does
        report.errors.append(Issue(None, "json-nesting", _TOO_DEEP))
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


_TOO_DEEP = (
    f"arrays and objects nested too deep to read (deeper than about {sys.getrecursionlimit()} "
    "levels; CityJSON needs fewer than 10)"
)


class _NotJson(ValueError):
    """Bytes that are not a JSON document: the rule, the reason, where (0: not known)."""

    def __init__(self, rule: str, reason: str, line: int = 0, column: int = 0):
        super().__init__(reason)
        self.rule, self.reason, self.line, self.column = rule, reason, line, column

    def issue(self, line: int = 0) -> Issue:
        """The report's error; ``line``: the CityJSONSeq line of the document read."""
        line = line or self.line
        where = f"line {line}" if line else ""
        where += f", column {self.column}" if line and self.column else ""
        return Issue(None, self.rule, f"{where}: {self.reason}" if where else self.reason)


def _load(data: bytes):
    """The JSON document in ``data`` (UTF-8, a BOM allowed); :class:`_NotJson` if there is none.

    Stricter than :func:`json.loads`: ``NaN`` and ``Infinity`` are not JSON."""
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        column = exc.start - data.rfind(b"\n", 0, exc.start)
        raise _NotJson("json-syntax", "not UTF-8 text", line, column) from None
    try:
        with _collector_paused():
            return json.loads(text, parse_constant=_not_a_number)
    except json.JSONDecodeError as exc:
        raise _NotJson("json-syntax", f"not valid JSON: {exc.msg}", exc.lineno, exc.colno) from None
    except RecursionError:
        raise _NotJson("json-nesting", _TOO_DEEP) from None
    except ValueError as exc:  # NaN, Infinity; an integer of more than 4300 digits
        raise _NotJson("json-syntax", f"not valid JSON: {str(exc).split(';')[0]}") from None


def _n_objects(doc: dict) -> int:
    objects = doc.get("CityObjects")
    return len(objects) if isinstance(objects, dict) else 0


def _not_a_number(name: str):
    raise ValueError(f"{name} is not a JSON number")


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
        try:
            doc = _load(line)
        except _NotJson as exc:
            errors.append(exc.issue(number))
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
            errors.append(Issue(None, "json-nesting", where + _TOO_DEEP))
        if len(shells) >= BATCH:
            errors.extend(shells.check())
            shells = Shells(closed=False)
    report.errors = errors + shells.check()
    return report
