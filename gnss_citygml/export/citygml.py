"""CityGML 2.0 LOD1: one ``bldg:Building`` per footprint, with its height estimate.

The document is a ``core:CityModel`` with ``gml:boundedBy/gml:Envelope`` (``srsName``
EPSG:7405, British National Grid + ODN, ``srsDimension`` 3) and one ``core:cityObjectMember``
per building. A ``bldg:Building`` holds, in the order ``building.xsd`` requires:
``core:creationDate``; generic attributes (``gen:doubleAttribute``, ``gen:intAttribute``,
``gen:stringAttribute``: every column of the buildings table, see
:mod:`gnss_citygml.export.cityjson` for their meaning, plus the original id when it is not a
valid ``gml:id``, under the name of its source's field: ``id``, or e.g. ``toid``, see
:mod:`gnss_citygml.files.ids`); ``bldg:measuredHeight uom="m"`` (roof - ground); then either
``bldg:lod1Solid`` or, for a MultiPolygon footprint, one ``bldg:consistsOfBuildingPart`` per
polygon, each a ``bldg:BuildingPart`` with its own ``bldg:lod1Solid``. A solid is a
``gml:Solid/gml:exterior/gml:CompositeSurface`` of ``gml:Polygon`` s whose ``gml:posList``
rings are closed, in metres with 3 decimals (the millimetre vertices of CityJSON) and oriented
outwards.

``gml:id``: an id that is a valid NCName (letters, digits, ``.``, ``-``, ``_``, not starting
with a digit, ``.`` or ``-``; OS TOIDs such as ``osgb1000005116342`` are) is kept as it is;
any other is sanitised deterministically: every other character becomes ``_`` and ``id_`` is
put in front of a first character that cannot start an NCName (``12/B`` gives ``id_12_B``).

Streaming: :func:`lxml.etree.xmlfile` writes the XML declaration, the ``CityModel`` element
with its namespaces and the envelope; the buildings are serialised a chunk at a time from
string templates (every text and attribute value escaped) into the same stream. Writing each
building as lxml elements measured 9,000 buildings/s, below the 20,000/s this writer must
reach; memory stays flat either way. Within a chunk, the coordinates are formatted once per
distinct (x, y) and per distinct height, and the document is assembled from numbered texts
laid out with numpy (:func:`_members`): 25,000-30,000 buildings/s, where formatting every
vertex and gluing the texts in Python gave 18,000.
"""

from __future__ import annotations

import datetime as dt
import json
import re
import warnings
from collections.abc import Iterable
from xml.sax.saxutils import escape

import geopandas as gpd
import numpy as np
import pandas as pd
from lxml import etree

from ..errors import InputError, listing, user_text
from ..files.paths import StrPath, atomic_path
from ..files.provenance import summary
from .attributes import attribute_columns, attribute_values, creation_date, measured_heights
from .output import ExportResult, Progress, check_title, validated_output
from .plan import CHECK_CHUNK, Plan, chunks, hash_texts, prepare_buildings, repeated_positions
from .prisms import Prisms, extrude, part_ids

__all__ = ["SRS_NAME", "gml_ids", "write_citygml"]

#: The CRS of the model: OSGB36 / British National Grid + ODN height.
SRS_NAME = "EPSG:7405"

_NS = {
    "core": "http://www.opengis.net/citygml/2.0",
    "bldg": "http://www.opengis.net/citygml/building/2.0",
    "gen": "http://www.opengis.net/citygml/generics/2.0",
    "gml": "http://www.opengis.net/gml",
    "xsi": "http://www.w3.org/2001/XMLSchema-instance",
}
_SCHEMA_LOCATION = " ".join(
    [
        _NS["bldg"],
        "http://schemas.opengis.net/citygml/building/2.0/building.xsd",
        _NS["gen"],
        "http://schemas.opengis.net/citygml/generics/2.0/generics.xsd",
    ]
)
_NCNAME = re.compile(r"^[A-Za-z_][A-Za-z0-9._-]*$")
_NOT_NCNAME_CHAR = re.compile(r"[^A-Za-z0-9._-]")
_NOT_XML_CHAR = re.compile("[\x00-\x08\x0b\x0c\x0e-\x1f\ud800-\udfff\ufffe\uffff]")
_POLYGON_OPEN = "<gml:surfaceMember><gml:Polygon>"
_POLYGON_CLOSE = "</gml:Polygon></gml:surfaceMember>"
_SOLID_OPEN = "<gml:Solid><gml:exterior><gml:CompositeSurface>"
_SOLID_CLOSE = "</gml:CompositeSurface></gml:exterior></gml:Solid>"
_PART_CLOSE = "</bldg:lod1Solid></bldg:BuildingPart></bldg:consistsOfBuildingPart>"
_ELEMENT = {"int": "intAttribute", "double": "doubleAttribute"}
_RESERVED = ("measuredHeight", "creationDate")


def gml_ids(ids: Iterable[str]) -> tuple[list[str], list[bool]]:
    """Valid ``gml:id`` s (NCNames) for building ids, and whether each was changed.

    Examples
    --------
    >>> gml_ids(["osgb1000005116342", "12/B", "a b"])
    (['osgb1000005116342', 'id_12_B', 'a_b'], [False, True, True])
    """
    out, changed = [], []
    for text in ids:
        if _NCNAME.match(text):
            out.append(text)
            changed.append(False)
            continue
        clean = _NOT_NCNAME_CHAR.sub("_", text)
        out.append(clean if _NCNAME.match(clean) else "id_" + clean)
        changed.append(True)
    return out, changed


def write_citygml(
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
) -> ExportResult:
    """Write the buildings as a CityGML 2.0 file of LOD1 solids.

    Parameters
    ----------
    buildings
        The buildings table with heights: ``id``, ``geometry``, ``ground``, ``height``
        (absolute roof, m ODN) and any attributes.
    path
        The output file (``.gml``).
    validate
        Validate the file (XML Schema and geometry, :func:`gnss_citygml.validate.validate_file`)
        before it is renamed into place; an invalid file raises
        :class:`~gnss_citygml.export.output.InvalidOutputError` and is not kept.
    schema_dir
        A folder with a ``schemas.opengis.net`` tree to validate against instead of the schemas
        bundled in ``citysmith``.
    overwrite
        Replace an existing file.
    strict
        Stop with an error if a building has no usable height, instead of skipping it.
    date
        ``core:creationDate`` (``datetime.date`` or ``YYYY-MM-DD``; default today).
    title
        The model's ``gml:name``.
    provenance
        Where the model came from (:func:`gnss_citygml.files.provenance.provenance`), written
        as the model's ``gml:description``: its one-line summary, then the record as JSON.
    progress
        Called with the number of buildings written after each chunk.

    Returns
    -------
    ExportResult

    Examples
    --------
    >>> import tempfile, shapely
    >>> frame = gpd.GeoDataFrame({"id": ["osgb1"], "ground": [20.0], "height": [32.5]},
    ...                          geometry=[shapely.box(529500, 182300, 529510, 182308)],
    ...                          crs="EPSG:27700")
    >>> with tempfile.TemporaryDirectory() as folder:
    ...     out = write_citygml(frame, f"{folder}/b.gml")
    ...     tree = etree.parse(out.path)
    >>> out.report.valid, tree.findtext(".//{*}measuredHeight")
    (True, '12.5')
    """
    check_title(title)
    plan = prepare_buildings(buildings, strict=strict)
    date = creation_date(date)
    _check_unique(plan)
    with atomic_path(path, overwrite=overwrite) as tmp:
        replaced = _write_model(tmp, plan, date, (title, provenance), progress)
        result = plan.result(path, None)  # raises if nothing was written
        result.report = validated_output(tmp, path, validate, schema_dir)
    _warn_not_xml(title, replaced)
    return result


def _warn_not_xml(title: str | None, replaced: list[str]) -> None:
    """One warning for the title and one for the buildings whose text XML cannot hold
    (control characters), written with U+FFFD in their place."""
    if title is not None and _NOT_XML_CHAR.search(title):
        warnings.warn(
            f"the title '{user_text(title)}' has characters that XML cannot hold (control "
            "characters), written with U+FFFD in their place (CityJSON keeps them as they are)",
            stacklevel=3,
        )
    if replaced:
        warnings.warn(
            f"{len(replaced)} building(s) have text that XML cannot hold (control characters), "
            f"written with U+FFFD in its place: {listing(map(repr, replaced))}"
            " (CityJSON keeps such text as it is)",
            stacklevel=3,
        )


def _write_model(tmp, plan, date: str, about, progress) -> list[str]:
    """Stream the city model into ``tmp``, chunk by chunk of buildings, with its title and
    provenance (``about``); returns the ids of those whose text XML cannot hold
    (:func:`_unwritable`)."""
    title, provenance = about
    replaced: list[str] = []
    with open(tmp, "wb") as raw:
        with etree.xmlfile(raw, encoding="utf-8") as xf:
            xf.write_declaration()
            root = etree.QName(_NS["core"], "CityModel")
            location = {etree.QName(_NS["xsi"], "schemaLocation"): _SCHEMA_LOCATION}
            with xf.element(root, location, nsmap=_NS):
                if provenance is not None:  # (GML: description, name, then boundedBy)
                    with xf.element(etree.QName(_NS["gml"], "description")):
                        about = f"{summary(provenance)}\n{json.dumps(provenance)}"
                        xf.write(_NOT_XML_CHAR.sub("\ufffd", about))  # (file names' controls)
                if title is not None:
                    with xf.element(etree.QName(_NS["gml"], "name")):
                        xf.write(_NOT_XML_CHAR.sub("\ufffd", title))
                _envelope(xf, plan.bounds_mm())
                for rows in plan.chunks():
                    replaced.extend(_unwritable(rows))
                    prisms = extrude(rows.geometry, rows["ground"], rows["height"], numbering="all")
                    xf.flush()
                    members = _members(rows, prisms, date, plan.id_field)
                    raw.write(members.encode("utf-8"))
                    if progress is not None:
                        progress(len(rows))
    return replaced


def _unwritable(rows: gpd.GeoDataFrame) -> list[str]:
    """Ids of the buildings whose id, attribute names or text attributes hold characters that
    XML 1.0 cannot carry (written as U+FFFD)."""
    texts = [
        c
        for c in rows.columns
        if c != rows.geometry.name
        and (pd.api.types.is_object_dtype(rows[c]) or pd.api.types.is_string_dtype(rows[c]))
    ]
    hit = np.zeros(len(rows), dtype=bool)
    if any(_NOT_XML_CHAR.search(str(c)) for c in rows.columns):
        hit[:] = True
    for column in texts:
        text = rows[column].map(lambda v: v if isinstance(v, str) else "").astype(object)
        hit |= text.str.contains(_NOT_XML_CHAR.pattern, regex=True).to_numpy(dtype=bool)
    return rows["id"][hit].tolist()


def _check_unique(plan: Plan) -> None:
    """Refuse building ids whose gml:ids would be the same (hashed a chunk at a time)."""
    column = plan.frame["id"]
    hashes = np.zeros(len(plan.rows), dtype=np.int64)
    for part in chunks(len(plan.rows), CHECK_CHUNK):
        names = gml_ids(column.iloc[plan.rows[part]].astype(str).tolist())[0]
        hashes[part] = hash_texts(names)
    suspects = repeated_positions(hashes)
    if not suspects.size:
        return
    ids = column.iloc[plan.rows[suspects]].astype(str).tolist()
    names = pd.Series(gml_ids(ids)[0], dtype=object)
    clash = names.duplicated(keep=False).to_numpy()
    if clash.any():
        first = names[clash].iloc[0]
        same = [i for i, n in zip(ids, names, strict=True) if n == first]
        raise InputError(
            f"building ids {', '.join(map(repr, same))} all get the gml:id {first!r}",
            where="buildings",
            fix="give ids that are valid XML names (letters, digits, . - _)",
        )


def _envelope(xf, bounds: np.ndarray) -> None:
    gml = _NS["gml"]
    corners = _coordinates(bounds.reshape(2, 3))
    with xf.element(etree.QName(gml, "boundedBy")):
        attributes = {"srsName": SRS_NAME, "srsDimension": "3"}
        with xf.element(etree.QName(gml, "Envelope"), attributes):
            for name, text in zip(("lowerCorner", "upperCorner"), corners, strict=True):
                with xf.element(etree.QName(gml, name)):
                    xf.write(text)


def _coordinates(mm: np.ndarray) -> list[str]:
    """``"x y z"`` in metres with 3 decimals for each row of millimetre coordinates."""
    return [f"{x:.3f} {y:.3f} {z:.3f}" for x, y, z in (np.asarray(mm) / 1000).tolist()]


def _text(value) -> str:
    return escape(_NOT_XML_CHAR.sub("\ufffd", value))


def _attribute_xml(rows: gpd.GeoDataFrame, changed: list[bool], id_name: str) -> list[list[str]]:
    """Per attribute column, the generic attribute element of each building ('' if missing);
    first the original ids that are not their gml:id, as ``id_name``."""
    columns = []
    names = [(n, k) for n, k in attribute_columns(rows) if n not in _RESERVED]
    if any(changed):
        originals = [_text(i) if c else None for i, c in zip(rows["id"], changed, strict=True)]
        columns.append(_generic(id_name, "string", originals))
    for name, kind in names:
        values = attribute_values(rows[name], kind)
        if kind == "bool":
            values = [None if v is None else str(v).lower() for v in values]
        elif kind == "string":
            values = [
                None if v is None else _text(", ".join(v) if isinstance(v, list) else v)
                for v in values
            ]
        else:
            values = [None if v is None else repr(v) for v in values]
        columns.append(_generic(name, kind, values))
    return columns


def _generic(name: str, kind: str, values: list) -> list[str]:
    element = _ELEMENT.get(kind, "stringAttribute")
    quoted = escape(_NOT_XML_CHAR.sub("\ufffd", name), {'"': "&quot;"})
    start = f'<gen:{element} name="{quoted}"><gen:value>'
    end = f"</gen:value></gen:{element}>"
    return ["" if v is None else start + v + end for v in values]


def _members(rows, prisms: Prisms, date: str, id_name: str) -> str:
    """The cityObjectMember elements of a chunk of buildings, as one text (an original id that
    is not its gml:id is written as the attribute ``id_name``).

    The text is a sequence of tokens from a vocabulary: the fixed texts (:data:`_FIXED`), each
    building's opening (up to its ``bldg:measuredHeight``), each building part's opening, the
    ``"x y "`` of each distinct (x, y) and the ``"z "`` and ``"z"`` of each distinct height.
    Each ring gives a building opening (or ``""``), a solid opening (or ``""``), a ring opening
    (with the solid's and the polygon's openings when it starts them), ``x y`` and ``z`` per
    vertex with the first vertex repeated to close the ring, and a ring closing (with the
    closings of the polygon, solid, part and building it ends). The token numbers are laid out
    with numpy and the tokens joined once: Python does no work per vertex.
    """
    ids, changed = gml_ids(rows["id"].tolist())
    parts = part_ids(ids, rows.geometry)
    creation = f"<core:creationDate>{date}</core:creationDate>"
    opening = [f'<core:cityObjectMember><bldg:Building gml:id="{i}">{creation}' for i in ids]
    heights = [
        f'<bldg:measuredHeight uom="m">{h!r}</bldg:measuredHeight>'
        for h in measured_heights(rows["ground"], rows["height"])
    ]
    attributes = _attribute_xml(rows, changed, id_name)
    headers = list(map("".join, zip(opening, *attributes, heights, strict=True)))
    part_openings = [
        f'<bldg:consistsOfBuildingPart><bldg:BuildingPart gml:id="{part}"><bldg:lod1Solid>'
        for group in parts
        for part in group
    ]
    xy_texts, xy_of, z_texts, z_of = _coordinate_tokens(prisms.vertices)
    groups = [headers, part_openings, xy_texts, [t + " " for t in z_texts], z_texts]
    first = np.cumsum([len(_FIXED)] + [len(g) for g in groups]).tolist()  # of each group
    has_parts = np.array([bool(group) for group in parts], dtype=bool)
    tokens = _tokens(prisms, has_parts, xy_of, z_of, first)
    vocabulary = np.array(_FIXED + [t for g in groups for t in g], dtype=object)
    return "".join(vocabulary[tokens].tolist())


def _tokens(prisms: Prisms, has_parts, xy_of, z_of, first: list[int]) -> np.ndarray:
    """The vocabulary numbers of the chunk's text (see :func:`_members`); ``first`` holds where
    the headers, part openings, ``"x y "``, ``"z "`` and ``"z"`` texts start."""
    header, part_open, xy, z_spaced, z_last = first[:5]
    role = _ring_roles(prisms, has_parts)
    ring_start, vertices = prisms.ring_start, prisms.ring_vertices
    size = np.diff(ring_start)
    length = 2 * size + 6  # 3 openings, x y and z of the closed ring, 1 closing
    at = np.cumsum(length) - length
    tokens = np.zeros(length.sum(), dtype=np.intp)
    tokens[at[role["building_first"]]] = header + np.arange(len(has_parts))
    in_part = role["part"][role["solid_first"]]
    tokens[at[role["solid_first"]] + 1] = np.where(
        in_part, part_open + np.cumsum(in_part) - 1, _LOD1_OPEN
    )
    tokens[at + 2] = role["open"]
    vertex_ring = np.repeat(np.arange(len(size)), size)
    position = at[vertex_ring] + 3 + 2 * (np.arange(len(vertices)) - ring_start[vertex_ring])
    tokens[position] = xy + xy_of[vertices]
    tokens[position + 1] = z_spaced + z_of[vertices]
    closing = vertices[ring_start[:-1]]  # the first vertex again
    tokens[at + length - 3] = xy + xy_of[closing]
    tokens[at + length - 2] = z_last + z_of[closing]
    tokens[at + length - 1] = role["close"]
    return tokens


def _coordinate_tokens(vertices: np.ndarray):
    """``"x y "`` texts of the distinct (x, y) and ``"z"`` texts of the distinct z (m, 3
    decimals) of millimetre vertices, and the index of each vertex's ones."""
    order = np.lexsort((vertices[:, 1], vertices[:, 0]))
    xy = vertices[order, :2]
    new = np.ones(len(xy), dtype=bool)
    new[1:] = (xy[1:] != xy[:-1]).any(axis=1)
    xy_of = np.empty(len(xy), dtype=np.intp)
    xy_of[order] = np.cumsum(new) - 1
    z, z_of = np.unique(vertices[:, 2], return_inverse=True)
    xy_texts = [f"{x:.3f} {y:.3f} " for x, y in (xy[new] / 1000).tolist()]
    return xy_texts, xy_of, [f"{h:.3f}" for h in (z / 1000).tolist()], z_of


def _ring_roles(prisms: Prisms, has_parts: np.ndarray) -> dict[str, np.ndarray]:
    """Per ring: opens its building, opens its solid, lies in a building part, and the
    :data:`_FIXED` numbers of its opening and closing texts."""
    ring_face = np.repeat(np.arange(len(prisms.face_start) - 1), np.diff(prisms.face_start))
    face_solid = np.repeat(np.arange(len(prisms.solid_start) - 1), np.diff(prisms.solid_start))
    solid_building = np.repeat(
        np.arange(len(prisms.building_start) - 1), np.diff(prisms.building_start)
    )
    ring = np.arange(len(ring_face))
    face_first = ring == prisms.face_start[ring_face]
    face_last = ring + 1 == prisms.face_start[ring_face + 1]
    ring_solid = face_solid[ring_face]
    solid_first = face_first & (ring_face == prisms.solid_start[ring_solid])
    solid_last = face_last & (ring_face + 1 == prisms.solid_start[ring_solid + 1])
    ring_building = solid_building[ring_solid]
    building_first = solid_first & (ring_solid == prisms.building_start[ring_building])
    building_last = solid_last & (ring_solid + 1 == prisms.building_start[ring_building + 1])
    part = has_parts[ring_building]
    # a ring opens a face with its exterior ring: exterior == face_first
    opening = _OPEN + face_first + 2 * solid_first
    closing = _CLOSE + face_first + 2 * face_last + 4 * solid_last + 8 * part + 16 * building_last
    return {
        "building_first": building_first,
        "solid_first": solid_first,
        "part": part,
        "open": opening,
        "close": closing,
    }


def _fixed_texts() -> list[str]:
    """``""``, ``<bldg:lod1Solid>``, then the ring openings (numbered exterior + 2 × first of
    its solid) and the ring closings (numbered exterior + 2 × last of its face + 4 × last of
    its solid + 8 × in a building part + 16 × last of its building)."""
    openings, closings = [], []
    for code in range(4):
        exterior, solid_first = code & 1, code & 2
        side = "exterior" if exterior else "interior"
        openings.append(
            (_SOLID_OPEN if solid_first else "")
            + (_POLYGON_OPEN if exterior else "")
            + f'<gml:{side}><gml:LinearRing><gml:posList srsDimension="3">'
        )
    for code in range(32):
        side = "exterior" if code & 1 else "interior"
        closings.append(
            f"</gml:posList></gml:LinearRing></gml:{side}>"
            + (_POLYGON_CLOSE if code & 2 else "")
            + (
                _SOLID_CLOSE + (_PART_CLOSE if code & 8 else "</bldg:lod1Solid>")
                if code & 4
                else ""
            )
            + ("</bldg:Building></core:cityObjectMember>" if code & 16 else "")
        )
    return ["", "<bldg:lod1Solid>", *openings, *closings]


#: The texts every chunk uses; see :func:`_fixed_texts` for their numbering.
_FIXED = _fixed_texts()
_LOD1_OPEN, _OPEN, _CLOSE = 1, 2, 6
