"""Provenance: every output says with what and from what it was made, and `info` reads it back."""

import hashlib
import json

import pytest
from test_cli import run
from test_outputs import CITY, estimate, heights_gpkg

import gnss_citygml
from gnss_citygml.errors import InputError
from gnss_citygml.files.provenance import digest_input, read_provenance


def sha256(path):
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture(scope="module")
def estimated(grid_args, tmp_path_factory):
    """The sample city estimated into a GeoPackage, with its report."""
    folder = tmp_path_factory.mktemp("made")
    args = estimate(folder, grid_args, "heights.gpkg", "--report", str(folder / "report"))
    with pytest.raises(SystemExit) as done:
        gnss_citygml.cli.main(args)
    assert done.value.code == 0
    return folder


def test_the_heights_and_the_report_name_the_run_and_its_inputs(estimated):
    for output in (estimated / "heights.gpkg", estimated / "report" / "report.html"):
        record = read_provenance(output)
        assert record["command"] == "estimate"
        assert record["software"].startswith("gnss-citygml ")
        by_role = {i["role"]: i for i in record["inputs"]}
        assert set(by_role) == {"observations", "footprints", "dem"}
        assert by_role["dem"]["sha256"] == sha256(CITY / "dem.tif")
        assert by_role["observations"]["name"] == "observations.parquet"
        assert record["settings"]["estimator"]["method"] == "4PL-B"
        caps = {k: record["settings"]["estimator"][k] for k in ("max_iter", "fit_max_iter")}
        assert caps == {"max_iter": 30, "fit_max_iter": 200}  # the heights can be checked


def test_the_layer_description_says_it_in_one_line(estimated):
    import pyogrio

    info = pyogrio.read_info(estimated / "heights.gpkg", layer="heights")
    assert info["layer_metadata"]["DESCRIPTION"].startswith("made by gnss-citygml")


@pytest.mark.parametrize("name", ["c.city.json", "c.city.jsonl", "c.gml", "t/tileset.json"])
def test_every_city_model_carries_it_and_info_prints_it(name, tmp_path, capsys):
    source = heights_gpkg(tmp_path)
    out = tmp_path / name
    extra = ["--no-validate"] if name.endswith("tileset.json") else []
    code, _, err = run(["convert", str(source), "-o", str(out), "--title", "T", *extra], capsys)
    assert code == 0, err
    record = read_provenance(out)
    assert record["command"] == "convert"
    assert record["inputs"] == [{"role": "source", **digest_input(source)}]
    assert record["inputs"][0]["sha256"] == sha256(source)
    code, text, err = run(["info", str(out)], capsys)
    assert code == 0, err
    assert "command:  convert" in text and sha256(source) in text
    code, text, _ = run(["info", str(out), "--json"], capsys)
    assert json.loads(text) == record


def test_a_file_without_a_record_is_an_error_naming_it(tmp_path, capsys):
    plain = tmp_path / "plain.city.json"
    plain.write_text('{"type": "CityJSON", "version": "2.0", "metadata": {}}')
    with pytest.raises(InputError, match="no provenance record"):
        read_provenance(plain)
    code, _, err = run(["info", str(plain)], capsys)
    assert code == 2 and "no provenance record in it" in err and str(plain) in err


def test_a_folder_is_digested_by_its_files_and_a_partition_by_its_index(tmp_path):
    (tmp_path / "dem").mkdir()
    (tmp_path / "dem" / "a.tif").write_bytes(b"a")
    first = digest_input(tmp_path / "dem")
    (tmp_path / "dem" / "a.tif").write_bytes(b"b")
    assert digest_input(tmp_path / "dem")["sha256"] != first["sha256"]
    (tmp_path / "dem" / "partition.json").write_text("{}")
    assert digest_input(tmp_path / "dem")["sha256"] == sha256(tmp_path / "dem" / "partition.json")


@pytest.mark.parametrize(
    "name, text, message",
    [
        ("bad.gpkg", "junk", "not a GeoPackage"),
        ("bad.gml", "<x>", "cannot read it"),
        ("bad.city.json", "{", "cannot read it"),
    ],
)
def test_a_damaged_file_is_one_line_naming_it(name, text, message, tmp_path, capsys):
    (tmp_path / name).write_text(text)
    code, _, err = run(["info", str(tmp_path / name)], capsys)
    assert code == 2 and message in err and name in err and "internal error" not in err
