"""Validation: the official samples (cjio's and cjval's in tests/data, the others in the shared
data), and one broken cube per rule."""

import copy
import gzip
import json
import shutil
import time
from pathlib import Path

import geopandas as gpd
import pytest
import shapely
from lxml import etree

from gnss_citygml.cli import main
from gnss_citygml.errors import InputError
from gnss_citygml.export import write_citygml, write_cityjson, write_cityjsonseq
from gnss_citygml.validate import SCHEMA_DIR_ENV, validate_file
from gnss_citygml.validate.schemas import (
    BUNDLED_CITYJSON_SCHEMAS,
    cityjson_schema_file,
    packed_schemas,
)

#: (sample, the rules of its errors): an empty set is a valid sample.
SAMPLES = [
    ("citygml2/ogc_examples/Building_LOD0-EPSG25832.gml", set()),
    ("citygml2/ogc_examples/Building_LOD1-EPSG25832.gml", set()),
    ("citygml2/ogc_examples/Building_LOD1-LocalEngineeringCRS.gml", set()),
    ("citygml2/ogc_examples/Building_LOD2-EPSG25832.gml", set()),  # xlinked surfaces
    ("citygml2/val3dity_csol1_valid.gml", set()),  # CompositeSolid of two touching cubes
    ("citygml2/invalid/val3dity_invalid_citygml_1.gml", {"xsd"}),
    ("citygml2/invalid/val3dity_invalid_citygml_2.gml", {"xml-syntax"}),
    ("citygml2/invalid/val3dity_geometry_103.gml", {"ring-not-closed"}),
    ("citygml2/invalid/val3dity_geometry_302_2.gml", {"shell-not-closed"}),
    ("citygml2/invalid/val3dity_geometry_502.gml", {"composite-overlap"}),
    ("cityjson/cjio_rotterdam_subset.city.json", set()),
    ("cityjson/cjio_multi_lod.city.json", set()),
    ("cityjson/cjio_DH_01_subs.city.json", set()),
    ("cityjson/cjio_minimal.city.json", set()),
    ("cityjson/cjval_cube.city.json", set()),
    ("cityjson/cjval_cjfeat1.city.json", set()),
    (
        "cityjson/invalid/cjval_cube_20_typo_GnericCityObject.city.jsonl",
        {"cityobject-type", "cityjson-type", "json-schema"},
    ),
    ("cityjson/invalid/cjval_material_overflow.city.json", {"appearance"}),
    ("cityjson/invalid/cjval_texture6_float_indices.city.json", {"appearance", "json-schema"}),
    ("cityjson/invalid/val3dity_invalid_json_cityjson.json", {"json-syntax"}),
    ("cityjson/invalid/val3dity_invalid_schema_cityjson_1.json", {"json-syntax"}),
    ("cityjson/invalid/val3dity_invalid_schema_cityjson_2.json", {"vertex-index"}),
    # Schema-valid, but geometrically broken: the LoD1 solid has no floor (77 open edges at
    # z = -0.1 m) and a 3DBAG ring lists vertex 18 twice in a row.
    ("cityjson/cjio_delft_1b.city.json", {"shell-not-closed"}),
    ("cityjson/val3dity_3dbag_b2.city.jsonl", {"ring-duplicate-vertex"}),
]


def _sample(name, rules):
    """A sample as parameters, marked ``shared_data`` unless tests/data has it: cjio's and
    cjval's (MIT) are there; val3dity's (GPL) and OGC's are only in the shared folder."""
    in_repo = Path(name).name.startswith(("cjio_", "cjval_"))
    return pytest.param(
        name, rules, id=Path(name).name, marks=() if in_repo else pytest.mark.shared_data
    )


@pytest.mark.parametrize(("name", "rules"), [_sample(*sample) for sample in SAMPLES])
def test_official_samples(reference_data, name, rules):
    report = validate_file(
        reference_data / "citymodels" / name, schema_dir=reference_data / "schemas" / "cityjson"
    )
    assert {issue.rule for issue in report.errors} == rules
    assert report.exit_code == (1 if rules else 0)
    if report.format.endswith(("1.1", "2.0")) and report.format.startswith("CityJSON"):
        assert "json-schema" in report.checks  # 1.1 files against 1.1.3, 2.0 against 2.0.1


def test_sample_details(shared_data):
    folder = shared_data / "citymodels"
    name = "cityjson/invalid/cjval_cube_20_typo_GnericCityObject.city.jsonl"
    typo = validate_file(folder / name, bundled_schemas=False)  # (the structure's rules)
    assert [(e.object_id, e.rule, e.message) for e in typo.errors] == [
        ("id-1", "cityobject-type", "line 2: unknown CityObject type 'GnericCityObject'"),
        (None, "cityjson-type", "line 5: type is 'CityJSONFeatur', not 'CityJSONFeature'"),
    ]
    assert typo.format == "CityJSONSeq 2.0" and typo.n_objects == 5
    assert any("JSON Schema check left out" in note for note in typo.notes)
    schema = validate_file(folder / name)  # and the schemas bundled with the package too
    assert [e.message for e in schema.errors if e.rule == "json-schema"] == [
        "line 2: (root): a 'GnericCityObject' matches none of the schemas allowed here",
        "line 5: type: 'CityJSONFeature' was expected",
    ]
    assert "JSON Schema: CityJSON 2.0.2's, bundled with gnss-citygml" in schema.notes
    overlap = validate_file(folder / "citygml2/invalid/val3dity_geometry_502.gml")
    assert overlap.errors[0].object_id == "GenericCityObject (line 6)"
    xsd = validate_file(folder / "citygml2/invalid/val3dity_invalid_citygml_1.gml")
    assert xsd.errors[0].object_id == "myid" and xsd.errors[0].message.startswith("line 15: ")
    index = validate_file(folder / "cityjson/invalid/val3dity_invalid_schema_cityjson_2.json")
    assert index.errors[0].message == "Solid (lod 1): vertex index 22 out of range (4 vertices)"


def test_cannot_validate(tmp_path, shared_data):
    with pytest.raises(InputError, match="CityGML 3.0 is not supported"):
        validate_file(shared_data / "citymodels/citygml3/ogc_Building_LOD1-EPSG25832_CityGML3.gml")
    with pytest.raises(InputError, match="file not found"):
        validate_file(tmp_path / "missing.gml")
    (tmp_path / "x.png").write_bytes(b"\x89PNG\r\n")
    with pytest.raises(InputError, match="not a CityGML"):
        validate_file(tmp_path / "x.png")
    (tmp_path / "other.xml").write_text("<svg xmlns='http://www.w3.org/2000/svg'/>")
    with pytest.raises(InputError, match="not a CityGML 2.0 city model"):
        validate_file(tmp_path / "other.xml")
    with pytest.raises(InputError, match="schema folder not found"):
        validate_file(tmp_path / "other.xml", schema_dir=tmp_path / "nowhere")
    with pytest.raises(InputError, match="cannot compile the CityGML 2.0 schemas"):
        (tmp_path / "broken/schemas.opengis.net/citygml/2.0").mkdir(parents=True)
        validate_file(
            shared_data / "citymodels/citygml2/val3dity_csol1_valid.gml",
            schema_dir=tmp_path / "broken",
        )


def test_the_bundled_cityjson_schemas_are_the_official_ones(shared_data):
    """The pack holds CityJSON 2.0.2's two inlined schemas, byte for byte, and nothing else."""
    official = shared_data / "schemas" / "cityjson" / "2.0.2"
    shipped = packed_schemas(BUNDLED_CITYJSON_SCHEMAS)
    assert sorted(shipped) == ["cityjson.min.schema.json", "cityjsonfeature.min.schema.json"]
    for name, text in shipped.items():
        assert text == (official / name).read_bytes(), name
    assert cityjson_schema_file(BUNDLED_CITYJSON_SCHEMAS, "2.0", "cityjson") is not None
    assert cityjson_schema_file(BUNDLED_CITYJSON_SCHEMAS, "1.1", "cityjson") is None


def test_schema_folder_from_the_environment(monkeypatch, repo_data):
    cube = repo_data / "citymodels/cityjson/cjval_cube.city.json"
    assert "json-schema" not in validate_file(cube, bundled_schemas=False).checks
    assert "json-schema" in validate_file(cube).checks  # the bundled CityJSON 2.0.2 schema
    monkeypatch.setenv(SCHEMA_DIR_ENV, str(repo_data / "schemas"))
    assert "json-schema" in validate_file(cube).checks


# --- one rule at a time, on a unit cube -----------------------------------------------------

#: A unit cube in decimetres (transform scale 0.1), and its faces, oriented outwards.
VERTICES = [[0, 0, 0], [10, 0, 0], [10, 10, 0], [0, 10, 0]]
VERTICES += [[x, y, 10] for x, y, _ in VERTICES]
FACES = [[0, 3, 2, 1], [4, 5, 6, 7], [0, 1, 5, 4], [1, 2, 6, 5], [2, 3, 7, 6], [3, 0, 4, 7]]
MOVED = [[x + 50, y, z] for x, y, z in VERTICES]  # a second cube, apart from the first
OUTSIDE = [[20, 0, 10], [30, 0, 10], [30, 10, 10]]  # a triangle beside the top face


def cube(faces=FACES, vertices=VERTICES, **geometry):
    """The cube as a CityJSON document; a face is a ring, or a list of rings."""
    boundaries = [[face if isinstance(face[0], list) else [face] for face in faces]]
    return {
        "type": "CityJSON",
        "version": "2.0",
        "transform": {"scale": [0.1, 0.1, 0.1], "translate": [529500.0, 182300.0, 20.0]},
        "CityObjects": {
            "c": {
                "type": "Building",
                "geometry": [{"type": "Solid", "lod": "1", "boundaries": boundaries, **geometry}],
            }
        },
        "vertices": copy.deepcopy(vertices),
    }


def rules_of(tmp_path, document) -> set:
    path = tmp_path / "c.city.json"
    path.write_text(json.dumps(document))
    return {issue.rule for issue in validate_file(path, bundled_schemas=False).errors}


def test_a_valid_cube(tmp_path):
    assert rules_of(tmp_path, cube()) == set()


@pytest.mark.parametrize(
    ("faces", "vertices", "rule"),
    [
        (FACES[:5], VERTICES, "shell-not-closed"),  # a face missing
        ([FACES[0][::-1], *FACES[1:]], VERTICES, "shell-orientation"),  # one face flipped
        ([f[::-1] for f in FACES], VERTICES, "solid-inward"),  # all faces inward
        (FACES, [*VERTICES[:6], [10, 10, 12], VERTICES[7]], "polygon-non-planar"),  # 2 dm off
        ([[0, 3, 2, 1], [4, 6, 5, 7], *FACES[2:]], VERTICES, "polygon-degenerate"),  # bowtie
        (  # the top face's hole lies outside it
            [FACES[0], [[4, 5, 6, 7], [8, 10, 9]], *FACES[2:]],
            VERTICES + OUTSIDE,
            "polygon-not-simple",
        ),
        ([[0, 3, 2, 1, 1], *FACES[1:]], VERTICES, "ring-duplicate-vertex"),
        ([[0, 3], *FACES[1:]], VERTICES, "ring-too-few-points"),
        (
            FACES + [[f + 8 for f in face] for face in FACES],
            VERTICES + MOVED,
            "shell-not-connected",
        ),
        (FACES + [[1, 2, 6, 5]], VERTICES, "shell-non-manifold"),  # a wall twice
        ([[0, 3, 2, 8], *FACES[1:]], VERTICES, "vertex-index"),
    ],
)
def test_one_broken_rule(tmp_path, faces, vertices, rule):
    assert rule in rules_of(tmp_path, cube(faces, vertices))


def test_shells_fuzzing_broke(tmp_path):
    """Found by `make fuzz`: a face without a ring, and a shell of one two-point face, are
    errors of the file, not crashes of the validator."""
    document = cube()
    document["CityObjects"]["c"]["geometry"][0]["boundaries"][0][5] = []
    assert {"face-empty", "shell-not-closed"} <= rules_of(tmp_path, document)
    assert "ring-too-few-points" in rules_of(tmp_path, cube([[5, 1]]))


def test_structural_rules(tmp_path):
    def broken(change):
        document = cube()
        change(document)
        return rules_of(tmp_path, document)

    assert broken(lambda d: d["CityObjects"]["c"]["geometry"][0].update(lod=1)) == {"lod"}
    assert broken(lambda d: d["CityObjects"]["c"]["geometry"][0].update(type="Sold")) == {
        "geometry-type"
    }
    assert broken(lambda d: d["CityObjects"]["c"].update(type="BuildingPart")) == {"parent-child"}
    assert broken(lambda d: d["CityObjects"]["c"].update(children=["gone"])) == {"parent-child"}
    assert broken(lambda d: d["CityObjects"]["c"].update(attributes={"+roof": 1})) == {"extension"}
    assert broken(lambda d: d.pop("transform")) == {"transform"}
    assert broken(lambda d: d["transform"]["translate"].__setitem__(1, 10**400)) == {"transform"}
    assert broken(lambda d: d.update(version="3.0")) == {"version"}
    assert broken(lambda d: d["vertices"].__setitem__(0, [0.5, 0, 0])) == {"vertices"}
    # JSON of the wrong type where the rules look: an error, never a crash (found by fuzzing)
    assert broken(lambda d: d["CityObjects"]["c"].update(type={"a": 1})) == {"cityobject-type"}
    assert broken(lambda d: d["CityObjects"]["c"].update(parents=[{}])) == {"parent-child"}
    assert broken(lambda d: d["CityObjects"]["c"].update(geometry={})) == {"geometry-type"}
    assert broken(lambda d: d["CityObjects"]["c"]["geometry"][0].update(material={"m": 3})) == {
        "appearance"
    }
    assert rules_of(tmp_path, cube()) == set()  # the changes touched copies
    semantics = {"surfaces": [{"type": "RoofSurface"}], "values": [[0, 0, 0, 0, 0, 1]]}
    assert broken(lambda d: d["CityObjects"]["c"]["geometry"][0].update(semantics=semantics)) == {
        "semantics"
    }


def test_cityjsonseq_rules(tmp_path):
    header = {k: v for k, v in cube().items() if k != "CityObjects"}
    header.update(CityObjects={}, vertices=[])
    feature = {
        "type": "CityJSONFeature",
        "id": "c",
        **{k: cube()[k] for k in ("CityObjects", "vertices")},
    }
    other = copy.deepcopy(feature)
    other["id"] = "d"
    lines = [header, feature, other]
    path = tmp_path / "s.city.jsonl"
    path.write_text("\n".join(json.dumps(line) for line in lines) + "\n")
    report = validate_file(path, bundled_schemas=False)
    assert [(e.object_id, e.rule) for e in report.errors] == [("d", "feature-id")]
    assert report.errors[0].message.startswith("line 3: ")
    assert report.summary().endswith("INVALID, 1 error(s) (checks: json, structure, geometry)")
    assert report.rule_counts() == {"feature-id": 1}


@pytest.mark.parametrize(("orientation", "rules"), [("-", set()), ("+", {"shell-orientation"})])
def test_orientable_surface(tmp_path, orientation, rules):
    """A wall written reversed inside a gml:OrientableSurface: valid only when flagged '-'."""
    box = gpd.GeoDataFrame(
        {"id": ["b"], "ground": [10.0], "height": [20.0]},
        geometry=[shapely.box(529500, 182300, 529510, 182308)],
        crs="EPSG:27700",
    )
    write_citygml(box, tmp_path / "b.gml")
    tree = etree.parse(str(tmp_path / "b.gml"))
    gml = "http://www.opengis.net/gml"
    member = tree.find(f".//{{{gml}}}surfaceMember")
    polygon = member[0]
    pos_list = polygon.find(f".//{{{gml}}}posList")
    points = pos_list.text.split()
    pos_list.text = " ".join(
        sum(([*points[i : i + 3]] for i in range(len(points) - 3, -1, -3)), [])
    )
    orientable = etree.SubElement(member, f"{{{gml}}}OrientableSurface", orientation=orientation)
    etree.SubElement(orientable, f"{{{gml}}}baseSurface").append(polygon)
    tree.write(str(tmp_path / "o.gml"))
    report = validate_file(tmp_path / "o.gml")
    assert {e.rule for e in report.errors} == rules


# --- bad input, from the user's side: `gnss-citygml validate FILE` --------------------------


def run(args, capsys):
    """``gnss-citygml ARGS``: the exit code, stdout and stderr."""
    with pytest.raises(SystemExit) as exc:
        main(args)
    out = capsys.readouterr()
    return exc.value.code, out.out, out.err


@pytest.fixture(scope="module")
def three(tmp_path_factory):
    """Buildings a, b and c written by the project's writers: {suffix: path}."""
    folder = tmp_path_factory.mktemp("three")
    frame = gpd.GeoDataFrame(
        {"id": ["a", "b", "c"], "ground": [20.0, 21.0, 22.0], "height": [32.5, 30.0, 31.0]},
        geometry=[shapely.box(529500 + 20 * k, 182300, 529510 + 20 * k, 182308) for k in range(3)],
        crs="EPSG:27700",
    )
    paths = {}
    for suffix, writer in (
        (".gml", write_citygml),
        (".city.json", write_cityjson),
        (".city.jsonl", write_cityjsonseq),
    ):
        paths[suffix] = folder / f"three{suffix}"
        writer(frame, paths[suffix], date="2024-05-01")
    return paths


def changed(three, suffix, tmp_path, change):
    """A copy of the three buildings in ``suffix``, its bytes changed by ``change``."""
    path = tmp_path / f"changed{suffix}"
    path.write_bytes(change(three[suffix].read_bytes()))
    return path


@pytest.mark.parametrize(
    ("cut", "expected"),
    [
        (lambda d: d[:1000], "line 2, column 962: not well-formed XML: expected '>'"),
        (
            lambda d: d[: d.index(b"<gml:posList", d.index(b'gml:id="b"')) + 40],
            "not well-formed XML: Premature end of data in tag posList",
        ),
        (
            lambda d: d[: d.rindex(b"</core:CityModel>")],
            "not well-formed XML: Premature end of data in tag CityModel",
        ),
        (lambda d: d + b"<!-- a comment cut sh", "not well-formed XML: Comment not terminated"),
        (
            lambda d: d.replace(b">529520.000", b">\x8029520.000", 1),
            "not well-formed XML: Invalid bytes in character encoding",
        ),
    ],
    ids=[
        "1000 bytes",
        "in building b",
        "after the last building",
        "in a trailing comment",
        "\\x80",
    ],
)
def test_a_cut_or_broken_citygml_is_invalid(three, tmp_path, capsys, cut, expected):
    """libxml2, validating while it parses, does not report an early end: it passed as valid."""
    path = changed(three, ".gml", tmp_path, cut)
    code, out, err = run(["validate", str(path)], capsys)
    assert code == 1 and err == ""
    error, summary = out.splitlines()
    assert error.startswith("-\txml-syntax\tline 2, column ") and expected in error
    assert summary.endswith(
        ": CityGML 2.0, 0 object(s): INVALID, 1 error(s) (checks: xml, xsd, geometry)"
    )


@pytest.mark.parametrize(
    ("suffix", "cut", "expected"),
    [
        (".city.json", lambda d: d[: len(d) // 2], "-\tjson-syntax\tline 1, column "),
        (".city.jsonl", lambda d: d[:-100], "-\tjson-syntax\tline 4, column "),  # the last line
    ],
)
def test_a_cut_cityjson_is_invalid(three, tmp_path, capsys, suffix, cut, expected):
    path = changed(three, suffix, tmp_path, cut)
    code, out, _ = run(["validate", str(path)], capsys)
    assert code == 1
    error, summary = out.splitlines()
    assert error.startswith(expected) and ": not valid JSON: " in error
    assert "INVALID, 1 error(s)" in summary


@pytest.mark.parametrize(
    ("change", "rule", "message"),
    [
        (  # deeper than Python's JSON reader goes
            lambda d: d.replace(b'"ground":', b'"deep":' + b"[" * 5000 + b"]" * 5000 + b',"g":', 1),
            "json-nesting",
            "arrays and objects nested deeper than 128 levels",
        ),
        (
            lambda d: d.replace(b'"scale":[0.001,0.001,0.001]', b'"scale":[1e308,1e308,1e308]'),
            "coordinate-range",
            "coordinate value(s) non-finite or beyond ±1e+12 (the first: inf, after the transform)",
        ),
        (
            lambda d: d.replace(b'"scale":[0.001,0.001,0.001]', b'"scale":[NaN,0.001,0.001]'),
            "json-syntax",
            "not valid JSON: NaN is not a JSON number",
        ),
        (lambda d: d.replace(b'"b"', b'"\xff"', 1), "json-syntax", "not UTF-8 text"),
    ],
    ids=["nested 5000 deep", "scale 1e308", "NaN", "not UTF-8"],
)
def test_unreadable_cityjson_is_invalid_not_a_crash(three, tmp_path, capsys, change, rule, message):
    """A crash would read as a verdict (exit 1): these are reports naming the problem."""
    path = changed(three, ".city.json", tmp_path, change)
    code, out, err = run(["validate", str(path)], capsys)
    assert code == 1
    assert all(line.startswith("note: ") for line in err.splitlines())  # no warning, no traceback
    error, summary = out.splitlines()
    assert error.startswith(f"-\t{rule}\t") and message in error
    assert "INVALID, 1 error(s)" in summary


def test_non_finite_gml_coordinates(three, tmp_path, capsys):
    """xs:double allows NaN and INF: the schema passes them, the geometry check names them."""
    path = changed(
        three,
        ".gml",
        tmp_path,
        lambda d: d.replace(b"529520.000 182300.000 21.000", b"NaN INF 21", 1),
    )
    code, out, err = run(["validate", str(path)], capsys)
    assert code == 1 and err == ""
    error, summary = out.splitlines()
    assert error.startswith("b\tcoordinate-range\tlod1Solid Solid (line 2): ")
    assert "2 coordinate value(s) non-finite or beyond ±1e+12 (the first: nan)" in error


def test_a_schema_error_names_its_building(three, tmp_path, capsys):
    """The writer puts its GML on one line: the building is found by element, not by line."""

    def inject(data):  # an element the schema does not allow, in building b (the 2nd of 3)
        k = data.index(b"<bldg:measuredHeight", data.index(b'gml:id="b"'))
        return data[:k] + b"<bldg:bogus/>" + data[k:]

    code, out, _ = run(["validate", str(changed(three, ".gml", tmp_path, inject))], capsys)
    assert code == 1
    error, summary = out.splitlines()
    assert error.startswith(
        "b\txsd\tline 2: Element '{http://www.opengis.net/citygml/building/2.0}bogus'"
    )
    assert summary.endswith("3 object(s): INVALID, 1 error(s) (checks: xml, xsd, geometry)")


#: Nine levels of ten: a billion "lol"s, used in an attribute (always expanded by XML parsers)
#: and in the text of the first building.
BILLION_LAUGHS = (
    b'<!DOCTYPE core:CityModel [<!ENTITY lol0 "lol">'
    + b"".join(b'<!ENTITY lol%d "%s">' % (k, b"&lol%d;" % (k - 1) * 10) for k in range(1, 10))
    + b"]>\n"
)


@pytest.mark.parametrize(
    ("doctype", "entity"),
    [
        (BILLION_LAUGHS, b"&lol9;"),
        (b'<!DOCTYPE core:CityModel [<!ENTITY xxe SYSTEM "file:///etc/passwd">]>\n', b"&xxe;"),
        (b'<!DOCTYPE core:CityModel SYSTEM "http://example.invalid/city.dtd">\n', b"&xxe;"),
        (b"<!DOCTYPE core:CityModel>\n", b""),
    ],
    ids=["billion laughs", "external entity", "external DTD", "no DTD"],
)
def test_a_doctype_is_refused_once(three, tmp_path, capsys, doctype, entity):
    """One line, nothing else, at once: the parser stops at the <!DOCTYPE>, before its DTD."""

    def add(data):
        declaration, rest = data.split(b"\n", 1)
        rest = rest.replace(b'name="ground"', b'name="ground' + entity + b'"', 1)
        return declaration + b"\n" + doctype + rest.replace(b"2024-05-01", entity, 1)

    path = changed(three, ".gml", tmp_path, add)
    start = time.perf_counter()
    code, out, err = run(["validate", str(path)], capsys)
    assert time.perf_counter() - start < 2  # expanded up to libxml2's limit: 7 s, 230 MB
    assert code == 2 and out == ""
    assert err == (
        "error: XML entities and DTDs refused: the file has a <!DOCTYPE> declaration "
        f"({path}): remove it (CityGML uses none; entities are never expanded nor DTDs loaded "
        "here)\n"
    )


def test_an_undeclared_entity_is_one_syntax_error(three, tmp_path, capsys):
    """Once, and without the schema compiler's warnings that libxml2 kept in its log."""
    path = changed(three, ".gml", tmp_path, lambda d: d.replace(b"2024-05-01", b"&x;", 1))
    code, out, _ = run(["validate", str(path)], capsys)
    assert code == 1
    error, _ = out.splitlines()
    assert error.startswith("-\txml-syntax\tline 2, column ")
    assert error.endswith(": not well-formed XML: Entity 'x' not defined")


def test_every_error_is_one_line(three, tmp_path, capsys):
    """Ids and quoted values can hold control characters: they are escaped."""

    def rename(data):
        data = data.replace(b'"b":{"type":"Building"', b'"b\\n\\t\\u0001":{"type":"Nope"')
        return data.replace(b'"c":{"type":"Building"', b'"c":{"type":"Nope"')

    path = changed(three, ".city.json", tmp_path, rename)
    code, out, _ = run(["validate", str(path)], capsys)
    assert code == 1
    lines = out.splitlines()
    assert lines == [
        "b\\n\\t\\x01\tcityobject-type\tunknown CityObject type 'Nope'",
        "c\tcityobject-type\tunknown CityObject type 'Nope'",
        "b\\n\\t\\x01\tjson-schema\t(root): a 'Nope' matches none of the schemas allowed here",
        "c\tjson-schema\t(root): a 'Nope' matches none of the schemas allowed here",
        f"{path}: CityJSON 2.0, 3 object(s): INVALID, 4 error(s) "
        "(checks: json, structure, json-schema, geometry)",
    ]
    code, out, _ = run(["validate", str(path), "--max-errors", "1"], capsys)
    assert code == 1
    more = "... 3 more (cityobject-type 2, json-schema 2)"
    assert out.splitlines() == [lines[0], more, lines[4]]
    code, _, err = run(["validate", str(path), "--max-errors", "-1"], capsys)
    assert code == 2 and "Invalid value for '--max-errors'" in err


@pytest.mark.parametrize(
    "pack",
    [
        b"not gzip",
        gzip.compress(b'{"tileset.schema.json": '),  # not JSON
        gzip.compress(b'["tileset.schema.json"]'),  # not an object of texts
        gzip.compress(b'{"cityjson.min.schema.json": {"type": "object"}}'),  # not texts
        gzip.compress(b'{"tileset.schema.json": "{}"}')[:-9],  # cut short
    ],
)
@pytest.mark.parametrize("kind", ["cityjson", "tileset"])
def test_a_schema_folder_with_an_unusable_pack_is_one_line(tmp_path, capsys, pack, kind):
    """A schemas.json.gz (the form the package ships its schemas in) in the folder given by
    --schema-dir that is not a gzip of schema texts is one line naming it, not an internal
    error (found at the command line: BadGzipFile)."""
    from test_cli import run
    from test_outputs import heights_gpkg

    folder = tmp_path / "schemas"
    packed = folder / ("3dtiles-1.1" if kind == "tileset" else "") / "schemas.json.gz"
    packed.parent.mkdir(parents=True)
    packed.write_bytes(pack)
    model = tmp_path / ("t/tileset.json" if kind == "tileset" else "c.city.json")
    args = ["convert", str(heights_gpkg(tmp_path)), "-o", str(model), "--no-validate", "-q"]
    code, _, err = run(args, capsys)
    assert code == 0, err
    code, _, err = run(["validate", str(model), "--schema-dir", str(folder)], capsys)
    assert code == 2 and "the schema cannot be used" in err and "schemas.json.gz" in err, err
    assert "internal error" not in err


@pytest.mark.parametrize("text", ["[" * 100_000 + "]" * 100_000, '{"a": ', "[1, 2]"])
@pytest.mark.parametrize("kind", ["cityjson", "tileset"])
def test_a_schema_folder_of_unusable_schemas_is_one_line(tmp_path, capsys, text, kind):
    """A schema of the folder given by --schema-dir that is not JSON, nested too deep or not
    a schema (an array) is one line naming it, not an internal error (found at the command
    line: RecursionError, JSONDecodeError)."""
    from test_cli import run
    from test_outputs import heights_gpkg

    from gnss_citygml.validate.schemas import tiles3d_schema_folder

    folder = tmp_path / "schemas"
    if kind == "tileset":
        shutil.copytree(tiles3d_schema_folder(), folder / "3dtiles-1.1")
        broken = folder / "3dtiles-1.1" / "asset.schema.json"
        model = tmp_path / "t" / "tileset.json"
    else:
        broken = folder / "2.0" / "cityjson.min.schema.json"
        broken.parent.mkdir(parents=True)
        model = tmp_path / "c.city.json"
    broken.write_text(text)
    args = ["convert", str(heights_gpkg(tmp_path)), "-o", str(model), "--no-validate", "-q"]
    code, _, err = run(args, capsys)
    assert code == 0, err
    code, _, err = run(["validate", str(model), "--schema-dir", str(folder)], capsys)
    assert code == 2 and "the schema cannot be used" in err and broken.name in err, err
    assert "internal error" not in err
