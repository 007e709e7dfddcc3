"""CityGML 2.0 LOD1 export: round trips checked by our validator and, independently, by libxml2
through the OASIS catalog of the shared schemas (a separate process), by the ``citysmith``
command line, and by volumes and envelopes computed here from the file."""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import shapely
from lxml import etree
from test_cityjson import FOOTPRINTS, GROUND, NOT_CONVERGED, ROOF, heights_table

from gnss_citygml.errors import InputError
from gnss_citygml.export import gml_ids, write_citygml
from gnss_citygml.export.output import InvalidOutputError, validated_output
from gnss_citygml.validate import validate_file

NS = {
    "core": "http://www.opengis.net/citygml/2.0",
    "bldg": "http://www.opengis.net/citygml/building/2.0",
    "gen": "http://www.opengis.net/citygml/generics/2.0",
    "gml": "http://www.opengis.net/gml",
}
#: Validates argv[1] against the shared CityGML 2.0 base profile through the OASIS catalog.
CATALOG_CHECK = """
import sys
from lxml import etree
parser = etree.XMLParser(no_network=True, resolve_entities=False)
schema = etree.XMLSchema(etree.parse(sys.argv[2], parser))
ok = schema.validate(etree.parse(sys.argv[1], parser))
print("valid" if ok else schema.error_log)
"""


def catalog_check(path: Path, shared_data: Path) -> str:
    schemas = shared_data / "schemas"
    env = {**os.environ, "XML_CATALOG_FILES": str(schemas / "catalog.xml")}
    xsd = schemas / "schemas.opengis.net/citygml/profiles/base/2.0/CityGML.xsd"
    out = subprocess.run(
        [sys.executable, "-c", CATALOG_CHECK, str(path), str(xsd)],
        env=env,
        capture_output=True,
        text=True,
        check=True,
    )
    return out.stdout.strip()


def citysmith_check(path: Path) -> str:
    command = Path(sys.executable).parent / "citysmith"
    out = subprocess.run(
        [str(command), "validate", "--schema-only", str(path)], capture_output=True, text=True
    )
    return out.stdout


def volume(solid) -> float:
    """Signed volume (m³) of a gml:Solid from its posLists, by the divergence theorem."""
    total, origin = 0.0, None
    for pos_list in solid.iter(f"{{{NS['gml']}}}posList"):
        p = np.array(pos_list.text.split(), dtype=float).reshape(-1, 3)
        assert (p[0] == p[-1]).all()  # closed rings
        origin = p[0] if origin is None else origin
        p = p[:-1] - origin
        total += np.einsum("ij,ij->", p[1:-1], np.cross(p[2:], p[0])) / 6
    return total


@pytest.fixture(scope="module")
def model(tmp_path_factory):
    path = tmp_path_factory.mktemp("gml") / "b.gml"
    result = write_citygml(heights_table([NOT_CONVERGED]), path, date="2024-05-01")
    return path, result, etree.parse(str(path))


def test_written_file_is_valid_for_three_validators(model, shared_data):
    path, result, _ = model
    assert result.written == 5 and result.skipped["id"].tolist() == ["unsure"]
    assert result.report.valid and result.report.checks == ["xml", "xsd", "geometry"]
    assert catalog_check(path, shared_data) == "valid"
    assert "schema              : valid (CityGML 2.0)" in citysmith_check(path)
    assert validate_file(path, schema_dir=shared_data / "schemas").valid  # the shared copies


def test_envelope_and_ids(model):
    _, _, tree = model
    envelope = tree.find("gml:boundedBy/gml:Envelope", NS)
    assert (envelope.get("srsName"), envelope.get("srsDimension")) == ("EPSG:7405", "3")
    assert envelope.findtext("gml:lowerCorner", namespaces=NS) == "529500.000 182300.000 21.250"
    assert envelope.findtext("gml:upperCorner", namespaces=NS) == "529550.000 182329.000 33.750"
    buildings = tree.findall("core:cityObjectMember/bldg:Building", NS)
    ids = [b.get(f"{{{NS['gml']}}}id") for b in buildings]
    assert ids == ["osgb1000005116342", "courtyard", "concave-U", "two-parts", "id_12_B"]
    original = buildings[4].find("gen:stringAttribute[@name='id']/gen:value", NS)
    assert original.text == "12/B"
    assert buildings[0].find("gen:stringAttribute[@name='id']", NS) is None  # a TOID is kept


def test_building_content_in_schema_order(model):
    _, _, tree = model
    building = tree.find("core:cityObjectMember/bldg:Building", NS)
    tags = [etree.QName(child).localname for child in building]
    assert tags[0] == "creationDate" and tags[-2:] == ["measuredHeight", "lod1Solid"]
    assert building.findtext("core:creationDate", namespaces=NS) == "2024-05-01"
    height = building.find("bldg:measuredHeight", NS)
    assert (height.text, height.get("uom")) == ("12.5", "m")
    attributes = {
        a.get("name"): (etree.QName(a).localname, a.findtext("gen:value", namespaces=NS))
        for a in building.findall("gen:*", NS)
    }
    assert attributes == {
        "ground": ("doubleAttribute", "21.25"),
        "height": ("doubleAttribute", "33.75"),
        "height_lower": ("doubleAttribute", "32.25"),
        "height_upper": ("doubleAttribute", "35.75"),
        "n_signals": ("intAttribute", "250"),
        "converged": ("stringAttribute", "true"),
        "method": ("stringAttribute", "4PL-B"),
        "status": ("stringAttribute", "ok"),
    }


def test_solids_are_closed_outward_prisms(model):
    _, _, tree = model
    volumes = {}
    for building in tree.findall("core:cityObjectMember/bldg:Building", NS):
        for owner in [building, *building.findall(".//bldg:BuildingPart", NS)]:
            solid = owner.find("bldg:lod1Solid/gml:Solid", NS)
            if solid is not None:
                volumes[owner.get(f"{{{NS['gml']}}}id")] = volume(solid)
    expected = {gml_ids([k])[0][0]: area * (ROOF - GROUND) for k, (_, area) in FOOTPRINTS.items()}
    expected.update({"two-parts-1": 25 * 12.5, "two-parts-2": 4 * 12.5})
    del expected["two-parts"]
    assert volumes == pytest.approx(expected, abs=1e-6)
    courtyard = tree.find(".//bldg:Building[@gml:id='courtyard']//gml:Solid", NS)
    assert len(courtyard.findall(".//gml:interior", NS)) == 2  # the hole, bottom and top


def test_gml_ids_are_ncnames():
    assert gml_ids(["osgb1000005116342", "12/B", "a b", "_x", "é", "x.y-z"]) == (
        ["osgb1000005116342", "id_12_B", "a_b", "_x", "_", "x.y-z"],
        [False, True, True, False, True, False],
    )


def test_clashing_gml_ids_are_refused(tmp_path):
    frame = heights_table()
    frame.loc[0, "id"] = "a b"
    frame.loc[1, "id"] = "a_b"
    with pytest.raises(InputError, match="'a b', 'a_b' all get the gml:id 'a_b'"):
        write_citygml(frame, tmp_path / "c.gml")
    assert list(tmp_path.iterdir()) == []


def test_an_invalid_output_raises(tmp_path, shared_data):
    bad = tmp_path / "bad.gml"
    bad.write_bytes(
        (shared_data / "citymodels/citygml2/invalid/val3dity_geometry_302_2.gml").read_bytes()
    )
    with pytest.raises(InvalidOutputError, match="shell-not-closed"):
        validated_output(bad, tmp_path / "out.gml", True, None)


def test_escaped_text_and_no_validation(tmp_path):
    frame = heights_table().assign(note=['<a & "b">', "ok\x01", None, "x", "y"])
    with pytest.warns(UserWarning, match="XML cannot hold.*'courtyard'"):
        result = write_citygml(frame, tmp_path / "e.gml", validate=False)
    assert result.report is None
    tree = etree.parse(str(tmp_path / "e.gml"))
    notes = [e.text for e in tree.iterfind(".//gen:stringAttribute[@name='note']/gen:value", NS)]
    assert notes == ['<a & "b">', "ok\ufffd", "x", "y"]
    assert validate_file(tmp_path / "e.gml").valid


def test_real_mastermap_footprints(tmp_path, shared_data):
    from gnss_citygml.export import buildings_with_heights
    from gnss_citygml.footprints import read_footprints

    footprints = read_footprints(shared_data / "footprints" / "mastermap-topo_3473984_0.gml")
    footprints["ground"] = 25.0
    footprints["abshmax"] = 25.0 + np.linspace(6.0, 40.0, len(footprints))
    path = tmp_path / "m.gml"
    result = write_citygml(buildings_with_heights(footprints, "abshmax"), path)
    assert (result.written, result.report.valid) == (160, True)
    assert catalog_check(path, shared_data) == "valid"
    tree = etree.parse(str(path))
    solids = tree.findall(".//gml:Solid", NS)
    areas = shapely.area(footprints.geometry.to_numpy())
    heights = np.rint(footprints["abshmax"].to_numpy() * 1000) / 1000 - 25.0  # mm vertices
    assert np.array([volume(s) for s in solids]) == pytest.approx(areas * heights, rel=1e-9)
