"""CityGML 2.0 LOD1: one ``bldg:Building`` per footprint, with its height estimate.

The document is a ``core:CityModel`` with ``gml:boundedBy/gml:Envelope`` (``srsName``
EPSG:7405, British National Grid + ODN, ``srsDimension`` 3) and one ``core:cityObjectMember``
per building. A ``bldg:Building`` holds, in the order ``building.xsd`` requires:
``core:creationDate``; generic attributes (``gen:doubleAttribute``, ``gen:intAttribute``,
``gen:stringAttribute``: every column of the buildings table, see
:mod:`gnss_citygml.export.cityjson` for their meaning, plus ``id``, the original id, when it is
not a valid ``gml:id``); ``bldg:measuredHeight uom="m"`` (roof - ground); then either
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
reach; memory stays flat either way.
"""

from __future__ import annotations

import re
from xml.sax.saxutils import escape

import geopandas as gpd
import numpy as np
import pandas as pd
from lxml import etree

from ..errors import InputError
from ..tables import atomic_path
from .lod1 import (
    ExportResult,
    Prisms,
    Progress,
    attribute_columns,
    attribute_values,
    creation_date,
    extrude,
    measured_heights,
    nested_text,
    part_ids,
    prepare_buildings,
    validated_output,
)

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
_NOT_XML_CHAR = re.compile("[\x00-\x08\x0b\x0c\x0e-\x1f\ufffe\uffff]")
_POLYGON_OPEN = "<gml:surfaceMember><gml:Polygon>"
_POLYGON_CLOSE = "</gml:Polygon></gml:surfaceMember>"
_ELEMENT = {"int": "intAttribute", "double": "doubleAttribute"}
_RESERVED = ("measuredHeight", "creationDate")


def gml_ids(ids) -> tuple[list[str], list[bool]]:
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
    path,
    *,
    validate: bool = True,
    schema_dir=None,
    overwrite: bool = False,
    strict: bool = False,
    date=None,
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
        :class:`~gnss_citygml.export.lod1.InvalidOutputError` and is not kept.
    schema_dir
        A folder with a ``schemas.opengis.net`` tree to validate against instead of the schemas
        bundled in ``citysmith``.
    overwrite
        Replace an existing file.
    strict
        Stop with an error if a building has no usable height, instead of skipping it.
    date
        ``core:creationDate`` (``datetime.date`` or ``YYYY-MM-DD``; default today).
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
    plan = prepare_buildings(buildings, strict=strict)
    date = creation_date(date)
    _check_unique(plan.frame["id"].astype(str).to_numpy()[plan.rows])
    with atomic_path(path, overwrite=overwrite) as tmp:
        with open(tmp, "wb") as raw:
            with etree.xmlfile(raw, encoding="utf-8") as xf:
                xf.write_declaration()
                root = etree.QName(_NS["core"], "CityModel")
                location = {etree.QName(_NS["xsi"], "schemaLocation"): _SCHEMA_LOCATION}
                with xf.element(root, location, nsmap=_NS):
                    _envelope(xf, plan.bounds_mm())
                    for rows in plan.chunks():
                        prisms = extrude(
                            rows.geometry, rows["ground"], rows["height"], numbering="all"
                        )
                        xf.flush()
                        raw.write(_members(rows, prisms, date).encode("utf-8"))
                        if progress is not None:
                            progress(len(rows))
        result = plan.result(path, None)  # raises if nothing was written
        result.report = validated_output(tmp, path, validate, schema_dir)
    return result


def _check_unique(ids) -> None:
    """Refuse building ids whose gml:ids would be the same."""
    names = pd.Series(gml_ids(ids)[0])
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


def _attribute_xml(rows: gpd.GeoDataFrame, changed: list[bool]) -> list[list[str]]:
    """Per attribute column, the generic attribute element of each building ('' if missing)."""
    columns = []
    names = [(n, k) for n, k in attribute_columns(rows) if n not in _RESERVED]
    if any(changed):
        originals = [_text(i) if c else None for i, c in zip(rows["id"], changed, strict=True)]
        columns.append(_generic("id", "string", originals))
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


def _members(rows, prisms: Prisms, date: str) -> str:
    """The cityObjectMember elements of a chunk of buildings."""
    ids, changed = gml_ids(rows["id"].tolist())
    parts = part_ids(ids, rows.geometry)
    attributes = _attribute_xml(rows, changed)
    heights = measured_heights(rows["ground"], rows["height"])
    solids = _solids(prisms)
    building_start = prisms.building_start.tolist()
    out = []
    for b, gml_id in enumerate(ids):
        out.append(
            f'<core:cityObjectMember><bldg:Building gml:id="{gml_id}">'
            f"<core:creationDate>{date}</core:creationDate>"
        )
        out.extend(column[b] for column in attributes)
        out.append(f'<bldg:measuredHeight uom="m">{heights[b]!r}</bldg:measuredHeight>')
        own = solids[building_start[b] : building_start[b + 1]]
        if not parts[b]:
            out.append(f"<bldg:lod1Solid>{own[0]}</bldg:lod1Solid>")
        else:
            out.extend(
                f'<bldg:consistsOfBuildingPart><bldg:BuildingPart gml:id="{part}">'
                f"<bldg:lod1Solid>{solid}</bldg:lod1Solid>"
                "</bldg:BuildingPart></bldg:consistsOfBuildingPart>"
                for part, solid in zip(parts[b], own, strict=True)
            )
        out.append("</bldg:Building></core:cityObjectMember>")
    return "".join(out)


def _solids(prisms: Prisms) -> list[str]:
    """Each solid of the chunk as a ``gml:Solid`` element."""
    coordinates = _coordinates(prisms.vertices)
    points = [coordinates[v] for v in prisms.ring_vertices.tolist()]
    ring_start, face_start = prisms.ring_start, prisms.face_start
    exterior = np.zeros(len(ring_start) - 1, dtype=bool)
    exterior[face_start[:-1]] = True
    firsts, lasts = ring_start[:-1].tolist(), (ring_start[1:] - 1).tolist()
    for first, last, outer in zip(firsts, lasts, exterior.tolist(), strict=True):
        side = "exterior" if outer else "interior"
        closing = f" {points[first]}</gml:posList></gml:LinearRing></gml:{side}>"
        points[last] += closing  # the ring closed on its first point
        points[first] = (
            f'<gml:{side}><gml:LinearRing><gml:posList srsDimension="3">' + (points[first])
        )
    return nested_text(
        points,
        [
            (ring_start, "", "", " "),
            (face_start, _POLYGON_OPEN, _POLYGON_CLOSE, ""),
            (
                prisms.solid_start,
                "<gml:Solid><gml:exterior><gml:CompositeSurface>",
                "</gml:CompositeSurface></gml:exterior></gml:Solid>",
                "",
            ),
        ],
    )
