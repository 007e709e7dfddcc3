"""CityGML 2.0 validation: well-formed XML, XML Schema, then the geometry of the solids.

XML Schema validation with lxml against the official CityGML 2.0 / GML 3.1.1 / xAL / XLink
schemas bundled unmodified in the PyPI package ``citysmith`` (or those under ``schema_dir`` when
it holds a ``schemas.opengis.net`` tree). A resolver maps every ``http://schemas.opengis.net/...``
import to the local copy; the network is off. A file with a ``<!DOCTYPE>`` is refused: no DTD
is ever read, no entity expanded. The file is checked for well-formedness, then validated while
it is parsed, the city objects freed one by one, so memory stays flat; only a file with schema
errors is parsed a third time, whole, to list them all with the city objects they are in.
"""

from __future__ import annotations

import re
import urllib.parse
from functools import lru_cache
from pathlib import Path

from lxml import etree

from ..errors import InputError, first_line
from ..files.names import native_name
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
        missing = ", ".join(resolver.missing) or first_line(exc)
        raise InputError(
            f"cannot compile the CityGML 2.0 schemas (missing: {missing})",
            where=str(folder),
            fix="give --schema-dir holding the official schemas.opengis.net tree",
        ) from None


def _xml_parser_options() -> dict:
    return {"no_network": True, "resolve_entities": False, "load_dtd": False, "huge_tree": True}


def validate_citygml(path: Path, schema_dir: Path | None) -> Report:
    """A CityGML 2.0 file's report: XML syntax, XML Schema errors, then the geometry of its solids.

    Up to four passes, the first three at libxml2's speed: the well-formedness of the whole
    file, with no tree built; the root element and the document type (a DTD declaring entities
    or an external DTD is refused); XML Schema validation while the city objects are read and
    freed one by one, their solids gathered as they go; and, for a file with schema errors only,
    the whole tree, to list every error with the city object it is in. The well-formedness pass
    is there because libxml2, validating while it parses, does not report a file that ends too
    early (cut in the middle of a building, or after its last one): it would pass as valid.
    """
    report = Report(str(path), "CityGML 2.0", checks=["xml", "xsd", "geometry"])
    report.errors = _syntax_errors(path)
    if report.errors:  # not well-formed: invalid, whatever it was meant to be
        return report
    _, root = next(etree.iterparse(native_name(path), events=("start",), **_xml_parser_options()))
    namespace = etree.QName(root).namespace
    if namespace in _OTHER_CITYGML:
        raise InputError(
            f"CityGML {_OTHER_CITYGML[namespace]} is not supported, only CityGML 2.0",
            where=str(path),
            fix="validate it with citygml-tools, or convert it to CityGML 2.0",
        )
    if namespace != _CORE:
        raise InputError(
            f"not a CityGML 2.0 city model (root element {root.tag})",
            where=str(path),
            fix="give a file whose root is core:CityModel",
        )
    schema = _citygml_schema(citygml_schema_folder(schema_dir))
    shells, errors = Shells(closed=True), []
    try:
        for _, member in etree.iterparse(
            native_name(path), events=("end",), tag=_MEMBERS, schema=schema, **_xml_parser_options()
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
    except etree.XMLSyntaxError:  # a schema error: list them all from the whole tree
        return _validate_citygml_tree(path, schema, report)
    report.errors = errors + shells.check()
    return report


class _DocumentType(Exception):
    """Raised by :class:`_NoTree` at a ``<!DOCTYPE>``, which stops the parser there."""


class _NoTree:
    """A parser target that builds nothing (the parser only checks that the XML is well-formed)
    and stops at a document type declaration, before its DTD is read."""

    def doctype(self, name, public_id, system_url) -> None:
        raise _DocumentType(name)

    def close(self) -> None:
        return None


def _syntax_errors(path: Path) -> list[Issue]:
    """The file's well-formedness errors, namespaces included (none: well-formed).

    libxml2 stops at the first fatal error; the namespace errors before it (an undeclared
    prefix) are listed too. No tree is built: memory stays flat.

    A file with a ``<!DOCTYPE>`` is refused (an :class:`InputError`, exit code 2: it cannot be
    validated). CityGML uses none, and a DTD is where XML entities are declared: entities
    defined by entities (billion laughs), external entities (a local file, a URL). Here no DTD
    is ever read, no entity expanded, nothing loaded from the network; an entity reference left
    unexpanded would be validated as if it were not there, so the file is refused whole, at its
    document type declaration, before the parser reads the DTD."""
    # types-lxml wants a target with every method of its ParserTarget; lxml calls those it has
    parser = etree.XMLParser(target=_NoTree(), **_xml_parser_options())  # type: ignore[call-overload]
    try:
        etree.parse(native_name(path), parser)
        fatal = None
    except _DocumentType:
        raise InputError(
            "XML entities and DTDs refused: the file has a <!DOCTYPE> declaration",
            where=str(path),
            fix="remove it (CityGML uses none; entities are never expanded nor DTDs loaded here)",
        ) from None
    except (etree.XMLSyntaxError, OSError) as exc:  # OSError: bytes not in the file's encoding
        fatal = exc
    issues = []
    for e in parser.error_log:
        if e.level >= etree.ErrorLevels.ERROR:
            issues.append(_syntax_issue(e.line, e.column, e.message))
            if e.level == etree.ErrorLevels.FATAL:
                break  # what libxml2 says after it, on the same spot, follows from it
    if isinstance(fatal, OSError) and not issues:
        raise InputError(f"cannot read the file ({fatal})", where=str(path), fix="check it")
    if isinstance(fatal, etree.XMLSyntaxError) and not issues:  # not expected: libxml2 logs it
        line, column = fatal.position or (0, 0)
        issues = [_syntax_issue(line, column, re.sub(r", line \d+, column \d+$", "", fatal.msg))]
    return issues


def _validate_citygml_tree(path: Path, schema: etree.XMLSchema, report: Report) -> Report:
    """The report of a well-formed file with schema errors, each with the city object it is in."""
    tree = etree.parse(native_name(path), etree.XMLParser(**_xml_parser_options()))
    members = [m for tag in _MEMBERS for m in tree.getroot().iter(tag)]
    members.sort(key=lambda m: m.sourceline)
    errors = []
    if not schema.validate(tree):
        owners = _Owners(tree.getroot())
        errors = [
            Issue(owners.of(e.path), "xsd", f"line {e.line}: {e.message}") for e in schema.error_log
        ]
    shells = Shells(closed=True)
    for member in members:
        errors.extend(gml_solids(member, shells))
    report.errors = errors + shells.check()
    report.n_objects = len(members)
    return report


_STEP = re.compile(r"(?:(?P<prefix>[^:\[\]]+):)?(?P<name>[^:\[\]]+)(?:\[(?P<index>\d+)\])?")


class _Owners:
    """The city object holding the node of a schema error, found from the error's node path.

    libxml2 names the node as ``/core:CityModel/core:cityObjectMember[2]/bldg:Building/...``
    (each step the element's prefix and name, numbered among its siblings of that name when it
    has any; ``*[k]``, the k-th element child, for an element in a default namespace). The
    owner is the innermost element on that path with a ``gml:id`` outside the GML namespace,
    the rule of :func:`~.gml.gml_solids`; a line can hold every building of a file (the
    project's writer puts its whole GML on one), so lines cannot tell them apart.
    """

    def __init__(self, root):
        self.root = root
        self.children: dict = {}  # element: {step name: [element children of that name]}

    def of(self, path: str | None) -> str | None:
        steps = (path or "").split("/")[2:]  # after the root
        element, owner, feature = self.root, None, None
        for step in steps:
            element = self._child(element, step)
            if element is None:
                break
            if feature is None and element.getparent().tag in _MEMBERS:
                feature = f"{etree.QName(element).localname} (line {element.sourceline})"
            if element.get(GML_ID) and not element.tag.startswith(f"{{{GML}}}"):
                owner = element.get(GML_ID)
        return owner or feature

    def _child(self, element, step: str):
        match = _STEP.fullmatch(step)
        if match is None:  # an attribute, text or comment step: its element is the owner
            return None
        if element not in self.children:
            by_name: dict[str, list] = {"*": []}
            for child in element:
                if isinstance(child.tag, str):
                    by_name["*"].append(child)
                    name = etree.QName(child).localname
                    key = f"{child.prefix}:{name}" if child.prefix else name
                    by_name.setdefault(key, []).append(child)
            self.children[element] = by_name
        prefix, name, index = match.group("prefix", "name", "index")
        siblings = self.children[element].get(f"{prefix}:{name}" if prefix else name, [])
        k = int(index or 1) - 1
        return siblings[k] if k < len(siblings) else None


def _syntax_issue(line: int, column: int, message: str) -> Issue:
    return Issue(
        None, "xml-syntax", f"line {line}, column {column}: not well-formed XML: {message}"
    )
