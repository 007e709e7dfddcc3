"""Validation: the official samples in shared/data/citymodels, and one broken cube per rule."""

import copy
import json

import geopandas as gpd
import pytest
import shapely
from lxml import etree

from gnss_citygml.errors import InputError
from gnss_citygml.export import write_citygml
from gnss_citygml.validate import SCHEMA_DIR_ENV, validate_file

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


@pytest.mark.parametrize(("name", "rules"), SAMPLES, ids=[s[0].split("/")[-1] for s in SAMPLES])
def test_official_samples(shared_data, name, rules):
    report = validate_file(
        shared_data / "citymodels" / name, schema_dir=shared_data / "schemas" / "cityjson"
    )
    assert {issue.rule for issue in report.errors} == rules
    assert report.exit_code == (1 if rules else 0)
    if report.format.endswith(("1.1", "2.0")) and report.format.startswith("CityJSON"):
        assert "json-schema" in report.checks  # 1.1 files against 1.1.3, 2.0 against 2.0.1


def test_sample_details(shared_data):
    folder = shared_data / "citymodels"
    typo = validate_file(folder / "cityjson/invalid/cjval_cube_20_typo_GnericCityObject.city.jsonl")
    assert [(e.object_id, e.rule, e.message) for e in typo.errors] == [
        ("id-1", "cityobject-type", "line 2: unknown CityObject type 'GnericCityObject'"),
        (None, "cityjson-type", "line 5: type is 'CityJSONFeatur', not 'CityJSONFeature'"),
    ]
    assert typo.format == "CityJSONSeq 2.0" and typo.n_objects == 5
    assert any("JSON Schema check left out" in note for note in typo.notes)
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


def test_schema_folder_from_the_environment(monkeypatch, shared_data):
    cube = shared_data / "citymodels/cityjson/cjval_cube.city.json"
    assert "json-schema" not in validate_file(cube).checks
    monkeypatch.setenv(SCHEMA_DIR_ENV, str(shared_data / "schemas"))
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
    return {issue.rule for issue in validate_file(path).errors}


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
    assert broken(lambda d: d.update(version="3.0")) == {"version"}
    assert broken(lambda d: d["vertices"].__setitem__(0, [0.5, 0, 0])) == {"vertices"}
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
    report = validate_file(path)
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
