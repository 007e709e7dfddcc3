"""Where an output came from: the toolkit's version, the command and its settings, each input's
name and SHA-256, and when, written into every output and read back by ``gnss-citygml info``.

A map made from crowdsourced data must say with what and from what it was made. The record
(:func:`provenance`) is one JSON object::

    {"software": "gnss-citygml 0.9.0", "created": "2026-11-27T12:00:00Z", "command": "estimate",
     "settings": {...}, "inputs": [{"role": "observations", "name": "june.parquet",
     "bytes": 1234, "sha256": "..."}]}

Each output keeps it where its format has room: a GeoPackage layer in ``gpkg_metadata``
(GDAL's metadata of the layer, item :data:`KEY`) with a one-line summary as the layer's
description; CityJSON and CityJSONSeq in ``metadata.provenance``; CityGML as the model's
``gml:description`` (the summary, then the record); a 3D Tiles tileset in
``asset.extras.provenance``; the report in its header and in a ``<script
type="application/json" id="provenance">``. A folder given as input (a partition, a DEM's
tiles) is digested as the SHA-256 of its files' relative paths and SHA-256, in name order; a
partition, as its index (which lists its files' SHA-256).
"""

from __future__ import annotations

import dataclasses
import datetime as dt
import enum
import hashlib
import json
import math
import os
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from ..errors import InputError, first_line, listing, user_text
from .geopackage import check_geopackage
from .names import native_name, os_text
from .paths import StrPath, file_digest
from .userjson import parse_json

__all__ = [
    "KEY",
    "PARTITION_INDEX",
    "digest_input",
    "plain",
    "provenance",
    "read_provenance",
    "summary",
]

#: The metadata item (GeoPackage) or member (JSON) holding the record.
KEY = "provenance"
#: A partition's index (:mod:`gnss_citygml.tiling.partition`), which lists the SHA-256 of each
#: of its files: a partition is digested as its index.
PARTITION_INDEX = "partition.json"


def provenance(
    command: str, settings: Any, inputs: Iterable[tuple[str, StrPath | None]]
) -> dict[str, Any]:
    """The record of an output made by ``command`` with ``settings`` (a dataclass such as
    :class:`~gnss_citygml.settings.RunSettings`, or a mapping) from ``inputs`` (``(role,
    path)``; None paths are left out), now."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        release = version("gnss-citygml")
    except PackageNotFoundError:  # (a source tree that was never installed)
        release = "unknown"
    return {
        "software": f"gnss-citygml {release}",
        "created": dt.datetime.now(dt.UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "command": command,
        "settings": json.loads(json.dumps(plain(settings), default=str)),
        "inputs": [
            {"role": role, **digest_input(path)} for role, path in inputs if path is not None
        ],
    }


def digest_input(path: StrPath) -> dict[str, Any]:
    """``name``, ``bytes`` and ``sha256`` of an input file, or of a folder's files."""
    path = Path(path)
    if (path / PARTITION_INDEX).is_file():  # a partition: its index lists its files' SHA-256
        return {"name": os_text(path.name) + "/", **digest_input(path / PARTITION_INDEX)}
    if path.is_file():
        size, sha = file_digest(path)
        return {"name": os_text(path.name), "bytes": size, "sha256": sha}
    if not path.is_dir():
        raise InputError("an input is gone", where=str(path), fix="give the file again")
    lines, total = [], 0
    for file in sorted(p for p in path.rglob("*") if p.is_file()):
        size, sha = file_digest(file)
        total += size
        lines.append(f"{file.relative_to(path).as_posix()} {sha}\n")
    sha = hashlib.sha256(os.fsencode("".join(lines))).hexdigest()  # (the names' own bytes)
    return {"name": os_text(path.name) + "/", "bytes": total, "sha256": sha}


def summary(record: dict[str, Any]) -> str:
    """One line: what made it, when, from what."""
    inputs = ", ".join(f"{i['name']} ({i['sha256'][:12]})" for i in record.get("inputs", []))
    return (
        f"made by {record.get('software')} ({record.get('command')}) on "
        f"{record.get('created')} from {inputs or 'no file'}"
    )


def plain(value: Any) -> Any:
    """Settings (or a record read back) as JSON's types: dataclasses as objects, enums by
    value, paths as text, the floats JSON has no number for (NaN, infinities) as text."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: plain(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, dict):
        return {str(k): plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [plain(v) for v in value]
    if isinstance(value, enum.Enum):
        return value.value
    if isinstance(value, str | Path):  # (a name the OS gave may hold bytes that are not UTF-8)
        return os_text(str(value))
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)  # (JSON has no NaN nor infinity)
    return value


def read_provenance(path: StrPath, layer: str | None = None) -> dict[str, Any]:
    """The provenance record an output holds: a GeoPackage's layer (``layer``, default the
    ``heights`` layer or the only one), a CityJSON or CityJSONSeq file, a CityGML file, a 3D
    Tiles tileset (its ``tileset.json`` or folder) or a report page; an :class:`InputError`
    if it holds none, or one that is not JSON (:func:`~.userjson.parse_json`) or not of the
    shape the toolkit writes (a field missing is left out; one of another type is refused)."""
    path = Path(path)
    if path.is_dir() and (path / "tileset.json").is_file():
        path = path / "tileset.json"
    if not path.is_file():
        raise InputError("no such file", where=str(path), fix="give an output of gnss-citygml")
    suffix = path.suffix.lower()
    reader = {
        ".gpkg": lambda: _from_geopackage(path, layer),
        ".json": lambda: _from_json(parse_json(path.read_bytes())),
        ".jsonl": lambda: _from_json(parse_json(_first_line(path))),
        ".gml": lambda: _from_citygml(path),
        ".xml": lambda: _from_citygml(path),
        ".html": lambda: _from_report(path),
    }.get(suffix)
    from lxml.etree import XMLSyntaxError

    try:
        record = reader() if reader is not None else None
    except (ValueError, OSError, XMLSyntaxError) as err:  # (NotJSON is a ValueError)
        raise InputError(f"cannot read it: {first_line(err)}", where=str(path)) from None
    if not isinstance(record, dict):
        raise InputError(
            "no provenance record in it",
            where=str(path),
            fix="give a heights GeoPackage, city model, tileset or report this toolkit wrote",
        )
    wrong = _wrong_field(record)
    if wrong is not None:
        raise InputError(
            f"the provenance record's {wrong} (its record is not as gnss-citygml writes it)",
            where=str(path),
            fix="give the output as gnss-citygml wrote it",
        )
    return record


#: The fields of a record and of each of its inputs, by the type the toolkit writes them as.
_FIELDS: dict[str, type] = {
    "software": str,
    "created": str,
    "command": str,
    "settings": dict,
    "inputs": list,
}
_INPUT_FIELDS: dict[str, type] = {"role": str, "name": str, "sha256": str, "bytes": int}
#: The types of JSON values, as a message names them.
_KINDS: dict[type, str] = {
    str: "text",
    dict: "an object",
    list: "a list",
    int: "a whole number",
    float: "a number",
}


def _wrong_field(record: dict[str, Any]) -> str | None:
    """What is wrong with the first field of ``record`` not of the type the toolkit writes
    (``inputs[0].bytes is text, not a whole number``), None if none is."""
    fields: list[tuple[str, Any, type]] = [
        (key, record[key], kind) for key, kind in _FIELDS.items() if key in record
    ]
    inputs = record.get("inputs")
    for n, item in enumerate(inputs if isinstance(inputs, list) else []):
        if not isinstance(item, dict):
            fields.append((f"inputs[{n}]", item, dict))
            continue
        fields += [
            (f"inputs[{n}].{k}", item[k], kind) for k, kind in _INPUT_FIELDS.items() if k in item
        ]
    for name, value, kind in fields:
        if type(value) is not kind:
            found = "null" if value is None else _KINDS.get(type(value), "true or false")
            return f"{name} is {found}, not {_KINDS[kind]}"
        if type(value) is int and not 0 <= value < 2**63:
            return f"{name} is {user_text(value)}, not a size in bytes"
    return None


def _from_json(doc: Any) -> Any:
    """A CityJSON's ``metadata`` or a tileset's ``asset.extras``."""
    if not isinstance(doc, dict):
        return None
    if "metadata" in doc:
        holder = doc["metadata"]
    else:
        asset = doc.get("asset")
        holder = asset.get("extras") if isinstance(asset, dict) else None
    return holder.get(KEY) if isinstance(holder, dict) else None


def _first_line(path: Path) -> bytes:
    with open(path, "rb") as file:
        return file.readline()


def _from_citygml(path: Path) -> Any:
    """The JSON after the summary line of the model's ``gml:description``."""
    from lxml import etree

    for _, element in etree.iterparse(native_name(path), events=("end",), resolve_entities=False):
        if etree.QName(element).localname == "description":
            text = (element.text or "").split("\n", 1)
            return parse_json(text[1]) if len(text) == 2 else None
        if etree.QName(element).localname in ("boundedBy", "cityObjectMember"):
            return None
    return None


#: How much of a report page is searched for its record: the toolkit writes it in the page's
#: head, before the figures (a bound on the search whatever the page holds).
REPORT_HEAD = 4 * 2**20
_SCRIPT = b'<script type="application/json" id="provenance">'


def _from_report(path: Path) -> Any:
    """The record in the first provenance script of the page's first :data:`REPORT_HEAD`
    bytes: two searches, each linear, however many times the page opens the script."""
    with open(path, "rb") as file:
        head = file.read(REPORT_HEAD)
    start = head.find(_SCRIPT)
    end = head.find(b"</script>", start + len(_SCRIPT)) if start >= 0 else -1
    return parse_json(head[start + len(_SCRIPT) : end]) if end >= 0 else None


def _from_geopackage(path: Path, layer: str | None) -> Any:
    import pyogrio

    check_geopackage(path, empty_ok=False)
    layers = [str(name) for name, _ in pyogrio.list_layers(native_name(path))]
    if layer is None:
        layer = "heights" if "heights" in layers else (layers[0] if len(layers) == 1 else None)
    if layer is None or layer not in layers:
        raise InputError(
            f"which layer? it has {listing(layers)}", where=str(path), fix="give --layer"
        )
    text = (pyogrio.read_info(native_name(path), layer=layer).get("layer_metadata") or {}).get(KEY)
    return parse_json(text) if text else None
