"""CityJSON 2.0 and CityJSONSeq export: round trips checked by our validator and, independently,
by python-jsonschema with the official CityJSON 2.0.1 schemas, by cjio (CityJSON's own command
line, a separate process) and by volumes computed here."""

import json
import subprocess
import sys
from pathlib import Path

import geopandas as gpd
import jsonschema
import numpy as np
import pytest
import shapely
from rasterio.io import MemoryFile
from rasterio.transform import from_origin

from gnss_citygml.errors import InputError, MissingColumnError
from gnss_citygml.export import (
    buildings_with_heights,
    extrude,
    snap_footprints,
    write_cityjson,
    write_cityjsonseq,
)
from gnss_citygml.footprints import read_footprints
from gnss_citygml.terrain import building_ground
from gnss_citygml.validate import validate_file

E, N = 529500.0, 182300.0
#: The canonical footprints (EPSG:27700), with the area each one has.
FOOTPRINTS = {
    "osgb1000005116342": (shapely.box(E, N, E + 10, N + 8), 80.0),
    "courtyard": (
        shapely.Polygon(
            [(E + 20, N), (E + 32, N), (E + 32, N + 12), (E + 20, N + 12)],
            [[(E + 24, N + 4), (E + 24, N + 8), (E + 28, N + 8), (E + 28, N + 4)]],
        ),
        128.0,
    ),
    "concave-U": (
        shapely.Polygon(
            [(E, N + 20), (E + 9, N + 20), (E + 9, N + 29), (E + 6, N + 29), (E + 6, N + 23)]
            + [(E + 3, N + 23), (E + 3, N + 29), (E, N + 29)]
        ),
        63.0,
    ),
    "two-parts": (
        shapely.MultiPolygon(
            [
                shapely.box(E + 20, N + 20, E + 25, N + 25),
                shapely.box(E + 27, N + 20, E + 29, N + 22),
            ]
        ),
        29.0,
    ),
    # a collinear vertex (E+45) and a repeated vertex (E+50, N): both valid footprints
    "12/B": (
        shapely.Polygon(
            [(E + 40, N), (E + 45, N), (E + 50, N), (E + 50, N), (E + 50, N + 6), (E + 40, N + 6)]
        ),
        60.0,
    ),
}
GROUND = 21.25
ROOF = 33.75
SCHEMAS = "schemas/cityjson/2.0.1"


def heights_table(extra_rows=()):
    """The buildings table as ``estimate`` leaves it, plus not-converged rows."""
    rows = [
        {
            "id": key,
            "geometry": geom,
            "ground": GROUND,
            "height": ROOF,
            "height_lower": ROOF - 1.5,
            "height_upper": ROOF + 2.0,
            "n_signals": 250,
            "converged": True,
            "method": "4PL-B",
            "status": "ok",
        }
        for key, (geom, _) in FOOTPRINTS.items()
    ]
    rows += list(extra_rows)
    return gpd.GeoDataFrame(rows, geometry="geometry", crs="EPSG:27700")


NOT_CONVERGED = {
    "id": "unsure",
    "geometry": shapely.box(E + 60, N, E + 66, N + 6),
    "ground": GROUND,
    "height": np.nan,
    "height_lower": np.nan,
    "height_upper": np.nan,
    "n_signals": 4,
    "converged": False,
    "method": "4PL-B",
    "status": "fewer than 10 signals",
}


def official(data, kind="cityjson"):
    schema = json.loads((data / SCHEMAS / f"{kind}.min.schema.json").read_text())
    return jsonschema.Draft7Validator(schema)


def solid_volumes(objects, vertices, transform):
    """Signed volume (m³) of every Solid, by the divergence theorem, per CityObject id."""
    points = np.asarray(vertices, dtype=float) * transform["scale"] + transform["translate"]
    volumes = {}
    for key, obj in objects.items():
        for geometry in obj.get("geometry", []):
            total = 0.0
            for face in geometry["boundaries"][0]:
                for ring in face:
                    p = points[ring] - points[0]
                    total += np.einsum("ij,ij->", p[1:-1], np.cross(p[2:], p[0])) / 6
            volumes[key] = total
    return volumes


def test_cityjson_round_trip(tmp_path, repo_data):
    frame = heights_table([NOT_CONVERGED])
    out = write_cityjson(frame, tmp_path / "b.city.json", date="2024-05-01", title="Bloomsbury")
    assert out.written == 5
    assert out.skipped.values.tolist() == [
        ["unsure", "height estimate did not converge (fewer than 10 signals)"]
    ]
    assert out.report.valid and out.report.checks == ["json", "structure", "geometry"]
    model = json.loads((tmp_path / "b.city.json").read_text())
    assert list(official(repo_data).iter_errors(model)) == []
    assert validate_file(tmp_path / "b.city.json", schema_dir=repo_data / SCHEMAS).valid

    assert model["version"] == "2.0"
    assert model["metadata"]["referenceSystem"] == "https://www.opengis.net/def/crs/EPSG/0/7405"
    assert model["metadata"]["referenceDate"] == "2024-05-01"
    assert model["metadata"]["geographicalExtent"] == [E, N, GROUND, E + 50, N + 29, ROOF]
    assert model["transform"] == {
        "scale": [0.001, 0.001, 0.001],
        "translate": [E, N, 21.0],
    }
    vertices = np.array(model["vertices"])
    assert vertices.dtype == np.int64 and len(np.unique(vertices, axis=0)) == len(vertices)
    assert set(vertices[:, 2]) == {250, 12750}  # ground and roof in mm above 21 m
    assert "unsure" not in model["CityObjects"]

    building = model["CityObjects"]["osgb1000005116342"]
    assert building["attributes"] == {
        "measuredHeight": 12.5,
        "creationDate": "2024-05-01",
        "ground": GROUND,
        "height": ROOF,
        "height_lower": 32.25,
        "height_upper": 35.75,
        "n_signals": 250,
        "converged": True,
        "method": "4PL-B",
        "status": "ok",
    }
    solid = building["geometry"][0]
    assert (solid["type"], solid["lod"]) == ("Solid", "1")
    assert solid["semantics"]["values"] == [[0, 1, 2, 2, 2, 2]]

    # every solid's volume is its footprint's area times 12.5 m: outward faces, holes cut out
    volumes = solid_volumes(model["CityObjects"], model["vertices"], model["transform"])
    expected = {k: area * 12.5 for k, (_, area) in FOOTPRINTS.items()}
    expected.update({"two-parts-1": 25 * 12.5, "two-parts-2": 4 * 12.5})
    del expected["two-parts"]
    assert volumes == pytest.approx(expected, abs=1e-6)


def test_multipolygon_is_a_building_with_parts(tmp_path):
    write_cityjson(heights_table(), tmp_path / "b.city.json")
    objects = json.loads((tmp_path / "b.city.json").read_text())["CityObjects"]
    parent = objects["two-parts"]
    assert parent["children"] == ["two-parts-1", "two-parts-2"] and "geometry" not in parent
    assert parent["attributes"]["measuredHeight"] == 12.5
    for part in parent["children"]:
        assert objects[part]["type"] == "BuildingPart"
        assert objects[part]["parents"] == ["two-parts"]


def test_courtyard_bottom_and_top_faces_keep_the_hole(tmp_path):
    write_cityjson(heights_table(), tmp_path / "b.city.json")
    model = json.loads((tmp_path / "b.city.json").read_text())
    faces = model["CityObjects"]["courtyard"]["geometry"][0]["boundaries"][0]
    assert [len(face) for face in faces[:2]] == [2, 2]  # exterior + hole, bottom and top
    assert len(faces) == 2 + 4 + 4  # and one wall per edge of both rings


def test_collinear_vertex_kept_and_repeated_vertex_dropped():
    (footprint,) = snap_footprints([FOOTPRINTS["12/B"][0]])
    prisms = extrude([footprint], [GROUND], [ROOF])
    assert len(prisms.vertices) == 2 * 5  # 6 points given, the repeated one dropped
    assert len(prisms.face_kind) == 2 + 5


def test_cityjsonseq_lines(tmp_path, repo_data):
    out = write_cityjsonseq(
        heights_table([NOT_CONVERGED]), tmp_path / "b.city.jsonl", schema_dir=repo_data / SCHEMAS
    )
    assert out.report.valid and "json-schema" in out.report.checks
    lines = [json.loads(line) for line in (tmp_path / "b.city.jsonl").read_text().splitlines()]
    header, features = lines[0], lines[1:]
    assert header["type"] == "CityJSON" and header["CityObjects"] == {}
    assert header["vertices"] == [] and header["transform"]["scale"] == [0.001] * 3
    header_schema = official(repo_data)
    assert list(header_schema.iter_errors(header)) == []
    feature_schema = official(repo_data, "cityjsonfeature")
    assert [f["id"] for f in features] == list(FOOTPRINTS)
    for feature in features:
        assert feature["type"] == "CityJSONFeature"
        assert list(feature_schema.iter_errors(feature)) == []
        used = [
            i
            for o in feature["CityObjects"].values()
            for g in o.get("geometry", [])
            for face in g["boundaries"][0]
            for ring in face
            for i in ring
        ]
        assert sorted(set(used)) == list(range(len(feature["vertices"])))  # local, all used
    parts = features[3]["CityObjects"]
    assert set(parts) == {"two-parts", "two-parts-1", "two-parts-2"}


def test_sequence_volumes_match_the_file(tmp_path):
    write_cityjsonseq(heights_table(), tmp_path / "b.city.jsonl")
    lines = [json.loads(line) for line in (tmp_path / "b.city.jsonl").read_text().splitlines()]
    transform = lines[0]["transform"]
    volumes = {}
    for feature in lines[1:]:
        volumes.update(solid_volumes(feature["CityObjects"], feature["vertices"], transform))
    assert volumes["courtyard"] == pytest.approx(128 * 12.5)
    assert volumes["concave-U"] == pytest.approx(63 * 12.5)


def cjio_info(source: Path, stream: bool) -> str:
    """``cjio FILE info --long`` (``cjio stdin`` for CityJSONSeq); fails unless cjio exits 0."""
    command = Path(sys.executable).parent / "cjio"
    args = ["stdin"] if stream else [str(source)]
    out = subprocess.run(
        [str(command), *args, "info", "--long"],
        input=source.read_text() if stream else None,
        capture_output=True,
        text=True,
    )
    assert out.returncode == 0, out.stdout + out.stderr
    return out.stdout


@pytest.mark.parametrize("writer", [write_cityjson, write_cityjsonseq])
def test_cjio_loads_the_files(tmp_path, writer):
    stream = writer is write_cityjsonseq
    path = tmp_path / ("b.city.jsonl" if stream else "b.city.json")
    writer(heights_table(), path)
    lines = [json.loads(line) for line in path.read_text().splitlines()]
    n_vertices = sum(len(line["vertices"]) for line in lines)
    text = cjio_info(path, stream)
    # the box, the courtyard, the U, 12/B and two-parts, whose 2 polygons are BuildingParts
    assert "|-- Building (5)\n    |-- BuildingPart (2)" in text
    for line in (
        "CityJSON version = 2.0",
        "EPSG = 7405",
        f"bbox = [ {E:.3f} {N:.3f} {GROUND:.3f} {E + 50:.3f} {N + 29:.3f} {ROOF:.3f} ]",
        f"vertices_total = {n_vertices}",
        "geom primitives = ['Solid']",
        "LoD = ['1']",
        "semantics surfaces = ['GroundSurface', 'RoofSurface', 'WallSurface']",
    ):
        assert line in text.splitlines()


def test_real_mastermap_footprints(tmp_path, shared_data):
    footprints = read_footprints(shared_data / "footprints" / "mastermap-topo_3473984_0.gml")
    footprints["ground"] = 25.0
    footprints["relh2"] = np.linspace(6.0, 40.0, len(footprints))
    frame = buildings_with_heights(footprints, "relh2", relative=True)
    out = write_cityjson(frame, tmp_path / "m.city.json", schema_dir=shared_data / SCHEMAS)
    assert (out.written, len(out.skipped), out.report.valid) == (160, 0, True)
    model = json.loads((tmp_path / "m.city.json").read_text())
    first = dict(list(model["CityObjects"].items())[:20])  # the whole schema is slow: 20 of them
    assert list(official(shared_data).iter_errors({**model, "CityObjects": first})) == []
    attributes = model["CityObjects"][footprints["id"].iloc[-1]]["attributes"]
    assert (
        attributes["measuredHeight"] == 40.0 and attributes["method"] == "attribute relh2 + ground"
    )
    assert attributes["descriptiveGroup"] == ["Building", "Structure"]  # a list attribute


def test_ground_from_a_dem_then_relative_heights(tmp_path):
    z = np.full((40, 40), 17.5)
    frame = heights_table().drop(columns=["ground", "height"])
    frame["relh2"] = 9.0
    with MemoryFile() as mem:
        with mem.open(
            driver="GTiff",
            width=40,
            height=40,
            count=1,
            dtype="float64",
            crs="EPSG:27700",
            transform=from_origin(E - 5, N + 35, 2, 2),
        ) as ds:
            ds.write(z, 1)
        with mem.open() as dem:
            frame = building_ground(frame, dem)
    out = write_cityjson(
        buildings_with_heights(frame, "relh2", relative=True), tmp_path / "d.city.json"
    )
    attributes = json.loads((tmp_path / "d.city.json").read_text())["CityObjects"]["courtyard"][
        "attributes"
    ]
    assert (attributes["ground"], attributes["height"], attributes["measuredHeight"]) == (
        17.5,
        26.5,
        9.0,
    )
    assert out.written == 5


def test_unusable_heights_are_listed_and_skipped(tmp_path):
    extra = [
        NOT_CONVERGED,
        {**NOT_CONVERGED, "id": "below", "height": GROUND - 2, "converged": True},
        {**NOT_CONVERGED, "id": "no-ground", "ground": np.nan, "height": 30.0, "converged": True},
        {
            **NOT_CONVERGED,
            "id": "sliver",
            "geometry": shapely.box(E, N, E + 0.0004, N + 5),
            "height": ROOF,
            "converged": True,
        },
    ]
    out = write_cityjsonseq(heights_table(extra), tmp_path / "b.city.jsonl")
    assert dict(out.skipped.values.tolist()) == {
        "unsure": "height estimate did not converge (fewer than 10 signals)",
        "below": "roof not above the ground",
        "no-ground": "no ground height",
        "sliver": "footprint vanishes at 1 mm precision",
    }
    with pytest.raises(InputError, match="3 building.*unsure.*below.*no-ground"):
        write_cityjsonseq(heights_table(extra), tmp_path / "s.city.jsonl", strict=True)
    with pytest.raises(InputError, match="1 footprint.* vanish at 1 mm precision: sliver"):
        write_cityjsonseq(heights_table(extra[3:]), tmp_path / "s.city.jsonl", strict=True)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["b.city.jsonl"]  # nothing half-written


def test_british_national_grid_however_it_is_spelt(tmp_path):
    # with ODN heights, or bound to WGS 84 by a Helmert: the same grid (geodesy.is_bng)
    bound = (
        "+proj=tmerc +lat_0=49 +lon_0=-2 +k=0.9996012717 +x_0=400000 +y_0=-100000 +ellps=airy "
        "+towgs84=446.448,-125.157,542.06,0.15,0.247,0.842,-20.489 +units=m +no_defs"
    )
    for k, crs in enumerate(["EPSG:7405", "EPSG:27700+5701", bound]):
        frame = heights_table().set_crs(crs, allow_override=True)
        assert write_cityjson(frame, tmp_path / f"{k}.city.json").written == len(frame)


def test_bad_input(tmp_path):
    target = tmp_path / "b.city.json"
    frame = heights_table()
    with pytest.raises(InputError, match="without a polygon footprint: osgb1000005116342"):
        write_cityjson(frame.set_geometry([shapely.Point(E, N)] + list(frame.geometry[1:])), target)
    with pytest.raises(InputError, match="duplicate building id"):
        write_cityjson(frame.assign(id="same"), target)
    with pytest.raises(InputError, match="not EPSG:27700"):
        write_cityjson(frame.set_crs("EPSG:4326", allow_override=True), target)
    with pytest.raises(MissingColumnError, match="'ground'"):
        write_cityjson(frame.drop(columns="ground"), target)
    with pytest.raises(InputError, match="none of the 1 buildings"):
        write_cityjson(gpd.GeoDataFrame([NOT_CONVERGED], crs="EPSG:27700"), target)
    with pytest.raises(InputError, match="output folder does not exist"):
        write_cityjson(frame, tmp_path / "missing" / "b.city.json")
    write_cityjson(frame, target)
    with pytest.raises(InputError, match="output exists"):
        write_cityjson(frame, target)
    write_cityjson(frame, target, overwrite=True)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["b.city.json"]  # no temporary left


def test_buildings_with_heights_errors():
    frame = heights_table().drop(columns=["height"]).assign(relh2="tall")
    with pytest.raises(InputError, match="column 'relh2' is not numeric"):
        buildings_with_heights(frame, "relh2", relative=True)
    with pytest.raises(MissingColumnError, match="'abshmax'"):
        buildings_with_heights(frame, "abshmax")
    with pytest.raises(InputError, match="a column 'ground' besides the ground field 'base'"):
        buildings_with_heights(frame.assign(base=1.0, relh2=5.0), "relh2", ground_field="base")


@pytest.mark.parametrize("suffix", [".city.json", ".gml", "/tileset.json"])
def test_an_infinite_attribute_is_named_not_dropped_silently(tmp_path, suffix):
    """A number JSON cannot hold (inf, -inf) in a column of the input is written as no value
    (CityJSON, CityGML's attribute left out, 3D Tiles' no data) with a warning naming the column
    and the buildings; found at the command line: a GeoParquet column of inf, -inf went out of
    every format without a word."""
    from gnss_citygml.export import write_3dtiles, write_citygml

    frame = heights_table().assign(area_ratio=1.5)
    ids = frame["id"].tolist()
    frame.loc[0, "area_ratio"], frame.loc[1, "height_upper"] = np.inf, -np.inf
    writer = {".city.json": write_cityjson, ".gml": write_citygml, "/tileset.json": write_3dtiles}
    with pytest.warns(UserWarning) as caught:
        writer[suffix](frame, tmp_path / f"out{suffix}", validate=False)
    said = {str(w.message).split()[1]: str(w.message) for w in caught}
    assert said.keys() == {"area_ratio", "height_upper"}, said
    assert ids[0] in said["area_ratio"] and ids[1] not in said["area_ratio"]
    assert ids[1] in said["height_upper"] and "not finite" in said["height_upper"]
