"""CityJSON 2.0 and CityJSONSeq: one LOD1 ``Building`` per footprint, with its height estimate.

Each building is a ``Building`` with a ``Solid`` of ``lod`` ``"1"`` (semantic surfaces
``GroundSurface``, ``RoofSurface``, ``WallSurface``); a MultiPolygon footprint gives a
``Building`` with one ``BuildingPart`` child per polygon (ids ``<id>-1``, ``<id>-2``, ...).
Vertices are integers in millimetres (``transform.scale`` 0.001, ``translate`` the whole metres
below the data) and identical vertices are stored once. ``metadata.referenceSystem`` is
``https://www.opengis.net/def/crs/EPSG/0/7405`` (British National Grid + ODN heights).

Each city object's key is the building's id (e.g. its TOID, whatever its source's field is
called); the id is not repeated as an attribute.

Attributes are plain CityJSON attributes by default: ``measuredHeight`` (roof - ground, m, as in
the spec), ``creationDate`` (the export date), then every column of the buildings table under
its own name (for an estimate: ``height`` the absolute roof height in m ODN,
``height_lower``/``height_upper`` its range, ``ground``, ``n_signals``, ``converged``,
``method``, ...). Missing values (NaN) are left out. Plain attributes need no Extension file
reachable at a URL, so every CityJSON reader and validator accepts the files offline.

With ``typed_attributes=True`` the toolkit's own attributes (the columns of the heights table:
``height``, ``height_lower``, ..., ``ground``, ``relative_height``) are written as ``+height``,
``+height_lower``, ... of the types the toolkit's CityJSON Extension gives them (integers as
integers, ``converged`` as a boolean), and the file declares that Extension (``extensions``:
its name, URL and version; the file ships in the package, see :mod:`gnss_citygml.contracts`).
The footprints' own attributes stay plain.

CityJSONSeq (``.city.jsonl``) has the CityJSON header on its first line (empty ``CityObjects``
and ``vertices``) and one ``CityJSONFeature`` per building on each following line, written
chunk by chunk: memory does not grow with the number of buildings.
"""

from __future__ import annotations

import functools
import json
from typing import TYPE_CHECKING

import geopandas as gpd
import numpy as np
import pandas as pd

from ..contracts import EXTENSION, load
from ..errors import InputError, listing
from ..files.paths import atomic_path
from ..files.provenance import KEY
from .attributes import attribute_columns, attribute_values, creation_date, measured_heights
from .output import ExportResult, Progress, check_title, validated_output
from .plan import CHUNK, booleans, chunks, prepare_buildings
from .prisms import SCALE, SURFACES, Prisms, extrude, part_ids

if TYPE_CHECKING:
    import datetime as dt

    from ..files.paths import StrPath

__all__ = ["CRS_URL", "VERSION", "write_cityjson", "write_cityjsonseq"]

#: The CityJSON version written.
VERSION = "2.0"
#: EPSG:7405, OSGB36 / British National Grid + ODN height, as CityJSON names a CRS.
CRS_URL = "https://www.opengis.net/def/crs/EPSG/0/7405"

_SURFACES_JSON = json.dumps([{"type": kind} for kind in SURFACES], separators=(",", ":"))
_RESERVED = ("measuredHeight", "creationDate")
#: The kind (of :func:`~gnss_citygml.export.attributes.attribute_values`) of each column the
#: Extension types, by the column's name (its attribute's without the ``+``).
_TYPED = {
    name[1:]: {"number": "double", "integer": "int", "boolean": "bool", "string": "string"}[
        spec["type"]
    ]
    for name, spec in load(EXTENSION)["extraAttributes"]["Building"].items()
}
#: The least value of each column whose Extension attribute has a ``minimum``.
_MINIMUM = {
    name[1:]: float(spec["minimum"])
    for name, spec in load(EXTENSION)["extraAttributes"]["Building"].items()
    if "minimum" in spec
}


def write_cityjson(
    buildings: gpd.GeoDataFrame,
    path: StrPath,
    *,
    validate: bool = True,
    schema_dir: StrPath | None = None,
    overwrite: bool = False,
    strict: bool = False,
    date: dt.date | str | None = None,
    title: str | None = None,
    provenance: dict | None = None,
    progress: Progress | None = None,
    typed_attributes: bool = False,
) -> ExportResult:
    """Write the buildings as one CityJSON 2.0 file of LOD1 solids.

    Parameters
    ----------
    buildings
        The buildings table with heights (see
        :func:`~gnss_citygml.export.plan.prepare_buildings`): ``id``, ``geometry``, ``ground``,
        ``height`` (absolute roof, m ODN) and any attributes.
    path
        The output file (``.city.json``).
    validate
        Validate the file (:func:`gnss_citygml.validate.validate_file`) before it is renamed
        into place; an invalid file raises
        :class:`~gnss_citygml.export.output.InvalidOutputError` and is not kept.
    schema_dir
        Folder of the official CityJSON JSON schemas, for the validation (default:
        ``$GNSS_CITYGML_SCHEMA_DIR``; without it the JSON Schema check is left out).
    overwrite, strict
        Replace an existing file; stop if a building has no usable height (not skip it).
    date, title, provenance
        The creation date written (``datetime.date`` or ``YYYY-MM-DD``; default today),
        ``metadata.title`` and ``metadata.provenance`` (:mod:`gnss_citygml.files.provenance`).
    progress
        Called with the number of buildings written after each chunk.
    typed_attributes
        Write the toolkit's attributes as ``+height``, ... typed by its CityJSON Extension,
        which the file declares (default: plain attributes).

    Returns
    -------
    ExportResult
        Buildings written and skipped, and the validation report.

    Raises
    ------
    InputError
        Besides the buildings table's errors (:func:`~gnss_citygml.export.plan.prepare_buildings`):
        with ``typed_attributes``, a column the Extension types whose values are not of its
        type (``n_signals`` of 2.5, ``converged`` of ``maybe``).

    Examples
    --------
    >>> import tempfile, shapely
    >>> frame = gpd.GeoDataFrame({"id": ["osgb1"], "ground": [20.0], "height": [32.5]},
    ...                          geometry=[shapely.box(529500, 182300, 529510, 182308)],
    ...                          crs="EPSG:27700")
    >>> with tempfile.TemporaryDirectory() as folder:
    ...     out = write_cityjson(frame, f"{folder}/b.city.json", date="2024-05-01")
    ...     model = json.load(open(out.path))
    >>> out.written, out.report.valid
    (1, True)
    >>> model["CityObjects"]["osgb1"]["attributes"]
    {'measuredHeight': 12.5, 'creationDate': '2024-05-01', 'ground': 20.0, 'height': 32.5}
    """
    plan = prepare_buildings(buildings, strict=strict)
    date = creation_date(date)
    header, translate = _header(plan.bounds_mm(), date, title, typed_attributes, provenance)
    frame = _all_chunks(plan, path)
    parts = part_ids(frame["id"], frame.geometry)
    prisms = extrude(frame.geometry, frame["ground"], frame["height"], numbering="all")
    with atomic_path(path, overwrite=overwrite) as tmp:
        with open(tmp, "w", encoding="utf-8") as out:
            objects = functools.partial(_objects, date=date, typed=typed_attributes)
            _write_model(out, header, frame, prisms, parts, objects, translate, progress)
        report = validated_output(tmp, path, validate, schema_dir)
    return plan.result(path, report)


def _all_chunks(plan, path) -> gpd.GeoDataFrame:
    """The buildings to write, in one table (one file holds them all)."""
    frames = list(plan.chunks())
    if not frames:
        plan.result(path, None)  # raises: nothing to write
    return pd.concat(frames, ignore_index=True)


def _write_model(out, header: dict, frame, prisms, parts, objects, translate, progress) -> None:
    """Stream the file: the header, the city objects chunk by chunk of buildings (their texts
    by ``objects``, :func:`_objects`), the vertices less ``translate``."""
    out.write(_dumps(header)[:-1] + ',"CityObjects":{')
    for part in chunks(len(frame)):
        texts = objects(frame.iloc[part], prisms.take(part), parts[part])
        out.write(("," if part.start else "") + ",".join(texts))
        if progress is not None:
            progress(part.stop - part.start)
    out.write('},"vertices":[')
    for part in chunks(len(prisms.vertices), 64 * CHUNK):
        text = ",".join(_vertex_texts(prisms.vertices[part] - translate))
        out.write(("," if part.start else "") + text)
    out.write("]}\n")


def write_cityjsonseq(
    buildings: gpd.GeoDataFrame,
    path: StrPath,
    *,
    validate: bool = True,
    schema_dir: StrPath | None = None,
    overwrite: bool = False,
    strict: bool = False,
    date: dt.date | str | None = None,
    title: str | None = None,
    provenance: dict | None = None,
    progress: Progress | None = None,
    typed_attributes: bool = False,
) -> ExportResult:
    """Write the buildings as CityJSONSeq: a header line, then one CityJSONFeature per line.

    Parameters and the result are those of :func:`write_cityjson` (``path``: ``.city.jsonl``).
    Buildings are extruded and written a chunk at a time, so memory stays flat however many
    buildings there are.

    Examples
    --------
    >>> import tempfile, shapely
    >>> frame = gpd.GeoDataFrame({"id": ["a", "b"], "ground": [20.0, 21.0],
    ...                           "height": [32.5, 30.0]}, crs="EPSG:27700",
    ...                          geometry=[shapely.box(529500, 182300, 529510, 182308),
    ...                                    shapely.box(529520, 182300, 529530, 182308)])
    >>> with tempfile.TemporaryDirectory() as folder:
    ...     out = write_cityjsonseq(frame, f"{folder}/b.city.jsonl")
    ...     lines = [json.loads(line) for line in open(out.path)]
    >>> [line["type"] for line in lines], lines[2]["vertices"][:2]
    (['CityJSON', 'CityJSONFeature', 'CityJSONFeature'], [[20000, 0, 1000], [20000, 0, 10000]])
    """
    plan = prepare_buildings(buildings, strict=strict)
    date = creation_date(date)
    header, translate = _header(plan.bounds_mm(), date, title, typed_attributes, provenance)
    header.update({"CityObjects": {}, "vertices": []})
    with atomic_path(path, overwrite=overwrite) as tmp:
        with open(tmp, "w", encoding="utf-8") as out:
            out.write(_dumps(header) + "\n")
            for rows in plan.chunks():
                prisms = extrude(rows.geometry, rows["ground"], rows["height"])
                parts = part_ids(rows["id"], rows.geometry)
                objects = _objects(rows, prisms, parts, date, typed_attributes)
                vertices = _nested_text(
                    _vertex_texts(prisms.vertices - translate),
                    [(prisms.vertex_start, "[", "]", ",")],
                )
                out.writelines(
                    f'{{"type":"CityJSONFeature","id":{_dumps(key)},"CityObjects":{{{obj}}},'
                    f'"vertices":{v}}}\n'
                    for key, obj, v in zip(rows["id"].tolist(), objects, vertices, strict=True)
                )
                if progress is not None:
                    progress(len(rows))
        result = plan.result(path, None)  # raises if nothing was written
        result.report = validated_output(tmp, path, validate, schema_dir)
    return result


def _dumps(value) -> str:
    return json.dumps(value, separators=(",", ":"), ensure_ascii=False, allow_nan=False)


def _header(
    bounds: np.ndarray, date: str, title: str | None, typed: bool, provenance: dict | None
) -> tuple[dict, np.ndarray]:
    """The CityJSON object without CityObjects and vertices, and the translation (mm); with
    ``typed``, it declares the toolkit's Extension; the ``provenance`` record
    (:mod:`gnss_citygml.files.provenance`) goes in the metadata, where other members than the
    six the specification names are allowed (3DBAG keeps its version there too). A title
    UTF-8 cannot hold is refused (:func:`~.output.check_title`) before anything is written."""
    check_title(title)
    translate = (bounds[:3] // 1000) * 1000  # whole metres below the data
    metadata = {
        "referenceSystem": CRS_URL,
        "geographicalExtent": (bounds * SCALE).round(3).tolist(),
        "referenceDate": date,
    }
    if title is not None:
        metadata["title"] = title
    if provenance is not None:
        metadata[KEY] = provenance
    header: dict[str, object] = {"type": "CityJSON", "version": VERSION}
    if typed:
        extension = load(EXTENSION)
        header["extensions"] = {
            extension["name"]: {"url": extension["url"], "version": extension["version"]}
        }
    header["transform"] = {"scale": [SCALE] * 3, "translate": (translate * SCALE).tolist()}
    header["metadata"] = metadata
    return header, translate


def _objects(rows: gpd.GeoDataFrame, prisms: Prisms, parts, date: str, typed: bool) -> list[str]:
    """Per building, its CityObjects (the building, then its parts) as JSON members; with
    ``typed``, the toolkit's attributes are those of its Extension (:func:`_typed_values`)."""
    values = [
        ("+" + name, _typed_values(rows, name))
        if typed and name in _TYPED
        else (name, attribute_values(rows[name], kind))
        for name, kind in attribute_columns(rows)
        if name not in _RESERVED
    ]
    heights = measured_heights(rows["ground"], rows["height"])
    solids = _solids(prisms)
    building_start = prisms.building_start.tolist()
    out = []
    for b, key in enumerate(rows["id"].tolist()):
        attributes = {"measuredHeight": heights[b], "creationDate": date}
        attributes.update((name, column[b]) for name, column in values if column[b] is not None)
        text = f'{_dumps(key)}:{{"type":"Building","attributes":{_dumps(attributes)}'
        own = solids[building_start[b] : building_start[b + 1]]
        if not parts[b]:
            out.append(f'{text},"geometry":[{own[0]}]}}')
            continue
        members = [f'{text},"children":{_dumps(parts[b])}}}']
        members.extend(
            f'{_dumps(part)}:{{"type":"BuildingPart","parents":[{_dumps(key)}],'
            f'"geometry":[{solid}]}}'
            for part, solid in zip(parts[b], own, strict=True)
        )
        out.append(",".join(members))
    return out


def _typed_values(rows: pd.DataFrame, name: str) -> list:
    """The values of a column the Extension types, of its type (None where missing).

    Numbers stored as text are read; whole numbers stored as floats (a column with gaps) are
    integers; flags are read as :func:`~gnss_citygml.export.plan.booleans` reads them. A value
    of another type is an error naming the buildings, never written."""
    kind, column = _TYPED[name], rows[name]
    if kind == "bool":
        return attribute_values(booleans(column, name, rows), kind)
    if kind == "string":
        values = attribute_values(column, kind)
        bad = np.array([isinstance(v, list) for v in values], dtype=bool)
    else:
        exact = kind == "int" and pd.api.types.is_integer_dtype(column)  # no float round trip
        numbers = pd.to_numeric(column, errors="coerce")
        if exact and not pd.api.types.is_unsigned_integer_dtype(column):  # (uint64: > int64)
            numbers = column.astype("Int64")
        floats = numbers.astype(float).to_numpy()
        bad = (numbers.isna() & column.notna()).to_numpy()
        if kind == "int":
            bad = bad | (np.isfinite(floats) & (floats % 1 != 0))
        if name in _MINIMUM:
            bad = bad | (floats < _MINIMUM[name])
    if bad.any():
        what = {"int": "a whole number", "double": "a number", "string": "text"}[kind]
        least = f" ({_MINIMUM[name]:g} or more)" if name in _MINIMUM else ""
        raise InputError(
            f"column {name!r} is not {what} as the Extension's '+{name}' is{least} "
            f"(buildings {listing(rows['id'][bad].astype(str).tolist())})",
            where="buildings",
            fix="give it so, or write plain attributes",
        )
    if kind == "string":
        return values
    if exact:
        return attribute_values(numbers, kind)
    numbers = numbers.astype(float).where(np.isfinite(floats))
    return attribute_values(numbers.astype("Int64") if kind == "int" else numbers, kind)


def _solids(prisms: Prisms) -> list[str]:
    """Each solid as a CityJSON Solid geometry (lod 1, with semantic surfaces)."""
    boundaries = _nested_text(
        map(str, prisms.ring_vertices.tolist()),
        [
            (prisms.ring_start, "[", "]", ","),
            (prisms.face_start, "[", "]", ","),
            (prisms.solid_start, "[[", "]]", ","),
        ],
    )
    values = _nested_text(prisms.face_kind.astype(str), [(prisms.solid_start, "[[", "]]", ",")])
    return [
        f'{{"type":"Solid","lod":"1","boundaries":{b},'
        f'"semantics":{{"surfaces":{_SURFACES_JSON},"values":{v}}}}}'
        for b, v in zip(boundaries, values, strict=True)
    ]


def _nested_text(tokens, levels) -> list[str]:
    """Serialise ragged nested groups of text tokens: one text per outermost group.

    Parameters
    ----------
    tokens
        The leaves (texts), in order.
    levels
        From the innermost level out, one ``(start, open, close, separator)`` each: ``start``
        says where each group's children (tokens, or the groups of the level inside) start,
        with a final end entry; ``open`` and ``close`` are written before and after each group,
        ``separator`` between two children of a group.

    Returns
    -------
    list of str

    Notes
    -----
    Before a token come the ``open`` texts of the levels whose groups start at it; after it the
    ``close`` texts of the levels whose groups end at it, then the separator of the next level
    up. Both are counted with numpy, so Python only glues three texts per token.

    Examples
    --------
    >>> levels = [([0, 2, 3, 4], "[", "]", ","), ([0, 2, 3], "[", "]", ",")]
    >>> _nested_text(["1", "2", "3", "4"], levels)
    ['[[1,2],[3]]', '[[4]]']
    """
    tokens = list(tokens)
    n = len(tokens)
    first = last = np.arange(n)
    opened = np.zeros(n, dtype=np.int64)  # levels whose groups start at each token
    closed = np.zeros(n, dtype=np.int64)  # levels whose groups end at each token
    starts = np.ones(n, dtype=bool)
    ends = np.ones(n, dtype=bool)
    for start, *_ in levels:
        start = np.asarray(start)
        first, last = first[start[:-1]], last[start[1:] - 1]
        at_start = np.zeros(n, dtype=bool)
        at_start[first] = True
        at_end = np.zeros(n, dtype=bool)
        at_end[last] = True
        starts &= at_start
        ends &= at_end
        opened += starts
        closed += ends
    before, after, closings = [""], [], ""
    for _, opening, closing, separator in levels:  # texts by number of levels opened/closed
        before.append(opening + before[-1])
        after.append(closings + separator)
        closings += closing
    after.append(closings)
    parts = [
        before[i] + t + after[j]
        for i, t, j in zip(opened.tolist(), tokens, closed.tolist(), strict=True)
    ]
    return ["".join(parts[a : b + 1]) for a, b in zip(first.tolist(), last.tolist(), strict=True)]


def _vertex_texts(vertices: np.ndarray) -> list[str]:
    """``[x,y,z]`` for each row of integer vertices."""
    return [f"[{x},{y},{z}]" for x, y, z in vertices.tolist()]
