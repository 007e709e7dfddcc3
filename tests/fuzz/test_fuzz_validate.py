"""Fuzzing the readers behind ``gnss-citygml validate``: CityJSON, CityJSONSeq and CityGML 2.0.

Seeds: three buildings written by the project's own writers (one with a courtyard, so a face
with a hole), and a few small official samples from the shared data (xlinked surfaces, a
CompositeSolid, semantics, materials). The bytes are mutated (:func:`mutated`), and, to reach
the CityJSON rules with JSON that still parses, so are the values of the parsed documents
(:func:`json_mutated`: any JSON where a type, a boundary, an index or a link should be).

Every case must end as a :class:`Report` or one :class:`GnssCityGMLError` line, each of the
report's errors printable as one line; and a file that is not well-formed (XML that lxml cannot
parse, text that is not JSON) is never valid. The outcomes are counted in the statistics
(``--hypothesis-show-statistics``).
"""

from __future__ import annotations

import copy
import json
import tempfile
from pathlib import Path

import geopandas as gpd
import pytest
import shapely
from hypothesis import event, given
from hypothesis import strategies as st
from lxml import etree

from gnss_citygml.export import write_citygml, write_cityjson, write_cityjsonseq
from gnss_citygml.validate import Report, validate_file

from .conftest import mutated

E, N = 529500.0, 182300.0


def _seed(writer, suffix: str) -> bytes:
    """Three LOD1 buildings (one with a courtyard) as the writer writes them."""
    buildings = gpd.GeoDataFrame(
        {"id": ["a", "courtyard", "c"], "ground": [20.0, 21.0, 22.0], "height": [32.5, 30, 31]},
        geometry=[
            shapely.box(E, N, E + 10, N + 8),
            shapely.box(E + 20, N, E + 32, N + 12).difference(
                shapely.box(E + 24, N + 4, E + 28, N + 8)
            ),
            shapely.box(E + 40, N, E + 50, N + 8),
        ],
        crs="EPSG:27700",
    )
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / f"seed{suffix}"
        writer(buildings, path, date="2024-05-01")
        return path.read_bytes()


CITYJSON = _seed(write_cityjson, ".city.json")
CITYJSONSEQ = _seed(write_cityjsonseq, ".city.jsonl")
CITYGML = _seed(write_citygml, ".gml")
#: Small official samples, valid and invalid, read from the shared data at test time.
SAMPLES = [
    "citygml2/ogc_examples/Building_LOD2-EPSG25832.gml",
    "citygml2/val3dity_csol1_valid.gml",
    "cityjson/cjval_cube.city.json",
    "cityjson/cjval_cjfeat1.city.json",
    "cityjson/invalid/cjval_material_overflow.city.json",
    "cityjson/invalid/cjval_cube_20_typo_GnericCityObject.city.jsonl",
]


@pytest.fixture(scope="module")
def folder():
    """One folder for the fuzz cases of the module (hypothesis reuses it across examples)."""
    with tempfile.TemporaryDirectory(prefix="fuzz-validate-") as name:
        yield Path(name)


@pytest.fixture(scope="module")
def schema_dir(repo_data) -> Path:
    """The official CityJSON schemas: the JSON Schema check runs on every case."""
    return repo_data / "schemas" / "cityjson"


def _validate(data: bytes, path: Path, schema_dir: Path, clean) -> Report | None:
    """The report (None after a one-line error); the outcomes are counted in the statistics."""
    path.write_bytes(data)
    report = clean(validate_file, path, schema_dir=schema_dir)
    if report is None:
        event("could not validate (one-line error, exit 2)")
        return None
    assert isinstance(report, Report)
    assert all("\n" not in issue.line() for issue in report.errors)
    assert "\n" not in report.summary()
    event("valid" if report.valid else f"invalid, first error: {report.errors[0].rule}")
    return report


def _not_xml(data: bytes) -> bool:
    parser = etree.XMLParser(no_network=True, resolve_entities=False, load_dtd=False)
    try:
        etree.fromstring(data, parser)
    except etree.XMLSyntaxError:
        return True
    return False


def _not_json(data: bytes) -> bool:
    """Neither one JSON document nor JSON documents one per line, for Python's own reader."""
    try:
        json.loads(data)
        return False
    except (ValueError, RecursionError):
        pass
    try:
        for line in data.splitlines():
            if line.strip():
                json.loads(line)
    except (ValueError, RecursionError):
        return True
    return False


@given(data=mutated(CITYJSON))
def test_cityjson(data, folder, schema_dir, clean):
    report = _validate(data, folder / "f.city.json", schema_dir, clean)
    assert not (report and report.valid and _not_json(data))


@given(data=mutated(CITYJSONSEQ))
def test_cityjsonseq(data, folder, schema_dir, clean):
    report = _validate(data, folder / "f.city.jsonl", schema_dir, clean)
    assert not (report and report.valid and _not_json(data))


@given(data=mutated(CITYGML))
def test_citygml(data, folder, schema_dir, clean):
    report = _validate(data, folder / "f.gml", schema_dir, clean)
    assert not (report and report.valid and _not_xml(data))


@given(data=st.data())
def test_official_samples(data, shared_data, folder, schema_dir, clean):
    name = data.draw(st.sampled_from(SAMPLES), label="sample")
    seed = (shared_data / "citymodels" / name).read_bytes()
    mutant = data.draw(mutated(seed), label="bytes")
    report = _validate(mutant, folder / Path(name).name, schema_dir, clean)
    not_parsed = _not_xml(mutant) if name.endswith(".gml") else _not_json(mutant)
    assert not (report and report.valid and not_parsed)


#: Keys the CityJSON rules look up, for the objects that :func:`json_mutated` makes.
KEYS = ["type", "geometry", "boundaries", "lod", "semantics", "surfaces", "values", "value"]
KEYS += ["material", "texture", "parents", "children", "attributes", "vertices", "transform"]
KEYS += ["scale", "translate", "appearance", "template", "id", "CityObjects", "+ext"]
JSON_VALUES = st.recursive(
    st.none()
    | st.booleans()
    | st.integers()
    | st.integers(-1, 20)
    | st.floats(allow_nan=False, allow_infinity=False)
    | st.text(max_size=6)
    | st.sampled_from(["Building", "BuildingPart", "Solid", "MultiSurface", "1", "+X", "2.0"]),
    lambda children: (
        st.lists(children, max_size=4)
        | st.dictionaries(st.sampled_from(KEYS) | st.text(max_size=4), children, max_size=4)
    ),
    max_leaves=12,
)


@st.composite
def json_mutated(draw, document, max_ops: int = 4):
    """``document`` with 1..max_ops values replaced, deleted or added at any depth, half of
    them inside a CityObject (its type, links, geometries, boundaries, semantics...)."""
    document = copy.deepcopy(document)
    for _ in range(draw(st.integers(1, max_ops))):
        parent, key, node = None, None, document
        objects = document.get("CityObjects") if isinstance(document, dict) else None
        if isinstance(objects, dict) and objects and draw(st.booleans()):
            parent, key = objects, draw(st.sampled_from(sorted(objects)))
            node = objects[key]
        for _ in range(draw(st.sampled_from(range(8)))):
            if not isinstance(node, dict | list) or not node:
                break
            keys = sorted(node) if isinstance(node, dict) else range(len(node))
            parent, key = node, draw(st.sampled_from(keys))
            node = parent[key]
        if parent is None:
            continue
        op = draw(st.sampled_from(["replace", "delete", "add"]))
        if op == "replace":
            parent[key] = draw(JSON_VALUES)
        elif op == "delete":
            del parent[key]
        elif isinstance(parent, dict):
            parent[draw(st.sampled_from(KEYS))] = draw(JSON_VALUES)
        else:
            parent.insert(key, draw(JSON_VALUES))
    return document


SEQ_LINES = [json.loads(line) for line in CITYJSONSEQ.splitlines()]


@given(data=st.data())
def test_cityjson_values(data, folder, schema_dir, clean):
    """JSON that parses, with values of any type and shape: a CityJSON file, or a line of a
    CityJSONSeq."""
    if data.draw(st.booleans(), label="sequence"):
        lines = list(SEQ_LINES)
        k = data.draw(st.integers(0, len(lines) - 1), label="line")
        lines[k] = data.draw(json_mutated(lines[k]), label="document")
        text, path = "\n".join(json.dumps(line) for line in lines) + "\n", "v.city.jsonl"
    else:
        text = json.dumps(data.draw(json_mutated(json.loads(CITYJSON)), label="document"))
        path = "v.city.json"
    _validate(text.encode(), folder / path, schema_dir, clean)
