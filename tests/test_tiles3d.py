"""3D Tiles 1.1 of the buildings (export/tiles3d.py): where they stand on the Earth, what each
building carries, how the folder is written."""

import json
import struct

import geopandas as gpd
import numpy as np
import pytest
import shapely

from gnss_citygml.errors import InputError
from gnss_citygml.export.tiles3d import write_3dtiles
from gnss_citygml.geodesy import from_osgb
from gnss_citygml.geodesy.grids import BUNDLED_GRID_DIR

#: GRS80 (ETRS89's ellipsoid): semi-major axis and flattening.
A, F = 6_378_137.0, 1 / 298.257222101


def ecef(lat, lon, h):
    """Geodetic (deg, m) to geocentric, GRS80, in closed form: an independent check."""
    lat, lon = np.radians(lat), np.radians(lon)
    e2 = F * (2 - F)
    n = A / np.sqrt(1 - e2 * np.sin(lat) ** 2)
    return np.column_stack(
        [
            (n + h) * np.cos(lat) * np.cos(lon),
            (n + h) * np.cos(lat) * np.sin(lon),
            (n * (1 - e2) + h) * np.sin(lat),
        ]
    )


@pytest.fixture(scope="module")
def buildings():
    """Five buildings in three 1 km squares and two 10 km squares of TQ: a box, one with a
    courtyard, an L, a two-part footprint and one without a height (left out)."""
    courtyard = shapely.box(529100, 181100, 529140, 181140).difference(
        shapely.box(529115, 181115, 529125, 181125)
    )
    ell = shapely.Polygon([(528500, 181500), (528530, 181500), (528530, 181510),
                           (528510, 181510), (528510, 181530), (528500, 181530)])  # fmt: skip
    parts = shapely.MultiPolygon(
        [shapely.box(530010, 181010, 530020, 181020), shapely.box(530030, 181010, 530040, 181020)]
    )
    return gpd.GeoDataFrame(
        {
            "id": ["box", "yard", "ell", "parts", "none"],
            "ground": [21.5, 22.0, 20.0, 18.25, 19.0],
            "height": [33.25, 40.0, 29.0, 27.5, np.nan],
            "height_lower": [32.0, np.nan, 28.0, 26.0, np.nan],
            "height_upper": [34.5, np.nan, 30.5, 29.0, np.nan],
            "n_signals": [120, 80, 40, 33, 0],
            "status": ["ok", "ok", "ok", "ok", "no signal"],
            "method": "4PL-B",
        },
        geometry=[
            shapely.box(529010, 181020, 529030, 181035),
            courtyard,
            ell,
            parts,
            shapely.box(539990, 181000, 539995, 181005),
        ],  # fmt: skip
        crs="EPSG:27700",
    )


@pytest.fixture(scope="module")
def tileset(buildings, tiles3d_schema_dir, node_dir, tmp_path_factory):
    """The buildings' tileset, with their ranges, validated as it is written (the official
    schemas, Khronos' glTF validator installed where it looks first, the metadata
    extensions)."""
    path = tmp_path_factory.mktemp("t") / "city" / "tileset.json"
    result = write_3dtiles(
        buildings, path, ranges=True, grid_dir=BUNDLED_GRID_DIR, schema_dir=tiles3d_schema_dir
    )
    return path, result


def test_the_tileset_is_validated_as_it_is_written(tileset):
    _, result = tileset
    assert result.report.valid and result.report.errors == []
    assert {"json-schema", "gltf", "gltf-metadata"} <= set(result.report.checks)


def read_glb(path):
    """The JSON and the binary chunk of a GLB file."""
    data = path.read_bytes()
    magic, version, total = struct.unpack_from("<III", data)
    assert (magic, version, total) == (0x46546C67, 2, len(data))
    length, kind = struct.unpack_from("<II", data, 12)
    assert kind == 0x4E4F534A
    gltf = json.loads(data[20 : 20 + length])
    blength, bkind = struct.unpack_from("<II", data, 20 + length)
    assert bkind == 0x004E4942
    return gltf, data[28 + length : 28 + length + blength]


def view(gltf, binary, index, dtype, width=1):
    v = gltf["bufferViews"][index]
    raw = np.frombuffer(binary, dtype=dtype, count=v["byteLength"] // np.dtype(dtype).itemsize,
                        offset=v["byteOffset"])  # fmt: skip
    return raw.reshape(-1, width) if width > 1 else raw


def accessor(gltf, binary, index):
    a = gltf["accessors"][index]
    dtype = {5126: np.float32, 5125: np.uint32}[a["componentType"]]
    width = {"SCALAR": 1, "VEC3": 3}[a["type"]]
    return view(gltf, binary, a["bufferView"], dtype, width)[: a["count"]]


def leaves(node):
    if "content" in node:
        yield node
    for child in node.get("children", []):
        yield from leaves(child)


def world_positions(folder, leaf):
    """A leaf's building vertices in ECEF: glTF's y-up turned z-up, then the tile's transform."""
    gltf, binary = read_glb(folder / leaf["content"]["uri"])
    primitive = gltf["meshes"][0]["primitives"][0]
    xyz = accessor(gltf, binary, primitive["attributes"]["POSITION"]).astype(float)
    z_up = np.column_stack([xyz[:, 0], -xyz[:, 2], xyz[:, 1]])
    return z_up + np.array(leaf["transform"][12:15]), gltf, binary, primitive


def test_every_building_with_a_height_is_written_in_its_1_km_square(tileset):
    path, result = tileset
    assert result.written == 4 and result.skipped["id"].tolist() == ["none"]
    doc = json.loads(path.read_text())
    assert doc["asset"]["version"] == "1.1"
    uris = sorted(leaf["content"]["uri"] for leaf in leaves(doc["root"]))
    assert uris == ["tiles/TQ2881.glb", "tiles/TQ2981.glb", "tiles/TQ3081.glb"]
    (hundred,) = doc["root"]["children"]  # TQ
    assert hundred["geometricError"] == 5000.0
    assert sorted(len(ten["children"]) for ten in hundred["children"]) == [1, 2]  # TQ38, TQ28
    assert (path.parent / "viewer.html").is_file()


def test_a_corner_stands_where_ostn15_and_osgm15_put_it_to_a_centimetre(tileset, buildings):
    path, _ = tileset
    doc = json.loads(path.read_text())
    lat, lon, h = from_osgb([529010.0, 529030.0], [181020.0, 181035.0], [21.5, 33.25],
                            grid_dir=BUNDLED_GRID_DIR)  # fmt: skip
    expected = ecef(lat, lon, h)  # the box's south-west foot and north-east roof corner
    near = []
    for leaf in leaves(doc["root"]):
        world, *_ = world_positions(path.parent, leaf)
        near.append(np.linalg.norm(world[:, None] - expected[None], axis=2).min(axis=0))
    assert np.min(near, axis=0).max() < 0.01


def test_every_vertex_is_inside_its_leafs_and_the_roots_region(tileset):
    path, _ = tileset
    doc = json.loads(path.read_text())
    root = doc["root"]["boundingVolume"]["region"]
    for leaf in leaves(doc["root"]):
        world, *_ = world_positions(path.parent, leaf)
        x, y, z = world.T
        lon = np.arctan2(y, x)
        lat = np.arctan2(z, np.hypot(x, y) * (1 - F * (2 - F)))  # geodetic, to ~1e-9 rad here
        for region in (leaf["boundingVolume"]["region"], root):
            assert (lon >= region[0] - 1e-9).all() and (lon <= region[2] + 1e-9).all()
            assert (lat >= region[1] - 1e-7).all() and (lat <= region[3] + 1e-7).all()


def strings(gltf, binary, table, name):
    """A string property's values."""
    spec = table["properties"][name]
    text = bytes(view(gltf, binary, spec["values"], np.uint8))
    offsets = view(gltf, binary, spec["stringOffsets"], np.uint32)
    return [text[a:b].decode() for a, b in zip(offsets[:-1], offsets[1:], strict=True)]


def test_each_building_is_a_feature_with_its_properties(tileset, buildings):
    path, _ = tileset
    doc = json.loads(path.read_text())
    seen = {}
    for leaf in leaves(doc["root"]):
        _, gltf, binary, primitive = world_positions(path.parent, leaf)
        table = gltf["extensions"]["EXT_structural_metadata"]["propertyTables"][0]
        ids, part = strings(gltf, binary, table, "id"), strings(gltf, binary, table, "part")
        count = part.count("building")
        assert part == ["building"] * count + ["range"] * (len(part) - count)
        features = accessor(gltf, binary, primitive["attributes"]["_FEATURE_ID_0"])
        assert set(np.unique(features).astype(int)) == set(range(count))
        heights = view(gltf, binary, table["properties"]["height"]["values"], np.float64)
        measured = view(gltf, binary, table["properties"]["measured_height"]["values"], np.float64)
        rows = zip(ids[:count], zip(heights, measured, strict=False), strict=False)
        seen.update(rows)
    expected = buildings.set_index("id").drop(index="none")
    assert sorted(seen) == sorted(expected.index)
    for name, (height, measured) in seen.items():
        assert height == expected.loc[name, "height"]
        assert measured == pytest.approx(
            expected.loc[name, "height"] - expected.loc[name, "ground"]
        )


def test_ranges_are_a_second_translucent_primitive_with_rows_of_their_own(tileset, buildings):
    """Each range's feature is a row of its own (``part`` ``range``), with its building's id
    and properties: a viewer styles them apart. The yard has no interval: no range."""
    path, _ = tileset
    doc = json.loads(path.read_text())
    ranged = []
    for leaf in leaves(doc["root"]):
        _, gltf, binary, _ = world_positions(path.parent, leaf)
        primitives = gltf["meshes"][0]["primitives"]
        assert len(primitives) == 2  # every square has a building with an interval
        assert gltf["materials"][primitives[1]["material"]]["alphaMode"] == "BLEND"
        table = gltf["extensions"]["EXT_structural_metadata"]["propertyTables"][0]
        ids, part = strings(gltf, binary, table, "id"), strings(gltf, binary, table, "part")
        features = accessor(gltf, binary, primitives[1]["attributes"]["_FEATURE_ID_0"])
        rows = np.unique(features).astype(int)
        assert all(part[k] == "range" for k in rows)
        ranged += [ids[k] for k in rows]
    assert sorted(ranged) == ["box", "ell", "parts"]


def test_the_output_is_a_tileset_json_in_a_folder_of_its_own(buildings, tmp_path):
    with pytest.raises(InputError, match="a 3D Tiles output is a folder's tileset.json"):
        write_3dtiles(buildings, tmp_path / "city.json")
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "notes.txt").write_text("mine")
    with pytest.raises(InputError, match="output exists"):
        write_3dtiles(buildings, tmp_path / "mine" / "tileset.json")
    with pytest.raises(InputError, match="holds files this output did not write"):
        write_3dtiles(buildings, tmp_path / "mine" / "tileset.json", overwrite=True)
    assert [p.name for p in (tmp_path / "mine").iterdir()] == ["notes.txt"]


def test_without_its_schemas_the_tileset_is_not_kept_and_the_error_says_what_to_do(
    buildings, tmp_path
):
    with pytest.raises(InputError, match="cannot validate the tileset") as caught:
        write_3dtiles(buildings, tmp_path / "city" / "tileset.json", schema_dir=tmp_path / "none")
    assert "--no-validate" in caught.value.fix
    assert list(tmp_path.iterdir()) == []  # no folder, and nothing half-written beside it


def _table_of(path):
    """Every leaf's property table: {id: {property: value}} of the building rows, and the ids
    of the range rows."""
    doc = json.loads(path.read_text())
    rows, ranged = {}, []
    for leaf in leaves(doc["root"]):
        gltf, binary = read_glb(path.parent / leaf["content"]["uri"])
        table = gltf["extensions"]["EXT_structural_metadata"]["propertyTables"][0]
        ids, part = strings(gltf, binary, table, "id"), strings(gltf, binary, table, "part")
        measured = view(gltf, binary, table["properties"]["measured_height"]["values"], np.float64)
        for k, (name, kind) in enumerate(zip(ids, part, strict=True)):
            if kind == "range":
                ranged.append(name)
            else:
                rows[name] = {"measured_height": float(measured[k])}
    return rows, sorted(ranged)


def test_ranges_no_building_can_have_are_not_drawn_and_said(buildings, tmp_path):
    """A range beyond what a building can be (far taller than 400 m, infinite, deep below the
    ground, half missing) is not drawn, with a warning naming the buildings; the others are."""
    frame = buildings.copy()
    frame["height_lower"] = [32.0, 30.0, 28.0, -2000.0, np.nan]
    frame["height_upper"] = [2e7, np.inf, 30.5, 29.0, np.nan]
    frame.loc[1, "height_lower"], frame.loc[1, "height_upper"] = 39.0, np.inf
    path = tmp_path / "city" / "tileset.json"
    with pytest.warns(UserWarning, match=r"3 building\(s\)' height range not drawn") as caught:
        write_3dtiles(frame, path, ranges=True, grid_dir=BUNDLED_GRID_DIR, validate=False)
    message = next(str(w.message) for w in caught if "not drawn" in str(w.message))
    assert "box (32 to 2e+07 m)" in message and "yard (39 to inf m)" in message
    assert "parts (-2000 to 29 m)" in message and "ell" not in message
    assert _table_of(path)[1] == ["ell"]
    frame["height_upper"] = [33.0, np.nan, 30.5, 29.0, np.nan]  # a bound missing
    frame["height_lower"] = [32.0, 39.0, 28.0, 26.0, np.nan]
    with pytest.warns(UserWarning, match=r"1 building\(s\)' height range not drawn: yard"):
        write_3dtiles(frame, tmp_path / "b" / "tileset.json", ranges=True,
                      grid_dir=BUNDLED_GRID_DIR, validate=False)  # fmt: skip


@pytest.mark.parametrize("column", ["measured_height", "part"])
def test_an_input_column_named_like_a_tiles_property_does_not_shadow_it(
    buildings, tmp_path, column
):
    """The tiles' own properties (measured_height, which the viewer colours by, and part)
    are the tool's: an input column of that name is left out, with a warning."""
    frame = buildings.assign(**{column: "not this"})
    path = tmp_path / "city" / "tileset.json"
    with pytest.warns(UserWarning, match=f"the input's column {column} is left out"):
        write_3dtiles(frame, path, grid_dir=BUNDLED_GRID_DIR, validate=False)
    rows, _ = _table_of(path)
    assert rows["box"]["measured_height"] == pytest.approx(33.25 - 21.5)
    assert sorted(rows) == ["box", "ell", "parts", "yard"]


@pytest.mark.parametrize("count", [-5, 2.5, 4_294_967_295, "many"])
def test_a_count_that_is_no_unsigned_number_is_refused_not_wrapped(buildings, count, tmp_path):
    """n_signals is an unsigned 32-bit property: -5 would be 4294967291, 2.5 would be 2 and
    4294967295 the no-data value; each is an error naming the building, and nothing is
    written."""
    counts = buildings["n_signals"].astype(object)
    counts[2] = count
    with pytest.raises(InputError, match=r"n_signals.*\bell\b") as caught:
        write_3dtiles(buildings.assign(n_signals=counts), tmp_path / "c" / "tileset.json",
                      validate=False, grid_dir=BUNDLED_GRID_DIR)  # fmt: skip
    assert "0 or more" in caught.value.what
    assert list(tmp_path.iterdir()) == []
