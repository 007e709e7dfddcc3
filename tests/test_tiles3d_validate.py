"""3D Tiles 1.1 validation (gnss_citygml.validate.tiles3d): tilesets against the official JSON
schemas (from the shared data), their content, and GLBs made here by hand through Khronos' glTF
validator, really run: the module installs it with npm when missing (a failure to install, with
$CI set, is a failure, never a skip)."""

import copy
import json
import shutil
import struct

import numpy as np
import pytest
from conftest import in_ci

from gnss_citygml.errors import InputError
from gnss_citygml.validate import (
    GLTF_VALIDATOR_VERSION,
    TILES3D_SCHEMA_DIR_ENV,
    install_gltf_validator,
    validate_tileset,
)
from gnss_citygml.validate.gltf import NODE_DIR_ENV, gltf_validator, node_folder
from gnss_citygml.validate.schemas import SCHEMA_DIR_ENV, tiles3d_schema_folder

ARRAY_BUFFER = 34962
FLOAT = 5126


# --- a GLB made by hand: what the writer produces ---------------------------------------------


def _pad(data: bytes, n: int = 8, fill: bytes = b"\0") -> bytes:
    return data + fill * (-len(data) % n)


def glb(doc: dict, binary: bytes) -> bytes:
    """A GLB: the 12-byte header, the JSON chunk (padded with spaces), the BIN chunk."""
    text = _pad(json.dumps(doc, separators=(",", ":")).encode(), 4, b" ")
    binary = _pad(binary, 4)
    length = 12 + 8 + len(text) + 8 + len(binary)
    return (
        struct.pack("<4sII", b"glTF", 2, length)
        + struct.pack("<I4s", len(text), b"JSON")
        + text
        + struct.pack("<I4s", len(binary), b"BIN\0")
        + binary
    )


def buildings(ids=("osgb1000012345", "osgb1000067890é"), heights=(10.5, 20.25)):
    """The glTF JSON and binary chunk of one triangle per building: POSITION, the feature id of
    each vertex (``_FEATURE_ID_0``, EXT_mesh_features) and a property table of the buildings'
    ``id`` (string) and ``height`` (float32) (EXT_structural_metadata)."""
    n = len(ids)
    triangle = np.array([[0, 0, 0], [10, 0, 0], [0, 0, -10]], dtype="<f4")
    positions = np.concatenate([triangle + [20 * i, 0, 0] for i in range(n)]).astype("<f4")
    feature_ids = np.repeat(np.arange(n), 3).astype("<f4")
    strings = [s.encode() for s in ids]
    offsets = np.cumsum([0] + [len(s) for s in strings]).astype("<u4")
    columns = [
        positions.tobytes(),
        feature_ids.tobytes(),
        b"".join(strings),
        offsets.tobytes(),
        np.asarray(heights, dtype="<f4").tobytes(),
    ]
    views, binary = [], b""
    for i, column in enumerate(columns):
        binary = _pad(binary)  # every buffer view starts on 8 bytes
        view = {"buffer": 0, "byteOffset": len(binary), "byteLength": len(column)}
        if i < 2:
            view["target"] = ARRAY_BUFFER
        views.append(view)
        binary += column
    doc = {
        "asset": {"version": "2.0", "generator": "gnss-citygml"},
        "extensionsUsed": ["EXT_mesh_features", "EXT_structural_metadata"],
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0}],
        "meshes": [
            {
                "primitives": [
                    {
                        "attributes": {"POSITION": 0, "_FEATURE_ID_0": 1},
                        "mode": 4,
                        "extensions": {
                            "EXT_mesh_features": {
                                "featureIds": [
                                    {"featureCount": n, "attribute": 0, "propertyTable": 0}
                                ]
                            }
                        },
                    }
                ]
            }
        ],
        "extensions": {
            "EXT_structural_metadata": {
                "schema": {
                    "id": "gnss_citygml",
                    "classes": {
                        "building": {
                            "properties": {
                                "id": {"type": "STRING", "required": True},
                                "height": {"type": "SCALAR", "componentType": "FLOAT32"},
                            }
                        }
                    },
                },
                "propertyTables": [
                    {
                        "class": "building",
                        "count": n,
                        "properties": {
                            "id": {"values": 2, "stringOffsets": 3, "stringOffsetType": "UINT32"},
                            "height": {"values": 4},
                        },
                    }
                ],
            }
        },
        "accessors": [
            {
                "bufferView": 0,
                "componentType": FLOAT,
                "count": 3 * n,
                "type": "VEC3",
                "min": positions.min(axis=0).tolist(),
                "max": positions.max(axis=0).tolist(),
            },
            {"bufferView": 1, "componentType": FLOAT, "count": 3 * n, "type": "SCALAR"},
        ],
        "bufferViews": views,
        "buffers": [{"byteLength": len(_pad(binary, 4))}],
    }
    return doc, binary


BOX = [20.0, 0.0, 5.0, 20.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 5.0]


def tile(uri=None, **more):
    """A tile with a box bounding volume and, if given, a content uri."""
    tile = {"boundingVolume": {"box": BOX}, "geometricError": 0.0, **more}
    if uri is not None:
        tile["content"] = {"uri": uri}
    return tile


def tileset(root, **more):
    return {"asset": {"version": "1.1"}, "geometricError": 50.0, "root": root, **more}


def write(folder, files: dict):
    """Write ``{relative name: JSON-able, bytes or (doc, binary) of a GLB}`` under ``folder``."""
    for name, content in files.items():
        path = folder / name
        path.parent.mkdir(parents=True, exist_ok=True)
        if isinstance(content, tuple):
            content = glb(*content)
        path.write_bytes(content if isinstance(content, bytes) else json.dumps(content).encode())
    return folder / "tileset.json"


def validate(path, tiles3d_schema_dir, node_dir):
    return validate_tileset(path, schema_dir=tiles3d_schema_dir, node_dir=node_dir)


# --- valid and invalid tilesets ---------------------------------------------------------------


def test_a_valid_tileset_passes(tmp_path, tiles3d_schema_dir, node_dir):
    root = tile("tiles/0.glb", refine="ADD", children=[tile("tiles/1.glb"), tile("sub.json")])
    path = write(
        tmp_path,
        {
            "tileset.json": tileset(root),
            "sub.json": tileset(tile("tiles/2.glb")),
            "tiles/0.glb": buildings(),
            "tiles/1.glb": buildings(ids=("a",), heights=(3.0,)),
            "tiles/2.glb": buildings(ids=("b", "", "c"), heights=(1.0, 2.0, 3.0)),
        },
    )
    report = validate(path, tiles3d_schema_dir, node_dir)
    assert report.errors == []
    assert report.valid
    assert report.format == "3D Tiles 1.1"
    assert report.n_objects == 4  # the tiles of both tilesets
    assert report.checks == ["json-schema", "content", "gltf-structure", "gltf", "gltf-metadata"]
    # the validator cannot check the metadata extensions: an info, not an error
    assert any("UNSUPPORTED_EXTENSION" in note for note in report.notes)


def test_a_tileset_missing_its_geometric_error_fails(tmp_path, tiles3d_schema_dir, node_dir):
    doc = tileset(tile("0.glb"))
    del doc["geometricError"]
    report = validate(
        write(tmp_path, {"tileset.json": doc, "0.glb": buildings()}), tiles3d_schema_dir, node_dir
    )
    assert [(e.object_id, e.rule) for e in report.errors] == [("tileset.json", "json-schema")]
    assert "'geometricError' is a required property" in report.errors[0].message


def test_schema_errors_name_where_they_are(tmp_path, tiles3d_schema_dir, node_dir):
    doc = tileset(tile(children=[tile(), {"boundingVolume": {}, "geometricError": -1}]))
    doc["asset"] = {"version": 1.1}
    report = validate(write(tmp_path, {"tileset.json": doc}), tiles3d_schema_dir, node_dir)
    messages = sorted(e.message for e in report.errors)
    assert {e.rule for e in report.errors} == {"json-schema"}
    assert any("asset/version: 1.1 is not of type 'string'" in m for m in messages)
    assert any("root/children/1/boundingVolume" in m for m in messages)
    assert any("root/children/1/geometricError: -1 is less than" in m for m in messages)


def test_a_missing_content_fails(tmp_path, tiles3d_schema_dir, node_dir):
    root = tile("0.glb", children=[tile("tiles/gone.glb")])
    report = validate(
        write(tmp_path, {"tileset.json": tileset(root), "0.glb": buildings()}),
        tiles3d_schema_dir,
        node_dir,
    )
    assert [(e.object_id, e.rule) for e in report.errors] == [("tileset.json", "content-missing")]
    assert "/root/children/0/content/uri: tiles/gone.glb: no such file" in report.errors[0].message


def test_a_broken_accessor_fails_naming_the_file(tmp_path, tiles3d_schema_dir, node_dir):
    doc, binary = buildings()
    broken = copy.deepcopy(doc)
    broken["accessors"][0]["count"] = 600  # far more than its buffer view holds
    broken["accessors"][1]["count"] = 600
    root = tile("tiles/good.glb", children=[tile("tiles/broken.glb")])
    files = {"tileset.json": tileset(root), "tiles/good.glb": (doc, binary)}
    files["tiles/broken.glb"] = (broken, binary)
    report = validate(write(tmp_path, files), tiles3d_schema_dir, node_dir)
    assert not report.valid
    found = {(e.object_id, e.rule) for e in report.errors}
    assert found == {("tiles/broken.glb", "gltf"), ("tiles/broken.glb", "gltf-structure")}
    first = next(e.message for e in report.errors if e.rule == "gltf")
    assert first.startswith("tiles/broken.glb: ACCESSOR_TOO_LONG at /accessors/0: Accessor")
    assert "does not fit referenced bufferView [0]" in first


def test_external_tilesets_are_validated_recursively(tmp_path, tiles3d_schema_dir, node_dir):
    """An external tileset's own errors, those of its content, a cycle back to the root."""
    deeper = tileset(tile("../../tileset.json", children=[tile("../nothing.glb")]))
    del deeper["root"]["geometricError"]
    files = {
        "tileset.json": tileset(tile("a/sub.json")),
        "a/sub.json": tileset(tile("b/deeper.json")),
        "a/b/deeper.json": deeper,
        "a/b/not.glb": b"not a GLB",
    }
    deeper["root"]["children"].append(tile("not.glb"))
    report = validate(write(tmp_path, files), tiles3d_schema_dir, node_dir)
    found = sorted((e.object_id, e.rule) for e in report.errors)
    assert found == [
        ("a/b/deeper.json", "content-missing"),
        ("a/b/deeper.json", "json-schema"),
        ("a/b/deeper.json", "tileset-cycle"),
        ("a/b/not.glb", "gltf"),
        ("a/b/not.glb", "gltf-structure"),
    ]
    assert report.n_objects == 5


def test_not_json_is_a_syntax_error(tmp_path, tiles3d_schema_dir, node_dir):
    path = tmp_path / "tileset.json"
    path.write_text('{"asset": {"version": "1.1"},', encoding="utf-8")
    report = validate(path, tiles3d_schema_dir, node_dir)
    assert [(e.rule, e.object_id) for e in report.errors] == [("json-syntax", "tileset.json")]
    assert "line 1" in report.errors[0].message


def test_content_not_read_is_noted(tmp_path, tiles3d_schema_dir, node_dir):
    root = tile("https://example.invalid/0.glb", children=[tile("0.b3dm")])
    report = validate(
        write(tmp_path, {"tileset.json": tileset(root), "0.b3dm": b"b3dm"}),
        tiles3d_schema_dir,
        node_dir,
    )
    assert report.valid
    assert "1 content file(s) not checked: https: URI, not a local file" in report.notes
    assert "1 content file(s) not checked: .b3dm, a format not validated" in report.notes


# --- the metadata extensions, which Khronos' validator does not check --------------------------


def _broken(change):
    doc, binary = buildings()
    doc = copy.deepcopy(doc)
    changed = change(doc, binary)  # new bytes, or the JSON changed in place
    return doc, changed if isinstance(changed, bytes) else binary


def _offsets_past_the_end(doc, binary):
    view = doc["bufferViews"][3]
    start = view["byteOffset"] + view["byteLength"] - 4
    return binary[:start] + struct.pack("<I", 999) + binary[start + 4 :]


METADATA = {
    "unknown class": (
        lambda doc, _: doc["extensions"]["EXT_structural_metadata"]["propertyTables"][0].update(
            {"class": "house"}
        ),
        "/extensions/EXT_structural_metadata/propertyTables/0/class: 'house' is not a class",
    ),
    "required id missing": (
        lambda doc, _: doc["extensions"]["EXT_structural_metadata"]["propertyTables"][0][
            "properties"
        ].pop("id"),
        "the required property 'id' of class 'building' is missing",
    ),
    "count zero": (
        lambda doc, _: doc["extensions"]["EXT_structural_metadata"]["propertyTables"][0].update(
            {"count": 0}
        ),
        "propertyTables/0/count: 0 is less than the minimum of 1",
    ),
    "bad component type": (
        lambda doc, _: doc["extensions"]["EXT_structural_metadata"]["schema"]["classes"][
            "building"
        ]["properties"]["height"].update({"componentType": "FLOAT16"}),
        "/extensions/EXT_structural_metadata/schema/classes/building/properties/height/"
        "componentType",
    ),
    "heights too short": (
        lambda doc, _: doc["bufferViews"][4].update({"byteLength": 4}),
        "properties/height: values: buffer view 4 holds 4 bytes, fewer than the 8 of 2 values",
    ),
    "offsets past the end": (
        _offsets_past_the_end,
        "properties/id: stringOffsets: the last offset, 999, is past the 30 bytes",
    ),
    "no feature id attribute": (
        lambda doc, _: doc["meshes"][0]["primitives"][0]["extensions"]["EXT_mesh_features"][
            "featureIds"
        ][0].update({"attribute": 1}),
        "featureIds/0: attribute 1: the primitive has no attribute _FEATURE_ID_1",
    ),
    "no such property table": (
        lambda doc, _: doc["meshes"][0]["primitives"][0]["extensions"]["EXT_mesh_features"][
            "featureIds"
        ][0].update({"propertyTable": 3}),
        "propertyTable 3: no such property table (1 in the file)",
    ),
}


def test_metadata_errors_are_found(tmp_path, tiles3d_schema_dir, node_dir):
    """Each broken GLB, all in one tileset (one node process), has its own error."""
    names = {case: f"{i}.glb" for i, case in enumerate(METADATA)}
    root = tile(children=[tile(name) for name in names.values()])
    files = {"tileset.json": tileset(root)}
    files.update({names[case]: _broken(change) for case, (change, _) in METADATA.items()})
    report = validate(write(tmp_path, files), tiles3d_schema_dir, node_dir)
    by_file: dict[str, list[str]] = {}
    for issue in report.errors:
        assert issue.rule == "gltf-metadata", issue
        by_file.setdefault(issue.object_id, []).append(issue.message)
    for case, (_, expected) in METADATA.items():
        messages = by_file.get(names[case], [])
        assert any(expected in m for m in messages), (case, messages)


def test_strings_that_are_not_utf8_fail(tmp_path, tiles3d_schema_dir, node_dir):
    doc, binary = buildings(ids=("ab", "cd"))
    start = doc["bufferViews"][2]["byteOffset"]
    binary = binary[:start] + b"\xff" + binary[start + 1 :]
    files = {"tileset.json": tileset(tile("0.glb")), "0.glb": (doc, binary)}
    report = validate(write(tmp_path, files), tiles3d_schema_dir, node_dir)
    assert [e.rule for e in report.errors] == ["gltf-metadata"]
    assert "the strings are not UTF-8" in report.errors[0].message


# --- what cannot be validated at all ------------------------------------------------------------


def test_missing_schemas_are_an_input_error(tmp_path, monkeypatch):
    """The folder named for them lacks them (a general schema folder without them falls back
    to the bundled copy: test_tiles3d_defaults.py)."""
    monkeypatch.setenv(TILES3D_SCHEMA_DIR_ENV, str(tmp_path / "elsewhere"))
    with pytest.raises(InputError) as caught:
        tiles3d_schema_folder()
    error = caught.value
    assert error.where == str(tmp_path / "elsewhere")
    assert TILES3D_SCHEMA_DIR_ENV in error.fix and "CesiumGS/3d-tiles" in error.fix


def test_the_schema_folder_from_the_environment(tiles3d_schema_dir, monkeypatch):
    monkeypatch.setenv(SCHEMA_DIR_ENV, str(tiles3d_schema_dir.parent))
    monkeypatch.delenv(TILES3D_SCHEMA_DIR_ENV, raising=False)
    assert tiles3d_schema_folder() == tiles3d_schema_dir
    monkeypatch.setenv(SCHEMA_DIR_ENV, "/nowhere")
    monkeypatch.setenv(TILES3D_SCHEMA_DIR_ENV, str(tiles3d_schema_dir))
    assert tiles3d_schema_folder() == tiles3d_schema_dir


def test_a_missing_tileset_is_an_input_error(tmp_path, tiles3d_schema_dir):
    with pytest.raises(InputError, match="tileset not found"):
        validate_tileset(tmp_path / "tileset.json", schema_dir=tiles3d_schema_dir)


def test_a_missing_validator_says_what_to_run(tmp_path, tiles3d_schema_dir):
    write(tmp_path, {"tileset.json": tileset(tile("0.glb")), "0.glb": buildings()})
    with pytest.raises(InputError) as caught:
        validate_tileset(
            tmp_path / "tileset.json",
            schema_dir=tiles3d_schema_dir,
            node_dir=tmp_path / "n",
            khronos=True,  # (by default it is installed, or the own checks run alone)
        )
    command = f"npm install --prefix {tmp_path / 'n'} gltf-validator@{GLTF_VALIDATOR_VERSION}"
    assert command in caught.value.fix
    with pytest.raises(InputError):
        gltf_validator(tmp_path / "n")


def test_without_npm_the_install_says_what_to_do(tmp_path, monkeypatch):
    monkeypatch.setenv("PATH", str(tmp_path))  # neither node nor npm
    with pytest.raises(InputError) as caught:
        install_gltf_validator(tmp_path / "n")
    assert caught.value.where == "PATH"
    assert "install Node.js" in caught.value.fix and "npm install --prefix" in caught.value.fix


@pytest.mark.skipif(not shutil.which("npm") and not in_ci(), reason="needs npm")
def test_a_failed_install_says_what_to_run(tmp_path, monkeypatch):
    """npm cannot reach its registry (a closed port, an empty cache): the error gives the
    command to run, and nothing is left that looks installed."""
    monkeypatch.setenv("npm_config_registry", "http://127.0.0.1:9/")
    monkeypatch.setenv("npm_config_fetch_retries", "0")
    monkeypatch.setenv("npm_config_cache", str(tmp_path / "cache"))
    with pytest.raises(InputError, match="installing the glTF validator failed") as caught:
        install_gltf_validator(tmp_path / "n")
    assert f"npm install --prefix {tmp_path / 'n'} gltf-validator@" in caught.value.fix
    with pytest.raises(InputError, match="is not installed"):
        gltf_validator(tmp_path / "n")


def test_the_node_folder(monkeypatch, tmp_path):
    monkeypatch.setenv(NODE_DIR_ENV, str(tmp_path))
    assert node_folder() == tmp_path
    monkeypatch.delenv(NODE_DIR_ENV)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    assert node_folder() == tmp_path / "cache" / "gnss-citygml" / "node"


def test_node_and_npm_are_there_in_ci():
    """Under CI the validator's tests must run: node and npm are part of the machine."""
    if in_ci():
        assert shutil.which("node") and shutil.which("npm")
