"""Pack a set of official JSON schemas into the one file the package ships: ``schemas.json.gz``.

The package's offline defaults (the 3D Tiles 1.1 schemas, CC BY 4.0; CityJSON 2.0.2's, CC0) are
read from one gzip-compressed JSON object per set, each schema's text, unchanged, under its path
relative to the set's folder (``gnss_citygml.validate.schemas.schema_texts`` reads it). One file
instead of 25 keeps the wheel small (the 617 kB of CityJSON's two inlined schemas pack into
about 40 kB) and the set whole: a file cannot go missing from it.

``--refs`` packs the files those schemas refer to (``$ref``, recursively), with the folder
layout their references need; ``--files`` packs the files named. The output is the same bytes
for the same input (gzip without a time stamp, keys sorted).

Usage (the sets bundled today)::

    python tools/pack_schemas.py ../shared/data/schemas/3dtiles-1.1 gnss_citygml/data/3dtiles-1.1 \\
        --refs tileset.schema.json Schema/schema.schema.json PropertyTable/propertyTable.schema.json
    python tools/pack_schemas.py ../shared/data/schemas/cityjson/2.0.2 \\
        gnss_citygml/data/cityjson-2.0.2 \\
        --files cityjson.min.schema.json cityjsonfeature.min.schema.json
"""

import argparse
import gzip
import json
import posixpath
from pathlib import Path

NAME = "schemas.json.gz"


def referred(source: Path, roots: list[str]) -> list[str]:
    """The roots and every file they refer to by a relative ``$ref``, recursively."""
    found, todo = set(), list(roots)
    while todo:
        relative = todo.pop()
        if relative in found:
            continue
        found.add(relative)
        todo.extend(_refs(json.loads((source / relative).read_text(encoding="utf-8")), relative))
    return sorted(found)


def _refs(node, relative: str):
    """The files a schema at ``relative`` refers to (references within itself left out)."""
    if isinstance(node, dict):
        ref = node.get("$ref")
        if isinstance(ref, str) and not ref.startswith("#") and "://" not in ref:
            target = ref.split("#", 1)[0]
            yield posixpath.normpath(posixpath.join(posixpath.dirname(relative), target))
        for value in node.values():
            yield from _refs(value, relative)
    elif isinstance(node, list):
        for value in node:
            yield from _refs(value, relative)


def pack(source: Path, folder: Path, names: list[str]) -> Path:
    """Write ``folder/schemas.json.gz``: each named file's text under its relative path."""
    texts = {name: (source / name).read_text(encoding="utf-8") for name in sorted(names)}
    data = json.dumps(texts, ensure_ascii=False, sort_keys=True).encode("utf-8")
    target = folder / NAME
    target.write_bytes(gzip.compress(data, compresslevel=9, mtime=0))
    return target


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("source", type=Path, help="the folder of the official schemas")
    parser.add_argument("folder", type=Path, help="the folder to write schemas.json.gz into")
    which = parser.add_mutually_exclusive_group(required=True)
    which.add_argument("--refs", nargs="+", help="pack these and every file they refer to")
    which.add_argument("--files", nargs="+", help="pack these files")
    args = parser.parse_args()
    names = referred(args.source, args.refs) if args.refs else args.files
    path = pack(args.source, args.folder, names)
    print(f"{path}: {len(names)} schemas, {path.stat().st_size} bytes")
