"""The structural rules of the CityJSON spec: header, vertices, CityObjects, geometries."""

from __future__ import annotations

import re
from typing import Any, TypeGuard

import numpy as np

from .extensions import Extensions
from .geometry import Shell, Shells, coordinate_problem
from .report import Issue, Report

__all__ = ["CityJSONRules"]

_GEOMETRY_DEPTH = {
    "MultiPoint": 1,
    "MultiLineString": 2,
    "MultiSurface": 3,
    "CompositeSurface": 3,
    "Solid": 4,
    "MultiSolid": 5,
    "CompositeSolid": 5,
    "GeometryInstance": 1,
}
_FIRST_LEVEL = {
    "Bridge",
    "Building",
    "CityFurniture",
    "CityObjectGroup",
    "GenericCityObject",
    "LandUse",
    "OtherConstruction",
    "PlantCover",
    "Railway",
    "Road",
    "SolitaryVegetationObject",
    "TINRelief",
    "TransportSquare",
    "Tunnel",
    "WaterBody",
    "Waterway",
}
_SECOND_LEVEL = {
    f"{parent}{child}"
    for parent, children in (
        ("Building", ("Part", "Installation", "ConstructiveElement", "Furniture", "Storey")),
        ("Building", ("Room", "Unit")),
        ("Bridge", ("Part", "Installation", "ConstructiveElement", "Room", "Furniture")),
        ("Tunnel", ("Part", "Installation", "ConstructiveElement", "HollowSpace", "Furniture")),
    )
    for child in children
}
_VERSIONS = ("1.0", "1.1", "2.0")
_LOD = re.compile(r"^\d(\.\d)?$")


class CityJSONRules:
    """The structural rules of the CityJSON spec, for a file or a sequence's header."""

    def __init__(self, header: dict, report: Report):
        self.version = header.get("version")
        transform = header.get("transform")
        self.scale: np.ndarray = np.ones(3)
        self.translate: np.ndarray = np.zeros(3)
        if _is_transform(transform):
            self.scale = np.array(transform["scale"], dtype=float)
            self.translate = np.array(transform["translate"], dtype=float)
        self.transform = transform
        self.extensions = _object_or_empty(header.get("extensions"))
        self.known_extensions = Extensions(self.extensions, report)
        self.report = report
        self._appearance(header)
        templates = _object_or_empty(header.get("geometry-templates"))
        self.n_templates = len(_array_or_empty(templates.get("templates")))
        self.n_template_vertices = len(_array_or_empty(templates.get("vertices-templates")))

    def _appearance(self, doc: dict) -> None:
        appearance = _object_or_empty(doc.get("appearance"))
        self.n_materials = len(_array_or_empty(appearance.get("materials")))
        self.n_textures = len(_array_or_empty(appearance.get("textures")))
        self.n_uv = len(_array_or_empty(appearance.get("vertices-texture")))

    def header(self, doc: dict, where: str, *, sequence: bool = False) -> list[Issue]:
        """Rules of the CityJSON object: type, version, transform, extensions."""
        issues = []
        if doc.get("type") != "CityJSON":
            issues.append(
                Issue(None, "cityjson-type", where + f"type is {doc.get('type')!r}, not 'CityJSON'")
            )
        if self.version not in _VERSIONS:
            issues.append(
                Issue(
                    None,
                    "version",
                    where + f"unknown CityJSON version {self.version!r} "
                    f"(known: {', '.join(_VERSIONS)})",
                )
            )
        if self.transform is not None and not _is_transform(self.transform):
            issues.append(
                Issue(
                    None,
                    "transform",
                    where + "transform needs scale and translate, 3 finite numbers each, "
                    "scale non-zero",
                )
            )
        elif self.transform is None and self.version in ("1.1", "2.0"):
            issues.append(Issue(None, "transform", where + f"CityJSON {self.version} needs one"))
        if sequence and (doc.get("CityObjects") != {} or doc.get("vertices") != []):
            issues.append(
                Issue(
                    None,
                    "seq-header",
                    where + "the first line of a CityJSONSeq has empty CityObjects and vertices",
                )
            )
        issues += self._extension_names(doc, None, where, "root property")
        return issues

    def feature(self, doc: dict, where: str) -> list[Issue]:
        """Rules of a CityJSONFeature: type, id among its CityObjects."""
        issues = []
        if doc.get("type") != "CityJSONFeature":
            issues.append(
                Issue(
                    None,
                    "cityjson-type",
                    where + f"type is {doc.get('type')!r}, not 'CityJSONFeature'",
                )
            )
        objects, key = doc.get("CityObjects"), doc.get("id")
        if not (isinstance(objects, dict) and isinstance(key, str) and key in objects):
            issues.append(
                Issue(
                    key if isinstance(key, str) else None,
                    "feature-id",
                    where + "the feature's id is not one of its CityObjects",
                )
            )
        if "appearance" in doc:
            self._appearance(doc)
        return issues

    def _extension_names(self, mapping, object_id, where, what) -> list[Issue]:
        plus = [k for k in _object_or_empty(mapping) if k.startswith("+")]
        if plus and not self.extensions:
            return [
                Issue(
                    object_id,
                    "extension",
                    where + f"{what} {plus[0]!r} belongs to an Extension the file does not declare",
                )
            ]
        return []

    def objects(self, doc: dict, where: str, shells: Shells) -> list[Issue]:
        """Rules of the CityObjects and vertices; their solids go to ``shells``."""
        objects = doc.get("CityObjects")
        if not isinstance(objects, dict):
            return [Issue(None, "cityobjects", where + "CityObjects is not a JSON object")]
        issues, n_vertices, vertices = self._vertices(doc.get("vertices"), where)
        for key, obj in objects.items():
            if not isinstance(obj, dict):
                issues.append(Issue(key, "cityobjects", where + "not a JSON object"))
                continue
            issues += self._object(key, obj, objects, where)
            geometries = obj.get("geometry", [])
            if not isinstance(geometries, list):
                issues.append(Issue(key, "geometry-type", where + "geometry is not an array"))
                continue
            for geometry in geometries:
                issues += self._geometry(key, geometry, n_vertices, vertices, where, shells)
        return issues

    def _vertices(self, vertices, where: str):
        """Problems, the number of vertices (None: indices unchecked), their coordinates (None:
        no geometry checked)."""
        if vertices == []:
            return [], 0, np.zeros((0, 3))
        try:
            array = np.array(vertices)
        except (ValueError, OverflowError):
            array = np.array([], dtype=object)
        if array.ndim != 2 or array.shape[1] != 3 or array.dtype.kind not in "iuf":
            problem = "vertices are not [x, y, z] numbers"
            return [Issue(None, "vertices", where + problem)], None, None
        if self.transform is not None and array.dtype.kind == "f":
            problem = "vertices must be integers with a transform"
            return [Issue(None, "vertices", where + problem)], len(array), None
        with np.errstate(over="ignore", invalid="ignore"):  # reported just below
            coordinates = array * self.scale + self.translate
        problem = coordinate_problem(coordinates, ", after the transform" if self.transform else "")
        if problem:
            return [Issue(None, "coordinate-range", where + problem)], len(array), None
        return [], len(array), coordinates

    def _object(self, key: str, obj: dict, objects: dict, where: str) -> list[Issue]:
        issues = []
        kind = obj.get("type")
        if not isinstance(kind, str):
            kind = repr(kind)  # unknown, and a name in the message
        if kind.startswith("+"):
            if kind[1:] and not self.extensions:
                issues.append(
                    Issue(key, "extension", where + f"type {kind!r} needs a declared Extension")
                )
        elif kind not in _FIRST_LEVEL and kind not in _SECOND_LEVEL:
            issues.append(
                Issue(key, "cityobject-type", where + f"unknown CityObject type {kind!r}")
            )
        if kind in _SECOND_LEVEL and not obj.get("parents"):
            issues.append(Issue(key, "parent-child", where + f"a {kind} needs a parent"))
        for link, back in (("children", "parents"), ("parents", "children")):
            for other in _array_or_empty(obj.get(link)):
                target = objects.get(other) if isinstance(other, str) else None
                if not isinstance(target, dict):
                    issues.append(
                        Issue(key, "parent-child", where + f"{link[:-1]} {other!r} does not exist")
                    )
                elif key not in _array_or_empty(target.get(back)):
                    issues.append(
                        Issue(
                            key,
                            "parent-child",
                            where + f"{link[:-1]} {other!r} does not list it in its {back}",
                        )
                    )
        issues += self._extension_names(obj.get("attributes"), key, where, "attribute")
        issues += self.known_extensions.errors(key, obj, where)
        return issues

    def _geometry(self, key, geometry, n_vertices, vertices, where, shells) -> list[Issue]:
        if not isinstance(geometry, dict):
            return [Issue(key, "geometry-type", where + "a geometry is not a JSON object")]
        kind = geometry.get("type")
        depth = _GEOMETRY_DEPTH.get(kind) if isinstance(kind, str) else None
        if depth is None:
            return [Issue(key, "geometry-type", where + f"unknown geometry type {kind!r}")]
        lod = geometry.get("lod")
        label = f"{kind} (lod {lod})"
        issues = []
        if kind != "GeometryInstance":
            if self.version == "1.0" and not isinstance(lod, int | float):
                issues.append(Issue(key, "lod", where + f"{label}: lod must be a number in 1.0"))
            elif self.version != "1.0" and not (isinstance(lod, str) and _LOD.match(lod)):
                issues.append(
                    Issue(key, "lod", where + f"{kind}: lod {lod!r} is not a string like '2.2'")
                )
        boundaries: Any = geometry.get("boundaries")  # JSON, checked by _flatten
        leaves, problem = _flatten(boundaries, depth)
        if problem:
            return issues + [Issue(key, "boundaries", where + f"{label}: {problem}")]
        limit = n_vertices
        if kind == "GeometryInstance":
            issues += self._instance(key, geometry, leaves, where)
        elif limit is not None and leaves and (max(leaves) >= limit or min(leaves) < 0):
            bad = max(leaves) if max(leaves) >= limit else min(leaves)
            return issues + [
                Issue(
                    key,
                    "vertex-index",
                    where + f"{label}: vertex index {bad} out of range ({limit} vertices)",
                )
            ]
        issues += self._semantics(key, geometry, boundaries, depth, label, where)
        issues += self._appearances(key, geometry, boundaries, depth, label, where)
        if kind in ("Solid", "MultiSolid", "CompositeSolid") and vertices is not None:
            solids = [boundaries] if kind == "Solid" else boundaries
            group = f"{key}/{id(geometry)}" if kind == "CompositeSolid" else None
            for s, solid in enumerate(solids):
                name = label if kind == "Solid" else f"{label} solid {s}"
                for k, shell in enumerate(solid):
                    faces = [[vertices[ring] for ring in face] for face in shell]
                    shells.add(Shell(key, f"{name} shell {k}", 1 if k == 0 else -1, group), faces)
        return issues

    def _instance(self, key, geometry, leaves, where) -> list[Issue]:
        issues = []
        template = geometry.get("template")
        if type(template) is not int or not 0 <= template < self.n_templates:
            issues.append(Issue(key, "template", where + f"template {template!r} does not exist"))
        if len(leaves) != 1:
            issues.append(
                Issue(key, "boundaries", where + "a GeometryInstance has one reference vertex")
            )
        matrix = geometry.get("transformationMatrix")
        if not isinstance(matrix, list) or len(matrix) != 16:
            issues.append(Issue(key, "template", where + "transformationMatrix needs 16 numbers"))
        return issues

    def _semantics(self, key, geometry, boundaries, depth, label, where) -> list[Issue]:
        semantics = geometry.get("semantics")
        if semantics is None:
            return []
        if depth < 3 or not isinstance(semantics, dict):
            return [Issue(key, "semantics", where + f"{label}: semantics not allowed here")]
        surfaces = semantics.get("surfaces")
        if not isinstance(surfaces, list):
            return [Issue(key, "semantics", where + f"{label}: semantics without surfaces")]
        problem = _values_match(semantics.get("values"), boundaries, depth - 2, len(surfaces))
        if problem:
            return [Issue(key, "semantics", where + f"{label}: semantic values {problem}")]
        for surface in surfaces:
            if not isinstance(surface, dict):
                return [Issue(key, "semantics", where + f"{label}: a surface is not a JSON object")]
            for link in ("parent", *_array_or_empty(surface.get("children"))):
                target = surface.get("parent") if link == "parent" else link
                if target is not None and not (type(target) is int and 0 <= target < len(surfaces)):
                    return [Issue(key, "semantics", where + f"{label}: semantic link {target!r}")]
        return []

    def _appearances(self, key, geometry, boundaries, depth, label, where) -> list[Issue]:
        themes = [
            (kind, theme, value)
            for kind in ("material", "texture")
            for theme, value in _object_or_empty(geometry.get(kind)).items()
        ]
        if themes and depth < 3:
            return [Issue(key, "appearance", where + f"{label}: appearances not allowed here")]
        issues = []
        for kind, theme, value in themes:
            if not isinstance(value, dict):
                problem = "not a JSON object"
            elif kind == "texture":
                problem = _texture_match(value.get("values"), boundaries, depth - 1, self)
            elif "value" in value:
                index = value["value"]
                ok = type(index) is int and 0 <= index < self.n_materials
                problem = None if ok else f"{index!r} refers to no material"
            else:
                problem = _values_match(
                    value.get("values"), boundaries, depth - 2, self.n_materials
                )
                problem = problem and f"values {problem} ({self.n_materials} materials)"
            if problem:
                issues.append(
                    Issue(key, "appearance", where + f"{label}: {kind} {theme!r}: {problem}")
                )
        return issues


def _object_or_empty(value) -> dict:
    """``value`` if it is a JSON object, else an empty one: a wrong type is the JSON Schema's."""
    return value if isinstance(value, dict) else {}


def _array_or_empty(value) -> list:
    """``value`` if it is a JSON array, else an empty one: a wrong type is the JSON Schema's."""
    return value if isinstance(value, list) else []


def _is_transform(transform) -> TypeGuard[dict]:
    """Whether ``transform`` has scale and translate, 3 finite numbers each, scale non-zero."""
    if not isinstance(transform, dict):
        return False
    parts: list[Any] = [transform.get("scale"), transform.get("translate")]
    if not all(isinstance(p, list) and len(p) == 3 for p in parts):
        return False
    if not all(isinstance(v, int | float) and not isinstance(v, bool) for p in parts for v in p):
        return False
    try:
        values = np.array(parts, dtype=float)
    except OverflowError:  # an integer beyond any float
        return False
    return bool(np.isfinite(values).all() and values[0].all())


def _flatten(boundaries, depth: int):
    """The vertex indices of boundaries nested ``depth`` arrays deep, or a problem."""
    level = [boundaries]
    for d in range(depth):
        nested = []
        for item in level:
            if not isinstance(item, list):
                return None, f"boundaries must be nested {depth} arrays deep (depth {d})"
            nested.extend(item)
        level = nested
    if not all(type(v) is int for v in level):
        return None, "vertex indices must be integers"
    return level, None


def _values_match(values, boundaries, depth: int, count: int) -> str | None:
    """Whether ``values`` mirror ``boundaries`` down to ``depth`` with indices < ``count``."""
    if values is None:
        return None
    if depth == 0:
        if type(values) is int and 0 <= values < count:
            return None
        return f"{values!r} refers to nothing"
    if not isinstance(values, list) or len(values) != len(boundaries):
        return "do not match the boundaries"
    for v, b in zip(values, boundaries, strict=True):
        problem = _values_match(v, b, depth - 1, count)
        if problem:
            return problem
    return None


def _texture_match(values, boundaries, depth: int, rules: CityJSONRules) -> str | None:
    """Texture values: per ring, [texture, uv per vertex], or [null]."""
    if values is None:
        return None
    if not isinstance(values, list) or len(values) != len(boundaries):
        return "values do not match the boundaries"
    if depth > 1:
        for v, b in zip(values, boundaries, strict=True):
            problem = _texture_match(v, b, depth - 1, rules)
            if problem:
                return problem
        return None
    for entry, ring in zip(values, boundaries, strict=True):
        if entry == [None]:
            continue
        if not isinstance(entry, list) or not all(type(i) is int for i in entry):
            return f"indices must be integers ({entry!r})"
        if len(entry) != len(ring) + 1:
            return "one texture and one uv index per ring vertex needed"
        if not 0 <= entry[0] < rules.n_textures:
            return f"texture {entry[0]} does not exist"
        if any(not 0 <= i < rules.n_uv for i in entry[1:]):
            return "uv index out of range"
    return None
