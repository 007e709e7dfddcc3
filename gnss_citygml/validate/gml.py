"""The solids of CityGML 2.0 city objects, read into :class:`~.geometry.Shells`.

The exterior and interior shells of every ``gml:Solid`` (those of a ``gml:CompositeSolid``
grouped), their surfaces followed through ``gml:OrientableSurface`` flips and xlinks within the
city object, their rings read from ``gml:posList``, ``gml:pos`` or ``gml:coordinates``.
"""

from __future__ import annotations

import warnings

import numpy as np
from lxml import etree

from .geometry import Shell, Shells
from .report import Issue

__all__ = ["GML", "GML_ID", "gml_solids"]

GML = "http://www.opengis.net/gml"
_GML_PREFIX = f"{{{GML}}}"
GML_ID = f"{{{GML}}}id"
_XLINK_HREF = "{http://www.w3.org/1999/xlink}href"
_SOLID, _COMPOSITE_SOLID = f"{{{GML}}}Solid", f"{{{GML}}}CompositeSolid"
_EXTERIOR, _INTERIOR = f"{{{GML}}}exterior", f"{{{GML}}}interior"
_LINEAR_RING, _POS_LIST, _POS = f"{{{GML}}}LinearRing", f"{{{GML}}}posList", f"{{{GML}}}pos"
_needs_resolving = etree.XPath(
    "boolean(descendant-or-self::gml:OrientableSurface | descendant-or-self::*[@xlink:href])",
    namespaces={"gml": GML, "xlink": "http://www.w3.org/1999/xlink"},
)


def _local(element) -> str:
    return element.tag.rpartition("}")[2]


def gml_solids(member: etree._Element, shells: Shells) -> list[Issue]:
    """Add the solids of one city object member to ``shells``; problems reading them."""
    problems: list[Issue] = []
    lookup: dict[str, etree._Element] | None = None
    for solid in member.iter(_SOLID):
        owner = _owner(solid, member)
        parent = solid.getparent()
        group = None
        if parent is not None and (composite := parent.getparent()) is not None:
            if composite.tag == _COMPOSITE_SOLID:
                group = f"CompositeSolid (line {composite.sourceline})"
        label = f"{_property(solid)} Solid (line {solid.sourceline})"
        for boundary in solid:
            if boundary.tag not in (_EXTERIOR, _INTERIOR):
                continue
            surface = next((c for c in boundary if isinstance(c.tag, str)), None)
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("error", DeprecationWarning)
                    if surface is not None and not _needs_resolving(surface):
                        faces = _gml_plain_faces(surface)
                    else:
                        if lookup is None:
                            lookup = {i: e for e in member.iter() if (i := e.get(GML_ID))}
                        faces = _gml_faces(surface, lookup, reverse=False)
            except _GmlProblem as exc:
                problems.append(Issue(owner, exc.rule, f"{label}: {exc}"))
                continue
            sign = 1 if boundary.tag == _EXTERIOR else -1
            shells.add(Shell(owner, label, sign, group), faces)
    return problems


def _gml_plain_faces(surface) -> list[list[np.ndarray]]:
    """The faces of a surface without xlinks or orientation flips: its rings in order."""
    faces: list[list[np.ndarray]] = []
    rings = [p.getparent() for p in surface.iter(_POS_LIST)] or list(surface.iter(_LINEAR_RING))
    for ring in rings:
        if ring.getparent().tag == _EXTERIOR:
            faces.append([_ring(ring, False)])
        elif faces:
            faces[-1].append(_ring(ring, False))
        else:
            raise _GmlProblem(f"an interior ring before any exterior (line {ring.sourceline})")
    if not faces:
        raise _GmlProblem("a surface without polygons")
    return faces


class _GmlProblem(ValueError):
    """A geometry that cannot be read, with the rule it breaks."""

    def __init__(self, message: str, rule: str = "gml-geometry"):
        super().__init__(message)
        self.rule = rule


def _owner(element, member) -> str:
    """The gml:id of the city object holding ``element`` (else its tag and line)."""
    for ancestor in element.iterancestors():
        if ancestor.get(GML_ID) and not ancestor.tag.startswith(_GML_PREFIX):
            return ancestor.get(GML_ID)
    feature = next((c for c in member if isinstance(c.tag, str)), member)
    return f"{_local(feature)} (line {feature.sourceline})"


def _property(element) -> str:
    for ancestor in element.iterancestors():
        if not ancestor.tag.startswith(_GML_PREFIX):
            return _local(ancestor)
    return "geometry"


def _gml_faces(surface, lookup: dict, reverse: bool) -> list[list[np.ndarray]]:
    """The faces (lists of open rings) of a GML surface, following xlinks within the object."""
    if surface is None:
        raise _GmlProblem("a boundary without a surface")
    name = _local(surface)
    if name in ("Polygon", "PolygonPatch", "Triangle", "Rectangle"):
        rings = []
        for boundary in surface:
            if not isinstance(boundary.tag, str) or _local(boundary) not in (
                "exterior",
                "interior",
            ):
                continue
            ring = next((c for c in boundary if isinstance(c.tag, str)), None)
            if ring is None or _local(ring) != "LinearRing":
                raise _GmlProblem(f"a {name} boundary is not a gml:LinearRing")
            rings.append(_ring(ring, reverse))
        if not rings:
            raise _GmlProblem(f"a {name} without an exterior ring")
        return [rings]
    if name == "OrientableSurface":
        base = _linked(surface, "baseSurface", lookup)
        flip = surface.get("orientation", "+") == "-"
        return [face for b in base for face in _gml_faces(b, lookup, reverse != flip)]
    if name in ("CompositeSurface", "Shell", "MultiSurface"):
        return [
            face
            for member in _linked(surface, ("surfaceMember", "surfaceMembers"), lookup)
            for face in _gml_faces(member, lookup, reverse)
        ]
    if name in ("Surface", "TriangulatedSurface", "Tin", "PolyhedralSurface"):
        patches = [
            patch
            for holder in surface
            if isinstance(holder.tag, str)
            for patch in holder
            if isinstance(patch.tag, str)
        ]
        return [face for patch in patches for face in _gml_faces(patch, lookup, reverse)]
    raise _GmlProblem(f"unsupported surface gml:{name}")


def _linked(element, names, lookup: dict) -> list:
    """The surfaces held by the property children ``names`` of ``element`` (or xlinked)."""
    names = (names,) if isinstance(names, str) else names
    found = []
    for prop in element:
        if not isinstance(prop.tag, str) or _local(prop) not in names:
            continue
        href = prop.get(_XLINK_HREF)
        if href is not None:
            target = lookup.get(href.lstrip("#"))
            if target is None:
                raise _GmlProblem(f"xlink {href} not found in the same city object")
            found.append(target)
        else:
            found.extend(c for c in prop if isinstance(c.tag, str))
    return found


def _ring(ring, reverse: bool) -> np.ndarray:
    """A gml:LinearRing's points, (k, 3), the closing point included."""
    pos_list = ring.find(_POS_LIST)
    if pos_list is not None:
        text = pos_list.text or ""
        dimension = pos_list.get("srsDimension", pos_list.get("dimension", "3"))
    else:
        text = " ".join(p.text or "" for p in ring.iter(_POS))
        dimension = "3"
        if not text.strip():
            coordinates = ring.find(f"{{{GML}}}coordinates")
            if coordinates is not None:
                cs, ts = coordinates.get("cs", ","), coordinates.get("ts", " ")
                text = (coordinates.text or "").replace(cs, " ").replace(ts, " ")
    try:  # the caller makes numpy's DeprecationWarning (text not all numbers) an error
        values = np.fromstring(text, sep=" ") if text.strip() else np.zeros(0)
    except (ValueError, DeprecationWarning):
        raise _GmlProblem(f"unreadable coordinates (line {ring.sourceline})") from None
    if dimension != "3" or values.size % 3:
        raise _GmlProblem(f"a ring without 3D coordinates (line {ring.sourceline})")
    points = values.reshape(-1, 3)
    return points[::-1] if reverse else points
