"""Validation of 3D Tiles 1.1 output: a ``tileset.json``, its external tilesets, its glTF content.

:func:`validate_tileset` checks, and lists in one :class:`~.report.Report` (each issue's object
the file it concerns, relative to the tileset's folder):

- every tileset file (the root one and each external tileset its tiles refer to, recursively)
  against the official 3D Tiles 1.1 JSON schemas (draft 2020-12), their ``$ref`` resolved
  between the local files (:func:`~.schemas.tiles3d_schema_folder`: by default the copy
  bundled with the package), never over the network:
  rule ``json-schema``; bytes that are not JSON, rule ``json-syntax`` (or ``json-nesting``);
- every content ``uri`` (``content`` and ``contents`` of every tile, relative to the tileset
  that names it) is a file that exists: rule ``content-missing``; an external tileset that
  refers back to one of the tilesets above it: rule ``tileset-cycle``;
- every ``.glb`` and ``.gltf`` content by the package's own checks of its structure
  (:mod:`.gltf_structure`, always): rule ``gltf-structure``;
- the same files with Khronos' glTF validator (:mod:`.gltf`, all in one node process) when
  node is found: each of its errors is an issue, rule ``gltf``, whose message names the file,
  the validator's code, the JSON pointer and the validator's message. Its warnings, infos and
  hints are not errors: the report's notes count them, by code. A note says which of the two
  ran, and why Khronos' did not;
- the ``EXT_mesh_features`` and ``EXT_structural_metadata`` of that content, which the
  validator does not know (:mod:`.gltf_metadata`): rule ``gltf-metadata``.

Content given by a URL (``http:``, ``data:``), by the templates of implicit tiling, or in
another format (``.b3dm``, ``.pnts``...) is not checked; a note says so.
"""

from __future__ import annotations

import os
from collections import Counter
from collections.abc import Iterator
from functools import lru_cache
from pathlib import Path
from typing import Any
from urllib.parse import unquote, urlsplit

from ..errors import listing, user_text
from ..files.paths import StrPath, input_file
from ..files.userjson import NotJSON, parse_json
from .cityjson import not_json_issue
from .gltf import GltfResult, khronos_results
from .gltf_metadata import MetadataRules, read_gltf
from .gltf_structure import structure_issues
from .json_schema import _schema_message
from .report import Issue, Report
from .schemas import (
    packed_schemas,
    tiles3d_schema_folder,
    tiles3d_schema_source,
    unusable_schema,
)

__all__ = ["validate_tileset"]

#: Content validated by Khronos' glTF validator.
GLTF_SUFFIXES = (".glb", ".gltf")


def validate_tileset(
    path: StrPath,
    *,
    schema_dir: StrPath | None = None,
    node_dir: StrPath | None = None,
    khronos: bool | None = None,
) -> Report:
    """Validate a 3D Tiles 1.1 tileset: its JSON, its external tilesets, its glTF content.

    Parameters
    ----------
    path
        The ``tileset.json``.
    schema_dir
        Folder of the 3D Tiles 1.1 JSON schemas, or a schema folder holding them as
        ``3dtiles-1.1`` (default ``$GNSS_CITYGML_3DTILES_SCHEMA_DIR``, else ``3dtiles-1.1`` in
        ``$GNSS_CITYGML_SCHEMA_DIR``, else the copy bundled with the package:
        :func:`~.schemas.tiles3d_schema_folder`).
    node_dir
        Folder Khronos' glTF validator is installed in (default ``$GNSS_CITYGML_NODE_DIR``, else
        ``~/.cache/gnss-citygml/node``; :func:`~.gltf.install_gltf_validator` installs it).
    khronos
        Whether Khronos' glTF validator runs besides the package's own checks of every glTF
        (:mod:`.gltf_structure`): None (default) when node is found, installing it with npm
        if missing (a note says why it did not run); True: it must (an error if it cannot);
        False: it does not.

    Returns
    -------
    Report
        Valid when no error was found. Its ``n_objects`` counts the tiles, its notes the
        schemas and glTF validators used, the validator's warnings and what was not checked.

    Raises
    ------
    InputError
        The tileset file is missing or unreadable, a schema folder named is not there, or
        ``khronos`` is True and Khronos' validator cannot run.
    """
    path = input_file(path, "tileset")
    folder = tiles3d_schema_folder(schema_dir).resolve()
    schemas = _schemas(folder)
    walk = _Walk(path, schemas["tileset"])
    report = walk.report
    report.notes.insert(0, f"3D Tiles JSON schemas: {tiles3d_schema_source(folder)}")
    if not walk.gltf:
        return report
    report.checks.append("gltf-structure")
    for file, name in walk.gltf.items():
        for pointer, problem in structure_issues(file):
            report.errors.append(Issue(name, "gltf-structure", f"{name}: {pointer}: {problem}"))
    results, khronos_name = khronos_results(list(walk.gltf), node_dir=node_dir, required=khronos)
    if results is None:
        report.notes.append(
            f"glTF: the package's own checks; Khronos' glTF validator not run: {khronos_name}"
        )
    else:
        report.checks.append("gltf")
        report.notes.append(
            f"glTF: the package's own checks and Khronos' glTF validator {khronos_name}"
        )
        for result in results:
            report.errors.extend(_gltf_issues(result, walk.gltf[result.path]))
        report.notes.extend(_gltf_notes(results))
    report.checks.append("gltf-metadata")
    rules = MetadataRules(schemas["schema"], schemas["table"])
    for file, name in walk.gltf.items():
        content = read_gltf(file)
        if content is None:
            continue
        for pointer, problem in rules.issues(*content):
            report.errors.append(Issue(name, "gltf-metadata", f"{name}: {pointer}: {problem}"))
    return report


@lru_cache(maxsize=4)
def _schemas(folder: Path) -> dict[str, Any]:
    """Validators of a tileset, a metadata schema and a property table, their ``$ref``
    resolved in a registry of every ``*.schema.json`` under ``folder`` (where there is none,
    those packed there, :data:`~.schemas.PACKED_SCHEMAS`), each under its ``$id`` and its
    path relative to ``folder``; a schema that is not a JSON object is an InputError naming
    it (the folder may be the user's, --schema-dir)."""
    import jsonschema
    from referencing import Registry, Resource
    from referencing.jsonschema import DRAFT202012

    texts = {
        file.relative_to(folder).as_posix(): file.read_bytes()
        for file in sorted(folder.rglob("*.schema.json"))
    } or packed_schemas(folder)
    resources = []
    for relative, text in texts.items():
        try:
            contents = parse_json(text)
            if not isinstance(contents, dict):
                raise TypeError(f"a JSON {type(contents).__name__}, not an object")
        except (ValueError, TypeError) as exc:  # (NotJSON is a ValueError)
            raise unusable_schema(exc, folder / relative) from None
        resource = Resource.from_contents(contents, default_specification=DRAFT202012)
        resources.append((relative, resource))
        if isinstance(contents.get("$id"), str) and contents["$id"] != relative:
            resources.append((contents["$id"], resource))
    registry: Registry = Registry().with_resources(resources).crawl()
    cls = jsonschema.validators.validator_for(registry.contents("tileset.schema.json"))
    files = {
        "tileset": "tileset.schema.json",
        "schema": "Schema/schema.schema.json",
        "table": "PropertyTable/propertyTable.schema.json",
    }
    return {key: cls({"$ref": file}, registry=registry) for key, file in files.items()}


class _Walk:
    """The tilesets read from a root one: the JSON checks done, the glTF content found."""

    def __init__(self, path: Path, validator: Any):
        self.folder = path.parent
        self.validator = validator
        self.report = Report(str(path), "3D Tiles", checks=["json-schema", "content"])
        self.gltf: dict[Path, str] = {}  # glTF content found: its name in the issues
        self.skipped: Counter[str] = Counter()  # content not checked, by reason
        self.tilesets: set[Path] = set()
        pending = [(path, ())]
        while pending:
            tileset, above = pending.pop()
            pending.extend(self._tileset(tileset, above))
        for reason, n in sorted(self.skipped.items()):
            self.report.notes.append(f"{n} content file(s) not checked: {reason}")

    def name(self, path: Path) -> str:
        """``path`` as the issues name it: relative to the root tileset's folder."""
        return Path(os.path.relpath(path, self.folder)).as_posix()

    def _tileset(self, path: Path, above: tuple[Path, ...]) -> Iterator[tuple[Path, tuple]]:
        """Check one tileset file; the external tilesets it refers to, still to check."""
        self.tilesets.add(path.resolve())
        name, errors = self.name(path), self.report.errors
        try:
            doc = parse_json(path.read_bytes())
        except NotJSON as exc:
            errors.append(Issue(name, exc.rule, f"{name}: {not_json_issue(exc).message}"))
            return
        except OSError as exc:
            errors.append(Issue(name, "content-missing", f"{name}: cannot read ({exc.strerror})"))
            return
        for error in self.validator.iter_errors(doc):
            errors.append(Issue(name, "json-schema", f"{name}: {_schema_message(error)}"))
        if not isinstance(doc, dict) or not isinstance(doc.get("root"), dict):
            return
        if not above:
            version = (
                doc.get("asset", {}).get("version") if isinstance(doc.get("asset"), dict) else None
            )
            self.report.format = f"3D Tiles {user_text(version)}" if version else "3D Tiles"
        for pointer, uri in self._contents(doc["root"]):
            target = self._target(uri, path.parent)
            if target is None:
                continue
            if not target.is_file():
                message = f"{name}: {pointer}/uri: {user_text(uri)}: no such file"
                errors.append(Issue(name, "content-missing", message))
            elif target.suffix.lower() == ".json":
                chain = (*above, path.resolve())
                if target.resolve() in chain:
                    message = (
                        f"{name}: {pointer}/uri: {user_text(uri)} is this tileset or one above it"
                    )
                    errors.append(Issue(name, "tileset-cycle", message))
                elif target.resolve() not in self.tilesets:
                    self.tilesets.add(target.resolve())
                    yield target, chain
            elif target.suffix.lower() in GLTF_SUFFIXES:
                self.gltf.setdefault(target.resolve(), self.name(target))
            else:
                self.skipped[f"{target.suffix or 'no suffix'}, a format not validated"] += 1

    def _contents(self, root: dict) -> Iterator[tuple[str, str]]:
        """(JSON pointer, uri) of every content of the tiles under ``root``."""
        pending = [(root, "/root")]
        while pending:
            tile, pointer = pending.pop()
            self.report.n_objects += 1
            found = [(f"{pointer}/content", tile.get("content"))]
            contents = tile.get("contents")
            if isinstance(contents, list):
                found += [(f"{pointer}/contents/{i}", c) for i, c in enumerate(contents)]
            for at, content in found:
                uri = content.get("uri") if isinstance(content, dict) else None
                if not isinstance(uri, str):
                    continue
                if "implicitTiling" in tile:
                    self.skipped["templates of implicit tiling"] += 1
                else:
                    yield at, uri
            children = tile.get("children")
            if isinstance(children, list):
                pending.extend(
                    (child, f"{pointer}/children/{i}")
                    for i, child in reversed(list(enumerate(children)))
                    if isinstance(child, dict)
                )

    def _target(self, uri: str, folder: Path) -> Path | None:
        """The file a content uri names, relative to the tileset's ``folder`` (None: not a
        local file, counted as not checked)."""
        parts = urlsplit(uri)
        if parts.scheme or parts.netloc:
            self.skipped[f"{parts.scheme or 'network'}: URI, not a local file"] += 1
            return None
        return folder / unquote(parts.path)


def _gltf_issues(result: GltfResult, name: str) -> Iterator[Issue]:
    """The validator's errors on one file, as issues."""
    if result.failure:
        yield Issue(name, "gltf", f"{name}: not glTF or GLB ({user_text(result.failure, 200)})")
        return
    errors = [m for m in result.messages if m.severity == 0]
    for m in errors:
        yield Issue(name, "gltf", f"{name}: {m.code} at {m.pointer or '/'}: {m.message}")
    if result.n_errors > len(errors):
        more = result.n_errors - len(errors)
        yield Issue(name, "gltf", f"{name}: and {more} more error(s) of the glTF validator")


def _gltf_notes(results: list[GltfResult]) -> list[str]:
    """One note per severity below error: how many messages, in how many files, which codes."""
    notes = []
    for severity, label in ((1, "warning"), (2, "info"), (3, "hint")):
        codes = Counter(m.code for r in results for m in r.messages if m.severity == severity)
        total = sum(getattr(r, f"n_{label}s") for r in results)
        if total:
            files = sum(1 for r in results if getattr(r, f"n_{label}s"))
            shown = listing(f"{code} ({n})" for code, n in codes.most_common())
            notes.append(
                f"glTF validator: {total} {label}(s) in {files} file(s), not errors: {shown}"
            )
    return notes
