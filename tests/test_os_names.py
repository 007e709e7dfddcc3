"""Text that XML or UTF-8 cannot hold (issue 45): a title with control characters (CityGML
writes U+FFFD), text options with a byte of another encoding (refused, naming the option),
and files named in Latin-1, which the OS and Python take but GDAL, Arrow and libxml2 do not
(read through a link; named in the provenance as ``\\xe9``). Real files, the command line in
a subprocess (its arguments as bytes)."""

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import geopandas as gpd
import pyogrio
import pytest
import shapely
from lxml import etree

from gnss_citygml.errors import InputError
from gnss_citygml.export import write_citygml, write_cityjson, write_cityjsonseq
from gnss_citygml.files.provenance import read_provenance
from gnss_citygml.terrain import sample_ground

CITY = Path(__file__).resolve().parents[1] / "examples" / "city"
LATIN1 = os.fsdecode(b"caf\xe9")  # as Python holds a Latin-1 byte from the OS: "caf\udce9"


def cli(*args, grid=()):
    """The command in a subprocess: exit code and stderr."""
    run = subprocess.run(
        [sys.executable, "-m", "gnss_citygml", *map(str, args), *grid], capture_output=True
    )
    err = run.stderr.decode("utf-8", "replace")
    assert "internal error" not in err and "Traceback" not in err, err
    return run.returncode, err


def footprints(path):
    """Two footprints with a height and a ground, as ``path`` (written under a plain name
    first: GDAL cannot write a name in Latin-1)."""
    boxes = [shapely.box(529500 + 20 * k, 182300, 529510 + 20 * k, 182308) for k in range(2)]
    frame = gpd.GeoDataFrame(
        {"id": ["a", "b"], "height": [30.0, 31.0], "ground": [10.0, 10.0]},
        geometry=boxes,
        crs="EPSG:27700",
    )
    frame.to_file(path.parent / "plain.gpkg")
    os.replace(path.parent / "plain.gpkg", path)
    return path


def test_a_title_with_control_characters(tmp_path):
    """CityGML holds U+FFFD in their place, with a warning; CityJSON keeps them."""
    source = footprints(tmp_path / "f.gpkg")
    title = "a\x01b\x1b[31m"
    gml, cj = tmp_path / "m.gml", tmp_path / "m.city.json"
    warned = []
    for out in (gml, cj):
        code, err = cli("convert", source, "--ground-field", "ground", "--title", title, "-o", out)
        assert code == 0, err
        warned.append("warning: the title 'a\\x01b\\x1b[31m' has characters that XML" in err)
    assert warned == [True, False]
    name = etree.parse(gml).findtext("{http://www.opengis.net/gml}name")
    assert name == "a\ufffdb\ufffd[31m"
    assert json.loads(cj.read_text())["metadata"]["title"] == title


@pytest.mark.parametrize("option", ["--title", "--layer", "--id-field", "--ground-field"])
def test_a_text_option_that_is_not_utf8_is_refused_by_name(tmp_path, option):
    source = footprints(tmp_path / "f.gpkg")
    args = ["convert", source, "-o", tmp_path / "m.gml", "--ground-field", "ground"]
    code, err = cli(*args, option, LATIN1)
    assert code == 2 and f"Invalid value for '{option}'" in err, err
    assert "'caf\\xe9' is not UTF-8 text" in err
    assert not (tmp_path / "m.gml").exists()


@pytest.mark.parametrize("writer", [write_citygml, write_cityjson, write_cityjsonseq])
def test_the_writers_refuse_a_title_utf8_cannot_hold(tmp_path, writer):
    frame = gpd.read_file(footprints(tmp_path / "f.gpkg"))
    with pytest.raises(InputError, match="the title 'caf\\\\xe9' is not UTF-8 text"):
        writer(frame, tmp_path / "m.gml", title=LATIN1)
    assert not list(tmp_path.glob("m.*")) and not list(tmp_path.glob(".m.*"))


@pytest.fixture
def latin1_inputs(tmp_path):
    """The sample city's inputs in a folder named in Latin-1, each named so too, and its DEM
    also as a folder of one tile so named."""
    folder = tmp_path / LATIN1
    folder.mkdir()
    names = {"observations.parquet": "obs", "footprints.gpkg": "fp", "dem.tif": "dem"}
    paths = {}
    for name, stem in names.items():
        paths[stem] = folder / f"{stem}{LATIN1}{Path(name).suffix}"
        shutil.copy(CITY / name, paths[stem])
    paths["tiles"] = folder / f"tiles{LATIN1}"
    paths["tiles"].mkdir()
    shutil.copy(CITY / "dem.tif", paths["tiles"] / f"t{LATIN1}.tif")
    return paths


def test_inputs_named_in_latin1_are_read_and_named(latin1_inputs, tmp_path, grid_args):
    """estimate (the DEM a file, then a folder of tiles), export and convert from files named
    in Latin-1 into a city model so named; validate and info read it; the provenance names
    each input with its byte as \\xe9."""
    obs, fp, dem, tiles = (latin1_inputs[k] for k in ("obs", "fp", "dem", "tiles"))
    for k, given in enumerate((dem, tiles)):
        out = tmp_path / f"h{k}.gpkg"
        code, err = cli("estimate", obs, fp, "--dem", given, "-o", out, grid=grid_args)
        assert code == 0, err
        names = [i["name"] for i in read_provenance(out)["inputs"]]
        dem_name = "demcaf\\xe9.tif" if k == 0 else "tilescaf\\xe9/"
        assert names == ["obscaf\\xe9.parquet", "fpcaf\\xe9.gpkg", dem_name]
    heights = pyogrio.read_dataframe(out, layer="heights", read_geometry=False)
    csv = obs.parent / f"h{LATIN1}.csv"
    heights.to_csv(csv, index=False)
    for suffix in (".gml", ".city.json"):
        model = obs.parent / f"m{LATIN1}{suffix}"
        code, err = cli("export", csv, "--footprints", fp, "--dem", tiles, "-o", model)
        assert code == 0, err
        assert cli("validate", model)[0] == 0
        assert read_provenance(model)["inputs"][0]["name"] == "hcaf\\xe9.csv"
        code, err = cli("info", model)
        assert code == 0, err


@pytest.mark.parametrize(
    ("name", "recorded"), [("f\x01.gpkg", "f\x01.gpkg"), (f"f{LATIN1}.gpkg", "fcaf\\xe9.gpkg")]
)
@pytest.mark.parametrize("suffix", [".gml", ".city.json", ".city.jsonl"])
def test_convert_footprints_named_with_a_control_character_or_in_latin1(
    tmp_path, name, recorded, suffix
):
    """The name goes into the model's provenance (in CityGML's description line, a control
    character as U+FFFD: the JSON record after it keeps it); the model validates."""
    source = footprints(tmp_path / name)
    out = tmp_path / f"m{suffix}"
    code, err = cli("convert", source, "--ground-field", "ground", "-o", out)
    assert code == 0, err
    assert read_provenance(out)["inputs"][0]["name"] == recorded
    assert cli("validate", out)[0] == 0


def test_an_output_gdal_writes_named_in_latin1_is_refused(latin1_inputs, tmp_path, grid_args):
    out = tmp_path / f"h{LATIN1}.gpkg"
    obs, fp, dem = (latin1_inputs[k] for k in ("obs", "fp", "dem"))
    code, err = cli("estimate", obs, fp, "--dem", dem, "-o", out, grid=grid_args)
    assert code == 2 and "the output's name is not UTF-8 text" in err and "hcaf\\xe9.gpkg" in err
    assert not list(tmp_path.glob("*.gpkg"))


def test_a_dem_named_in_latin1_is_named_so_in_messages(latin1_inputs):
    """Not by the link it is read through."""
    dem = latin1_inputs["dem"]
    with pytest.raises(InputError, match="off the DEM") as caught:
        sample_ground(dem, [0.0], [0.0])
    assert caught.value.where == str(dem)


@pytest.mark.parametrize("command", ["update", "partition"])
def test_a_map_or_folder_gdal_or_arrow_write_named_in_latin1_is_refused(
    latin1_inputs, tmp_path, grid_args, command
):
    """update writes its map with GDAL, partition its folder's files with Arrow: a name in
    Latin-1 is refused before any work (the map untouched, no folder)."""
    obs, fp, dem = (latin1_inputs[k] for k in ("obs", "fp", "dem"))
    before = fp.read_bytes()
    out = tmp_path / f"parts{LATIN1}"
    args = {
        "update": ["update", fp, "--observations", obs, "--dem", dem],
        "partition": ["partition", obs, "--dem", dem, "-o", out],
    }[command]
    code, err = cli(*args, grid=grid_args)
    what = {"update": "map", "partition": "partition folder"}[command]
    assert code == 2 and f"the {what}'s name is not UTF-8 text" in err, err
    assert fp.read_bytes() == before and not out.exists()
