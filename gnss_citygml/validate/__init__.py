"""Validation of CityGML 2.0, CityJSON and CityJSONSeq files (schemas, structure, geometry),
and of 3D Tiles 1.1 tilesets.

:func:`validate_file` finds the format from the file's content (a tileset: a JSON object with
``asset.version`` and ``root``) and returns a :class:`Report`
listing every error with the object it concerns and the rule it breaks. The checks live in the
modules of this package:

- :mod:`.citygml`: CityGML 2.0, XML Schema validation against the official schemas, offline,
  and the solids read by :mod:`.gml`;
- :mod:`.cityjson`: CityJSON (1.0 to 2.0) and CityJSONSeq, the spec's structural rules
  (:mod:`.cityjson_rules`), the toolkit's own CityJSON Extension (:mod:`.extensions`) and
  the official JSON schemas (:mod:`.json_schema`);
- :mod:`.geometry`: the solids of both formats, with the matching val3dity error codes;
- :mod:`.schemas`: where the official schemas are found;
- :mod:`.tiles3d`: 3D Tiles 1.1, :func:`validate_tileset`: a ``tileset.json`` and its external
  tilesets against the official JSON schemas (bundled with the package), their content files
  there, the glTF content by the package's own checks (:mod:`.gltf_structure`) and, when node
  is found, Khronos' glTF validator (:mod:`.gltf`, an npm package run by node, installed by
  :func:`install_gltf_validator`), and its ``EXT_mesh_features`` and
  ``EXT_structural_metadata``, which that validator does not know (:mod:`.gltf_metadata`).

A report is ``valid`` when it lists no error. A file that cannot be validated at all (missing,
not CityGML, CityJSON or a tileset, a CityGML version other than 2.0, a CityGML with a
``<!DOCTYPE>``, schemas not found) raises an :class:`~gnss_citygml.errors.InputError`
instead: exit code 0 valid, 1 invalid, 2 could not validate.

Bad bytes are never valid: a file cut short or otherwise not well-formed XML or JSON is invalid
(rule ``xml-syntax`` or ``json-syntax``, with the line and column of the first fatal error), as
is JSON nested deeper than 128 levels (``json-nesting``), and coordinates that are NaN,
infinite or beyond ±1e12 (``coordinate-range``, also after a CityJSON transform). Only a
CityJSONSeq cut exactly at the end of a line, which nothing tells from a shorter sequence,
passes. No DTD is read, no XML entity expanded, nothing fetched from the network.
"""

from __future__ import annotations

import re
from pathlib import Path

from ..errors import InputError
from ..files.paths import StrPath, input_file
from ..files.userjson import NotJSON, parse_json
from .citygml import validate_citygml
from .cityjson import validate_cityjson
from .geometry import PLANARITY_TOLERANCE, SNAP_TOLERANCE
from .gltf import GLTF_VALIDATOR_VERSION, install_gltf_validator
from .report import Issue, Report
from .schemas import (
    BUNDLED_CITYJSON_SCHEMAS,
    SCHEMA_DIR_ENV,
    TILES3D_SCHEMA_DIR_ENV,
    schema_folder,
)
from .tiles3d import validate_tileset

__all__ = [
    "GLTF_VALIDATOR_VERSION",
    "PLANARITY_TOLERANCE",
    "SCHEMA_DIR_ENV",
    "SNAP_TOLERANCE",
    "TILES3D_SCHEMA_DIR_ENV",
    "Issue",
    "Report",
    "install_gltf_validator",
    "validate_file",
    "validate_tileset",
]

#: Bytes read to tell the formats apart.
HEAD = 65536
_TILESET_KEY = re.compile(rb'"(?:asset|root)"\s*:')
_TILESET_ASSET = re.compile(rb'"asset"\s*:\s*\{[^{}]*"version"\s*:')
_CITYJSON_TYPE = re.compile(rb'"type"\s*:\s*"CityJSON')


def validate_file(
    path: StrPath, *, schema_dir: StrPath | None = None, bundled_schemas: bool = True
) -> Report:
    """Validate a CityGML 2.0, CityJSON or CityJSONSeq file, or a 3D Tiles tileset.

    Parameters
    ----------
    path
        The file. Its format is found from its content: XML is CityGML; a JSON object with
        ``asset.version`` and ``root`` is a 3D Tiles tileset (:func:`validate_tileset`, with
        Khronos' glTF validator when node is found); another JSON document is CityJSON (or a
        lone CityJSONFeature); JSON objects one per line, the first a CityJSON header, are
        CityJSONSeq.
    schema_dir
        Folder of the official schemas (default ``$GNSS_CITYGML_SCHEMA_DIR``): the CityJSON JSON
        schemas (``cityjson.min.schema.json`` in it or in a version sub-folder, also under
        ``cityjson/``) and, optionally, a ``schemas.opengis.net`` tree used for CityGML instead
        of the schemas bundled in ``citysmith``.
    bundled_schemas
        Without a schema folder, check CityJSON 2.0 against the CityJSON 2.0.2 schemas bundled
        with the package (``gnss_citygml/data/cityjson-2.0.2``). The writers' own check of
        what they wrote passes False: the schema costs about 1 ms a building, and the writers
        are tested against it; a note then says it was left out.

    Returns
    -------
    Report

    Raises
    ------
    InputError
        The file cannot be validated: missing, neither CityGML nor CityJSON, CityGML other than
        2.0, a CityGML with a ``<!DOCTYPE>`` (refused: no DTD is read, no entity expanded), or
        the schemas cannot be found or compiled.

    Examples
    --------
    >>> import json
    >>> import tempfile
    >>> cube = {"type": "CityJSON", "version": "2.0", "CityObjects": {"c": {
    ...     "type": "GenericCityObject", "geometry": [{"type": "Solid", "lod": "1",
    ...     "boundaries": [[[[0, 3, 2, 1]], [[4, 5, 6, 7]], [[0, 1, 5, 4]], [[1, 2, 6, 5]],
    ...                     [[2, 3, 7, 6]], [[3, 0, 4, 8]]]]}]}},
    ...     "transform": {"scale": [1, 1, 1], "translate": [0, 0, 0]},
    ...     "vertices": [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0],
    ...                  [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]]}
    >>> with tempfile.NamedTemporaryFile("w", suffix=".city.json") as f:
    ...     _ = f.write(json.dumps(cube)); f.flush()
    ...     report = validate_file(f.name)
    >>> report.valid
    False
    >>> [(e.object_id, e.rule) for e in report.errors]
    [('c', 'vertex-index')]
    >>> report.errors[0].message
    'Solid (lod 1): vertex index 8 out of range (8 vertices)'
    """
    path = input_file(path)
    schema_dir = schema_folder(schema_dir)
    try:
        with open(path, "rb") as f:
            head = f.read(HEAD).lstrip(b"\xef\xbb\xbf \t\r\n")
    except OSError as exc:
        raise InputError(
            f"cannot read the file ({exc.strerror})", where=str(path), fix="check it"
        ) from None
    if head.startswith(b"<"):
        return validate_citygml(path, schema_dir)
    if head.startswith(b"{") and _is_tileset(path, head):
        return validate_tileset(path, schema_dir=schema_dir)
    if head.startswith(b"{"):
        return _cityjson(path, schema_dir, bundled_schemas)
    raise InputError(
        "not a CityGML (XML), CityJSON (JSON) or 3D Tiles (tileset.json) file",
        where=str(path),
        fix="give a .gml, .city.json, .city.jsonl or tileset.json file",
    )


def _cityjson(path: Path, schema_dir: Path | None, bundled_schemas: bool) -> Report:
    """A CityJSON file's report: against the schema folder's schemas, else (``bundled_schemas``)
    the CityJSON 2.0.2 schemas bundled with the package, a note naming them."""
    if schema_dir is not None or not bundled_schemas:
        return validate_cityjson(path, schema_dir)
    report = validate_cityjson(path, BUNDLED_CITYJSON_SCHEMAS)
    if "json-schema" in report.checks:
        report.notes.append("JSON Schema: CityJSON 2.0.2's, bundled with gnss-citygml")
    return report


def _is_tileset(path: Path, head: bytes) -> bool:
    """Whether the JSON file ``path`` starting with ``head`` is a 3D Tiles tileset: an object
    with ``asset.version`` and ``root``. Read whole only when its start names ``asset`` or
    ``root`` and not the type CityJSON; bytes that are not JSON are a tileset when their start
    has an ``asset`` with a ``version`` (then the tileset's check says what is wrong)."""
    if not _TILESET_KEY.search(head) or _CITYJSON_TYPE.search(head):
        return False
    try:
        doc = parse_json(path.read_bytes())
    except NotJSON:
        return _TILESET_ASSET.search(head) is not None
    except OSError:
        return False
    asset = doc.get("asset") if isinstance(doc, dict) else None
    return isinstance(asset, dict) and "version" in asset and "root" in doc
