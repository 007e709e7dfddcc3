"""3D Tiles validation with what the machine has (gnss_citygml.validate.tiles3d): the JSON
schemas bundled with the package, the package's own checks of every GLB, Khronos' glTF
validator when node is there (the report says which ran), and `validate` telling a tileset
from a CityJSON file."""

import copy
import json
import os
import shutil
import struct
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import in_ci
from test_tiles3d_validate import buildings, glb, tile, tileset, write

from gnss_citygml.errors import InputError
from gnss_citygml.validate import (
    GLTF_VALIDATOR_VERSION,
    TILES3D_SCHEMA_DIR_ENV,
    validate_file,
    validate_tileset,
)
from gnss_citygml.validate.schemas import (
    BUNDLED_TILES3D_SCHEMAS,
    PACKED_SCHEMAS,
    SCHEMA_DIR_ENV,
    packed_schemas,
    tiles3d_schema_folder,
)

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tools"))
import pack_schemas  # noqa: E402


@pytest.fixture
def no_schema_variables(monkeypatch):
    monkeypatch.delenv(TILES3D_SCHEMA_DIR_ENV, raising=False)
    monkeypatch.delenv(SCHEMA_DIR_ENV, raising=False)


@pytest.fixture
def no_node(tmp_path, monkeypatch):
    """A PATH without node or npm."""
    empty = tmp_path / "empty-path"
    empty.mkdir()
    monkeypatch.setenv("PATH", str(empty))


def valid_tileset(folder):
    root = tile("tiles/0.glb", children=[tile("tiles/1.glb")])
    files = {"tileset.json": tileset(root), "tiles/0.glb": buildings()}
    files["tiles/1.glb"] = buildings(ids=("a",), heights=(3.0,))
    return write(folder, files)


# --- the schemas: the bundled copy unless another is given -----------------------------------


def test_the_bundled_schemas_are_the_default(tmp_path, no_schema_variables, no_node):
    assert tiles3d_schema_folder() == BUNDLED_TILES3D_SCHEMAS
    assert (BUNDLED_TILES3D_SCHEMAS / "LICENSE").is_file()
    report = validate_tileset(valid_tileset(tmp_path))
    assert report.valid, report.errors
    assert any("bundled with gnss-citygml" in note for note in report.notes), report.notes


def test_the_bundled_schemas_are_the_official_ones(tiles3d_schema_dir):
    """The pack holds the official files byte for byte, and exactly those the tileset's,
    metadata schema's and property table's references reach (the shared data holds them)."""
    shipped = packed_schemas(BUNDLED_TILES3D_SCHEMAS)
    roots = ["tileset.schema.json", "Schema/schema.schema.json"]
    roots.append("PropertyTable/propertyTable.schema.json")
    assert sorted(shipped) == pack_schemas.referred(tiles3d_schema_dir, roots)
    assert len(shipped) == 25
    for relative, text in shipped.items():
        assert text == (tiles3d_schema_dir / relative).read_bytes(), relative
    assert sorted(p.name for p in BUNDLED_TILES3D_SCHEMAS.iterdir()) == [
        "LICENSE",
        "README.md",
        PACKED_SCHEMAS,
    ]


def test_a_schema_folder_without_3d_tiles_falls_back_to_the_bundled_copy(
    tmp_path, no_schema_variables, monkeypatch
):
    """A general schema folder (the CityJSON schemas, say), given or from the environment."""
    cityjson = tmp_path / "cityjson-schemas"
    cityjson.mkdir()
    assert tiles3d_schema_folder(cityjson) == BUNDLED_TILES3D_SCHEMAS
    monkeypatch.setenv(SCHEMA_DIR_ENV, str(cityjson))
    assert tiles3d_schema_folder() == BUNDLED_TILES3D_SCHEMAS


def test_a_folder_given_is_used_first(tiles3d_schema_dir, no_schema_variables, monkeypatch):
    assert tiles3d_schema_folder(tiles3d_schema_dir) == tiles3d_schema_dir
    assert tiles3d_schema_folder(tiles3d_schema_dir.parent) == tiles3d_schema_dir
    monkeypatch.setenv(TILES3D_SCHEMA_DIR_ENV, str(tiles3d_schema_dir))
    assert tiles3d_schema_folder() == tiles3d_schema_dir


@pytest.mark.parametrize("where", ["variable", "argument"])
def test_a_missing_folder_is_an_error_naming_the_option(tmp_path, where, monkeypatch):
    """A folder named for the schemas that is not there: an error whose fix names the
    command line's option, not the Python argument."""
    if where == "variable":
        monkeypatch.setenv(TILES3D_SCHEMA_DIR_ENV, str(tmp_path / "elsewhere"))
        call = tiles3d_schema_folder
    else:
        monkeypatch.delenv(TILES3D_SCHEMA_DIR_ENV, raising=False)

        def call():
            return tiles3d_schema_folder(tmp_path / "elsewhere")

    with pytest.raises(InputError, match="elsewhere") as caught:
        call()
    assert "--schema-dir" in caught.value.fix and "schema_dir=" not in caught.value.fix


# --- glTF: the package's own checks always, Khronos' validator when node is there ------------


def _glb_file(change):
    """A GLB of two buildings as bytes, changed by ``change(doc, binary)`` (returns new bytes
    of the whole file, new binary bytes, or None: the JSON was changed in place)."""
    doc, binary = buildings()
    doc = copy.deepcopy(doc)
    changed = change(doc, binary)
    if isinstance(changed, bytes) and changed[:4] == b"glTF":
        return changed
    return glb(doc, changed if isinstance(changed, bytes) else binary)


def _indices_past_the_vertices(doc, binary):
    start = len(binary) + (-len(binary) % 8)
    doc["bufferViews"].append({"buffer": 0, "byteOffset": start, "byteLength": 12})
    doc["accessors"].append({"bufferView": 5, "componentType": 5125, "count": 3, "type": "SCALAR"})
    doc["meshes"][0]["primitives"][0]["indices"] = 2
    binary = binary + b"\0" * (start - len(binary)) + struct.pack("<3I", 0, 1, 6)
    doc["buffers"][0]["byteLength"] = len(binary)
    return binary


def _whole(doc, binary):
    return glb(doc, binary)


STRUCTURE = {
    "not a GLB": (lambda doc, b: b"glTF-not-really", "GLB header"),
    "version 1": (
        lambda doc, b: _whole(doc, b)[:4] + struct.pack("<I", 1) + _whole(doc, b)[8:],
        "GLB version 1, not 2",
    ),
    "length": (
        lambda doc, b: _whole(doc, b) + b"\0\0\0\0",
        "the header's length",
    ),
    "JSON chunk": (
        lambda doc, b: _whole(doc, b)[:20] + b"x" + _whole(doc, b)[21:],
        "the JSON chunk is not JSON",
    ),
    "accessor too long": (
        lambda doc, b: doc["accessors"][1].update(count=600),
        "/accessors/1: 600 values of 4 byte(s) from byte 0 do not fit buffer view 1",
    ),
    "view past the buffer": (
        lambda doc, b: doc["bufferViews"][4].update(byteLength=4000),
        "/bufferViews/4: bytes",
    ),
    "buffer past the BIN chunk": (
        lambda doc, b: doc["buffers"][0].update(byteLength=10_000),
        "/buffers/0: byteLength 10000 is more than the BIN chunk's",
    ),
    "index past the vertices": (_indices_past_the_vertices, "index 6, not below the 6 vertices"),
    "min not the data's": (
        lambda doc, b: doc["accessors"][0].update(min=[-5.0, 0.0, -10.0]),
        "/accessors/0/min: [-5.0, 0.0, -10.0], not the values' [0.0, 0.0, -10.0]",
    ),
    "POSITION without bounds": (
        lambda doc, b: doc["accessors"][0].pop("max"),
        "/accessors/0: a POSITION accessor without min and max",
    ),
    "component type a list": (  # values of the wrong JSON type: errors, not a crash
        lambda doc, b: doc["accessors"][1].update(componentType=[5126], count={}),
        "/accessors/1: componentType, type or count (at least 1) is not one of glTF's",
    ),
    "view offset a string": (
        lambda doc, b: doc["bufferViews"][0].update(byteOffset="0"),
        "/bufferViews/0: byteOffset or byteLength is not a non-negative integer",
    ),
    "no such accessor": (
        lambda doc, b: doc["meshes"][0]["primitives"][0]["attributes"].update(NORMAL=9),
        "attributes/NORMAL: accessor 9 does not exist",
    ),
}


def test_the_own_checks_find_each_broken_glb(tmp_path):
    names = {case: f"{i}.glb" for i, case in enumerate(STRUCTURE)}
    root = tile(children=[tile(name) for name in names.values()] + [tile("good.glb")])
    files = {"tileset.json": tileset(root), "good.glb": buildings()}
    files.update({names[case]: _glb_file(change) for case, (change, _) in STRUCTURE.items()})
    report = validate_tileset(write(tmp_path, files), khronos=False)
    by_file: dict[str, list[str]] = {}
    for issue in report.errors:
        by_file.setdefault(issue.object_id, []).append(f"{issue.rule}: {issue.message}")
    assert "good.glb" not in by_file
    for case, (_, expected) in STRUCTURE.items():
        found = by_file.get(names[case], [])
        assert any(m.startswith("gltf-structure: ") and expected in m for m in found), (
            case,
            found,
        )
    assert "gltf" not in report.checks and "gltf-structure" in report.checks
    assert any("Khronos' glTF validator not run: not asked for" in n for n in report.notes)


def test_without_node_the_own_checks_run_and_say_so(tmp_path, no_node, no_schema_variables):
    report = validate_tileset(valid_tileset(tmp_path))
    assert report.valid, report.errors
    assert report.checks == ["json-schema", "content", "gltf-structure", "gltf-metadata"]
    note = "glTF: the package's own checks; Khronos' glTF validator not run: node not found"
    assert note in report.notes
    with pytest.raises(InputError, match="node not found"):  # asked for: no silent fallback
        validate_tileset(tmp_path / "tileset.json", khronos=True)


def test_with_node_khronos_validator_runs_too_and_is_named(tmp_path, node_dir):
    report = validate_tileset(valid_tileset(tmp_path), node_dir=node_dir)
    assert report.valid, report.errors
    assert "gltf" in report.checks and "gltf-structure" in report.checks
    expected = (
        f"glTF: the package's own checks and Khronos' glTF validator {GLTF_VALIDATOR_VERSION}"
    )
    assert any(note.startswith(expected) for note in report.notes), report.notes


@pytest.mark.skipif(not shutil.which("npm") and not in_ci(), reason="needs node and npm")
def test_with_node_but_no_validator_installable_the_own_checks_run(tmp_path, monkeypatch):
    """node is there, the validator is not and npm cannot fetch it: said, not hidden."""
    monkeypatch.setenv("npm_config_registry", "http://127.0.0.1:9/")
    monkeypatch.setenv("npm_config_fetch_retries", "0")
    monkeypatch.setenv("npm_config_cache", str(tmp_path / "cache"))
    report = validate_tileset(valid_tileset(tmp_path / "t"), node_dir=tmp_path / "n")
    assert report.valid, report.errors
    (note,) = [n for n in report.notes if n.startswith("glTF:")]
    assert "Khronos' glTF validator not run: installing it with npm failed" in note
    assert f"npm install --prefix {tmp_path / 'n'} gltf-validator@" in note
    assert "gltf" not in report.checks
    # the next run does not wait for npm again: a failed install is not retried for a day
    monkeypatch.setattr(shutil, "which", lambda name, _which=shutil.which: (
        None if name == "npm" else _which(name)))  # fmt: skip
    again = validate_tileset(valid_tileset(tmp_path / "u"), node_dir=tmp_path / "n")
    (note,) = [n for n in again.notes if n.startswith("glTF:")]
    assert "failed in the last day" in note and "npm install --prefix" in note


# --- validate: a tileset is checked as one ------------------------------------------------------


def test_validate_file_checks_a_tileset(tmp_path, no_node):
    path = valid_tileset(tmp_path / "good")
    report = validate_file(path)
    assert report.valid and report.format == "3D Tiles 1.1", report.errors
    bad = tileset(tile("tiles/gone.glb"))
    del bad["geometricError"]
    report = validate_file(write(tmp_path / "bad", {"tileset.json": bad}))
    assert report.format == "3D Tiles 1.1"
    assert sorted(e.rule for e in report.errors) == ["content-missing", "json-schema"]


def test_a_city_json_that_mentions_asset_and_root_stays_city_json(tmp_path):
    doc = {"type": "CityJSON", "version": "2.0", "metadata": {"asset": {"version": "1"}},
           "root": {}, "CityObjects": {}, "vertices": [],
           "transform": {"scale": [1, 1, 1], "translate": [0, 0, 0]}}  # fmt: skip
    path = tmp_path / "x.city.json"
    path.write_text(json.dumps(doc))
    assert validate_file(path).format.startswith("CityJSON")


def _cli(args, cwd, path_env):
    env = {k: v for k, v in os.environ.items() if not k.startswith("GNSS_CITYGML_")}
    env.update(PATH=path_env, PYTHONPATH=str(ROOT))
    return subprocess.run(
        [sys.executable, "-m", "gnss_citygml", *map(str, args)],
        capture_output=True,
        text=True,
        env=env,
        cwd=cwd,
    )


def test_the_validate_command_checks_a_tileset(tmp_path):
    good = valid_tileset(tmp_path / "good")
    broken = tileset(tile("0.glb"))
    files = {"tileset.json": broken, "0.glb": _glb_file(lambda d, b: d["accessors"][0].pop("min"))}
    bad = write(tmp_path / "bad", files)
    empty = tmp_path / "empty-path"
    empty.mkdir()
    done = _cli(["validate", good], tmp_path, str(empty))
    assert done.returncode == 0, done.stdout + done.stderr
    assert "3D Tiles 1.1, 2 object(s): valid" in done.stdout
    assert "Khronos' glTF validator not run: node not found" in done.stderr
    done = _cli(["validate", bad], tmp_path, str(empty))
    assert done.returncode == 1, done.stdout + done.stderr
    assert "0.glb\tgltf-structure\t0.glb: /accessors/0: a POSITION accessor" in done.stdout


@pytest.mark.parametrize(
    "change",
    [
        lambda prop: prop.update(componentType={"not": "a name"}),
        lambda prop: prop.update(type="ENUM", enumType=["a list"]),
    ],
)
def test_metadata_of_the_wrong_json_type_is_an_error_not_a_crash(tmp_path, change):
    doc, binary = buildings()
    doc = copy.deepcopy(doc)
    schema = doc["extensions"]["EXT_structural_metadata"]["schema"]
    change(schema["classes"]["building"]["properties"]["height"])
    path = write(tmp_path, {"tileset.json": tileset(tile("0.glb")), "0.glb": (doc, binary)})
    report = validate_tileset(path, khronos=False)
    assert {e.rule for e in report.errors} == {"gltf-metadata"}
    assert any("/schema/classes/building/properties/height" in e.message for e in report.errors)
