"""The wheel as a user gets it: built from the tree, installed into a clean venv, it holds the
grids with their licence, the sample city, the contracts (schemas/), the 3D Tiles schemas with
their licence and the command, and runs `gnss-citygml demo` and the README's 3D Tiles command
with no other file, no network and nothing of the developer's (no grid folder, no PROJ user
grids, none of the project's variables, no node unless a test puts it there).

The clean venv gets the third-party packages through a ``.pth`` file naming the development
venv's site-packages (installing them would need the network). ``.pth`` files inside a folder
added that way are not processed, so the development venv's editable gnss_citygml is not
importable there: the test checks that the package imported is the installed wheel.
"""

import hashlib
import json
import os
import shutil
import subprocess
import sys
import sysconfig
import time
import zipfile
from pathlib import Path

import pytest

import gnss_citygml
from gnss_citygml.cli.demo import OUTPUTS, REPORT_OUTPUTS
from gnss_citygml.contracts import SCHEMA_FOLDER
from gnss_citygml.files.styles import heights_qml
from gnss_citygml.geodesy.grids import BUNDLED_GRID_DIR, GRIDS
from gnss_citygml.validate import GLTF_VALIDATOR_VERSION
from gnss_citygml.validate.schemas import BUNDLED_CITYJSON_SCHEMAS, BUNDLED_TILES3D_SCHEMAS

ROOT = Path(__file__).resolve().parents[1]
CITY_FILES = ("observations.parquet", "footprints.gpkg", "dem.tif", "truth.csv")


def _run(args, **kwargs):
    """Run a command; its completed process, failing the test with its output if it fails."""
    done = subprocess.run([str(a) for a in args], capture_output=True, text=True, **kwargs)
    assert done.returncode == 0, f"{args[:3]} exit {done.returncode}\n{done.stdout}{done.stderr}"
    return done


def _source_copy(target: Path) -> Path:
    """The repository's files (tracked, or new and not ignored) copied to ``target``, so that
    building leaves nothing in the tree and nothing stale in it (a ``build/``) gets in."""
    listed = _run(["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"], cwd=ROOT)
    for name in filter(None, listed.stdout.split("\0")):
        source = ROOT / name
        if not os.path.lexists(source):  # deleted in the tree, not yet in the index
            continue
        (target / name).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(source, target / name, follow_symlinks=False)
    return target


@pytest.fixture(scope="module")
def timings():
    """Seconds per step, printed at the end of the module (run with -s to see them)."""
    steps = {}
    yield steps
    print("\nwheel test: " + ", ".join(f"{k} {v:.1f} s" for k, v in steps.items()))


@pytest.fixture(scope="module")
def wheel(tmp_path_factory, timings):
    start = time.perf_counter()
    tmp = tmp_path_factory.mktemp("wheel")
    source = _source_copy(tmp / "src")
    _run([sys.executable, "-m", "build", "--wheel", "--no-isolation", "--outdir", tmp / "dist",
          source])  # fmt: skip
    (path,) = (tmp / "dist").glob("gnss_citygml-*.whl")
    timings["build"] = time.perf_counter() - start
    return path


@pytest.fixture(scope="module")
def clean_venv(wheel, tmp_path_factory, timings):
    """A new venv with the wheel installed and the third-party packages by a ``.pth``."""
    start = time.perf_counter()
    venv = tmp_path_factory.mktemp("venv") / "clean"
    _run([sys.executable, "-m", "venv", venv])
    python = venv / "bin" / "python"
    site = _run([python, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"])
    Path(site.stdout.strip(), "dev-site-packages.pth").write_text(
        sysconfig.get_paths()["purelib"] + "\n"
    )
    _run([python, "-m", "pip", "install", "--no-deps", "--no-index", "--quiet", wheel])
    timings["venv + install"] = time.perf_counter() - start
    return venv


@pytest.fixture(scope="module")
def user_env(tmp_path_factory):
    """A user's environment: an empty home (so no PROJ user grids), none of the project's
    variables, no virtualenv or path settings of the developer's."""
    home = tmp_path_factory.mktemp("home")
    env = dict(os.environ, HOME=str(home))
    project = [name for name in env if name.startswith("GNSS_CITYGML_")]  # none of them
    for name in ("PROJ_USER_WRITABLE_DIRECTORY", "XDG_DATA_HOME", "XDG_CACHE_HOME", "PYTHONPATH",
                 "VIRTUAL_ENV", "PROJ_DATA", "PROJ_LIB", *project):  # fmt: skip
        env.pop(name, None)
    return env


def test_the_wheel_holds_the_grids_their_licence_the_city_and_the_command(wheel):
    with zipfile.ZipFile(wheel) as archive:
        names = set(archive.namelist())
        info = next(n.rsplit("/", 1)[0] for n in names if n.endswith(".dist-info/METADATA"))
        data = "gnss_citygml/data/"
        for grid in GRIDS:
            digest = hashlib.sha256(archive.read(data + "grids/" + grid)).hexdigest()
            assert digest == hashlib.sha256((BUNDLED_GRID_DIR / grid).read_bytes()).hexdigest()
        for name in ("LICENSE", "README.md"):
            assert data + "grids/" + name in names
        for name in CITY_FILES:
            assert data + "city/" + name in names
        assert archive.read(data + "styles/heights.qml").decode() == heights_qml()  # QGIS style
        for name in SCHEMA_FOLDER.iterdir():  # the contracts: JSON Schemas, CityJSON Extension
            assert archive.read("gnss_citygml/schemas/" + name.name) == name.read_bytes()
        assert "gnss_citygml/validate/gltf_validate.mjs" in names  # runs the glTF validator
        for schema in BUNDLED_CITYJSON_SCHEMAS.iterdir():  # CityJSON 2.0.2's (CC0)
            assert archive.read(f"{data}cityjson-2.0.2/{schema.name}") == schema.read_bytes()
        for schema in BUNDLED_TILES3D_SCHEMAS.rglob("*"):  # the 3D Tiles 1.1 JSON schemas
            if schema.is_file():
                name = (
                    "gnss_citygml/data/3dtiles-1.1/"
                    + schema.relative_to(BUNDLED_TILES3D_SCHEMAS).as_posix()
                )
                assert archive.read(name) == schema.read_bytes(), name
        assert (
            "CC BY 4.0"
            in archive.read(f"{info}/licenses/gnss_citygml/data/3dtiles-1.1/LICENSE").decode()
        )
        assert f"{info}/licenses/LICENSE" in names
        notice = archive.read(f"{info}/licenses/gnss_citygml/data/grids/LICENSE").decode()
        assert "Ordnance Survey" in notice and "Redistribution and use" in notice
        assert "MIT License" in archive.read(f"{info}/licenses/LICENSE").decode()
        metadata = archive.read(f"{info}/METADATA").decode()
        assert "License-Expression: MIT AND BSD-2-Clause AND CC-BY-4.0" in metadata
        entry_points = archive.read(f"{info}/entry_points.txt").decode()
        assert "gnss-citygml = gnss_citygml.cli:main" in entry_points
        assert not any("__pycache__" in n or n.startswith(("tests/", "benchmarks/")) for n in names)


def test_the_installed_wheel_runs_the_demo_offline(clean_venv, user_env, tmp_path, timings):
    python, command = clean_venv / "bin" / "python", clean_venv / "bin" / "gnss-citygml"
    code = "import gnss_citygml; print(gnss_citygml.__file__)"
    where = _run([python, "-c", code], env=user_env, cwd=tmp_path)  # not the tree's folder
    installed = Path(where.stdout.strip())
    assert installed.is_relative_to(clean_venv), installed  # the wheel, not the editable tree
    assert not installed.is_relative_to(Path(gnss_citygml.__file__).parents[1])
    _run([python, "-m", "pip", "check"], env=user_env, cwd=tmp_path)

    grids = _run([command, "grids"], env=user_env, cwd=tmp_path)
    lines = grids.stdout.splitlines()
    assert len(lines) == 2 and all("(bundled with gnss-citygml)" in line for line in lines)
    assert all(str(installed.parent / "data" / "grids") in line for line in lines)

    start = time.perf_counter()
    work = tmp_path / "work"  # outside the repository: nothing found beside the command
    work.mkdir()
    demo = _run([command, "demo", "-o", "OUT", "--quiet"], env=user_env, cwd=work)
    timings["demo"] = time.perf_counter() - start
    for name in ("heights.gpkg", "city.city.json", "city.gml"):
        assert (work / "OUT" / name).stat().st_size > 0, name
    assert json.loads((work / "OUT" / "city.city.json").read_text())["type"] == "CityJSON"
    lines = demo.stdout.splitlines()
    header = next(i for i, line in enumerate(lines) if line.split()[:2] == ["id", "estimate"])
    rows = lines[header + 1 : header + 31]
    assert len(rows) == 30 and all(row.startswith("city_") for row in rows)
    assert lines[header + 31].startswith("24 of 30 buildings converged, RMSE ")
    # the report too (matplotlib, an extra, is among the developer's packages here)
    assert sorted(p.name for p in (work / "OUT").iterdir()) == sorted(OUTPUTS + REPORT_OUTPUTS)

    # typed attributes: the installed package finds its CityJSON Extension to validate them
    args = ["convert", "OUT/heights.gpkg", "-o", "typed.city.json", "--typed-attributes"]
    typed = _run([command, *args], env=user_env, cwd=work)
    assert "extension" in typed.stdout.split("valid (")[1]
    # validate checks it against the CityJSON 2.0.2 schema bundled with the package
    schema = _run([command, "validate", "typed.city.json"], env=user_env, cwd=work)
    assert "json-schema" in schema.stdout.split("valid (checks: ")[1], schema.stdout

    # 3D Tiles as the README writes them, with no node on the PATH: the schemas bundled with
    # the package and its own checks of every GLB, which the output names
    hidden = tmp_path / "path-without-node"
    hidden.mkdir()
    no_node = dict(user_env, PATH=str(hidden))
    tiles = _run([command, "convert", "OUT/heights.gpkg", "-o", "t/tileset.json"], env=no_node,
                 cwd=work)  # fmt: skip
    assert "-> t/tileset.json, valid (json-schema, content, gltf-structure, gltf-metadata)" in (
        tiles.stdout
    )
    assert "Khronos' glTF validator not run: node not found" in tiles.stderr
    assert "(bundled with gnss-citygml)" in tiles.stderr
    checked = _run([command, "validate", "t/tileset.json"], env=no_node, cwd=work)
    assert ": 3D Tiles 1.1, " in checked.stdout and ": valid (" in checked.stdout


def test_the_installed_wheel_runs_khronos_validator_when_node_is_there(
    clean_venv, user_env, tmp_path, node_dir
):
    """node on the PATH and the validator installed where the package looks by default (in
    the user's cache folder, as an earlier run installs it): it runs, named in the output."""
    shutil.copytree(node_dir, Path(user_env["HOME"]) / ".cache" / "gnss-citygml" / "node")
    command = clean_venv / "bin" / "gnss-citygml"
    import geopandas as gpd

    city = gpd.read_file(Path(gnss_citygml.__file__).parent / "data" / "city" / "footprints.gpkg")
    city.assign(ground=20.0, height=31.5).to_file(tmp_path / "heights.gpkg")
    args = ["convert", "heights.gpkg", "--ground-field", "ground", "-o", "t/tileset.json"]
    tiles = _run([command, *args], env=user_env, cwd=tmp_path)
    assert "valid (json-schema, content, gltf-structure, gltf, gltf-metadata)" in tiles.stdout
    note = f"glTF: the package's own checks and Khronos' glTF validator {GLTF_VALIDATOR_VERSION}"
    assert note in tiles.stderr
