"""CityGML 2.0 validation: XML Schema, then the geometry of the solids.

XML Schema validation with lxml against the official CityGML 2.0 / GML 3.1.1 / xAL / XLink
schemas bundled unmodified in the PyPI package ``citysmith`` (or those under ``schema_dir`` when
it holds a ``schemas.opengis.net`` tree). A resolver maps every ``http://schemas.opengis.net/...``
import to the local copy; the network is off and no external entity or DTD is ever loaded. The
file is validated while it is parsed and the city objects are freed one by one, so memory stays
flat; only an invalid file is parsed a second time, whole, to list all its schema errors with
their lines.
"""

from __future__ import annotations

import bisect
import urllib.parse
from functools import lru_cache
from pathlib import Path

from lxml import etree

from ..errors import InputError
from .geometry import BATCH, Shells
from .gml import GML, GML_ID, gml_solids
from .report import Issue, Report
from .schemas import citygml_schema_folder

__all__ = ["validate_citygml"]

_CORE = "http://www.opengis.net/citygml/2.0"
_MEMBERS = (f"{{{_CORE}}}cityObjectMember", f"{{{GML}}}featureMember")
_CITYGML2_MODULES = {
    _CORE: "citygml/2.0/cityGMLBase.xsd",
    **{
        f"http://www.opengis.net/citygml/{name.lower()}/2.0": (
            f"citygml/{name.lower()}/2.0/{name}.xsd"
        )
        for name in (
            "appearance",
            "bridge",
            "building",
            "cityFurniture",
            "cityObjectGroup",
            "generics",
            "landUse",
            "relief",
            "texturedSurface",
            "transportation",
            "tunnel",
            "vegetation",
            "waterBody",
        )
    },
}
_OTHER_CITYGML = {
    "http://www.opengis.net/citygml/1.0": "1.0",
    "http://www.opengis.net/citygml/3.0": "3.0",
}


class _LocalSchemas(etree.Resolver):
    """Serve ``http(s)://host/path`` from ``folder/host/path``; never from the network."""

    def __init__(self, folder: Path):
        super().__init__()
        self.folder = folder
        self.missing: list[str] = []

    def resolve(self, url, pubid, context):
        parts = urllib.parse.urlparse(url)
        if parts.scheme in ("http", "https"):
            local = self.folder / parts.netloc / parts.path.lstrip("/")
            if local.is_file():
                return self.resolve_filename(str(local), context)
            self.missing.append(url)
            return self.resolve_string("", context)  # an empty schema fails loudly
        return None


@lru_cache(maxsize=4)
def _citygml_schema(folder: Path) -> etree.XMLSchema:
    """One schema importing every CityGML 2.0 module, compiled offline from ``folder``."""
    imports = "".join(
        f'<xs:import namespace="{ns}" schemaLocation="http://schemas.opengis.net/{rel}"/>'
        for ns, rel in _CITYGML2_MODULES.items()
    )
    wrapper = f'<xs:schema xmlns:xs="http://www.w3.org/2001/XMLSchema">{imports}</xs:schema>'
    resolver = _LocalSchemas(folder)
    parser = etree.XMLParser(no_network=True, resolve_entities=False, load_dtd=False)
    parser.resolvers.add(resolver)
    try:
        document = etree.fromstring(
            wrapper.encode(), parser, base_url=(folder / "wrapper.xsd").as_uri()
        )
        return etree.XMLSchema(document)
    except (etree.XMLSchemaParseError, etree.XMLSyntaxError) as exc:
        missing = ", ".join(resolver.missing) or str(exc).splitlines()[0]
        raise InputError(
            f"cannot compile the CityGML 2.0 schemas (missing: {missing})",
            where=str(folder),
            fix="give --schema-dir holding the official schemas.opengis.net tree",
        ) from None


def _xml_parser_options() -> dict:
    return {"no_network": True, "resolve_entities": False, "load_dtd": False, "huge_tree": True}


def validate_citygml(path: Path, schema_dir: Path | None) -> Report:
    """A CityGML 2.0 file's report: XML Schema errors, then the geometry of its solids."""
    report = Report(str(path), "CityGML 2.0", checks=["xml", "xsd", "geometry"])
    try:
        _, root = next(etree.iterparse(str(path), events=("start",), **_xml_parser_options()))
    except etree.XMLSyntaxError as exc:
        report.errors.append(Issue(None, "xml-syntax", _syntax_message(exc)))
        return report
    namespace = etree.QName(root).namespace
    if namespace in _OTHER_CITYGML:
        raise InputError(
            f"CityGML {_OTHER_CITYGML[namespace]} is not supported, only CityGML 2.0",
            where=str(path),
            fix="validate it with citygml-tools, or convert it to CityGML 2.0",
        )
    if namespace != _CORE:
        if _parsed(path, report) is None:  # not well-formed: invalid, whatever it was meant to be
            return report
        raise InputError(
            f"not a CityGML 2.0 city model (root element {root.tag})",
            where=str(path),
            fix="give a file whose root is core:CityModel",
        )
    schema = _citygml_schema(citygml_schema_folder(schema_dir))
    shells, errors = Shells(closed=True), []
    try:
        for _, member in etree.iterparse(
            str(path), events=("end",), tag=_MEMBERS, schema=schema, **_xml_parser_options()
        ):
            report.n_objects += 1
            errors.extend(gml_solids(member, shells))
            if len(shells) >= BATCH:
                errors.extend(shells.check())
                shells = Shells(closed=True)
            member.clear(keep_tail=True)
            parent = member.getparent()
            while member.getprevious() is not None:
                del parent[0]
    except etree.XMLSyntaxError:  # schema or syntax error: list them all from the whole tree
        return _validate_citygml_tree(path, schema, report)
    report.errors = errors + shells.check()
    return report


def _parsed(path: Path, report: Report):
    """The whole XML tree, or None with the syntax errors in the report."""
    try:
        return etree.parse(str(path), etree.XMLParser(**_xml_parser_options()))
    except etree.XMLSyntaxError as exc:
        report.errors = [
            Issue(None, "xml-syntax", f"line {e.line}, column {e.column}: {e.message}")
            for e in exc.error_log
        ] or [Issue(None, "xml-syntax", _syntax_message(exc))]
        report.n_objects = 0
        return None


def _validate_citygml_tree(path: Path, schema: etree.XMLSchema, report: Report) -> Report:
    tree = _parsed(path, report)
    if tree is None:
        return report
    members = [m for tag in _MEMBERS for m in tree.getroot().iter(tag)]
    members.sort(key=lambda m: m.sourceline)
    lines = [m.sourceline for m in members]
    ids = [next((c.get(GML_ID) for c in m if isinstance(c.tag, str)), None) for m in members]
    errors = []
    if not schema.validate(tree):
        for e in schema.error_log:
            k = bisect.bisect_right(lines, e.line) - 1
            errors.append(Issue(ids[k] if k >= 0 else None, "xsd", f"line {e.line}: {e.message}"))
    shells = Shells(closed=True)
    for member in members:
        errors.extend(gml_solids(member, shells))
    report.errors = errors + shells.check()
    report.n_objects = len(members)
    return report


def _syntax_message(exc: etree.XMLSyntaxError) -> str:
    line, column = exc.position if exc.position else (0, 0)
    return f"line {line}, column {column}: not well-formed XML: {exc.msg}"
