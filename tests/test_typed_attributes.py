"""Typed attributes: CityJSON written with the toolkit's Extension (+height, ...), validated
against it offline, a file that breaks it invalid, cjio reading it; plain attributes stay the
default."""

import json

import numpy as np
import pandas as pd
import pytest
from test_cityjson import NOT_CONVERGED, SCHEMAS, cjio_info, heights_table, official
from test_cli import run

from gnss_citygml.contracts import EXTENSION, load
from gnss_citygml.errors import InputError
from gnss_citygml.export import write_cityjson, write_cityjsonseq
from gnss_citygml.validate import validate_file

EXT = load(EXTENSION)
DECLARED = {EXT["name"]: {"url": EXT["url"], "version": EXT["version"]}}


def typed_model(tmp_path, **columns):
    """A CityJSON file written with typed attributes, and its JSON."""
    frame = heights_table([NOT_CONVERGED]).assign(**{"source": "OS", **columns})
    path = tmp_path / "t.city.json"
    out = write_cityjson(frame, path, date="2024-05-01", overwrite=True, typed_attributes=True)
    return out, json.loads(path.read_text())


def test_cityjson_with_typed_attributes_is_valid(tmp_path, repo_data):
    out, model = typed_model(tmp_path)
    assert out.report.valid and "extension" in out.report.checks
    assert model["extensions"] == DECLARED
    assert list(model)[:3] == ["type", "version", "extensions"]
    assert model["CityObjects"]["osgb1000005116342"]["attributes"] == {
        "measuredHeight": 12.5,
        "creationDate": "2024-05-01",
        "+ground": 21.25,
        "+height": 33.75,
        "+height_lower": 32.25,
        "+height_upper": 35.75,
        "+n_signals": 250,
        "+converged": True,
        "+method": "4PL-B",
        "+status": "ok",
        "source": "OS",  # the footprints' own attribute stays plain
    }
    assert list(official(repo_data).iter_errors(model)) == []
    report = validate_file(tmp_path / "t.city.json", schema_dir=repo_data / SCHEMAS)
    assert report.valid and {"extension", "json-schema"} <= set(report.checks)


def test_cityjsonseq_with_typed_attributes_is_valid(tmp_path):
    path = tmp_path / "t.city.jsonl"
    out = write_cityjsonseq(heights_table(), path, typed_attributes=True)
    assert out.report.valid and "extension" in out.report.checks
    header, *features = [json.loads(line) for line in path.read_text().splitlines()]
    assert header["extensions"] == DECLARED
    assert all("+height" in f["CityObjects"][f["id"]]["attributes"] for f in features)


def test_plain_attributes_stay_the_default(tmp_path):
    out = write_cityjson(heights_table(), tmp_path / "p.city.json")
    model = json.loads((tmp_path / "p.city.json").read_text())
    assert "extensions" not in model and "extension" not in out.report.checks
    names = {n for obj in model["CityObjects"].values() for n in obj.get("attributes", {})}
    assert "height" in names and not any(n.startswith("+") for n in names)


def test_values_take_the_extensions_types(tmp_path):
    """Counts with gaps (floats after a join) are written as integers, flags in text as
    booleans, numbers in text as numbers; a value of another type is an error."""
    n = len(heights_table([NOT_CONVERGED]))
    _, model = typed_model(
        tmp_path,
        n_signals=[250.0] * (n - 2) + [np.nan, 4.0],
        converged=["yes"] * (n - 1) + ["no"],
        c=["31.5"] * n,
    )
    objects = model["CityObjects"]
    attributes = objects["courtyard"]["attributes"]
    assert attributes["+n_signals"] == 250 and isinstance(attributes["+n_signals"], int)
    assert attributes["+converged"] is True and attributes["+c"] == 31.5
    assert "+n_signals" not in objects["12/B"]["attributes"]  # missing: left out
    with pytest.raises(InputError, match=r"column 'n_signals' is not a whole number as the "):
        typed_model(tmp_path, n_signals=2.5)
    with pytest.raises(InputError, match=r"column 'relative_height' is not a number .*courtyard"):
        typed_model(tmp_path, relative_height="low")
    with pytest.raises(InputError, match=r"'n_signals' is not a whole number .* is \(0 or more\)"):
        typed_model(tmp_path, n_signals=-1)  # was an invalid output, "please report this bug"
    big = 2**60 + 1  # beyond a float's whole numbers: written exactly
    _, model = typed_model(tmp_path, iterations=np.int64(big))
    assert model["CityObjects"]["courtyard"]["attributes"]["+iterations"] == big
    assert not list(tmp_path.glob("*.part*"))


@pytest.mark.parametrize("kind", [np.uint64, np.uint32])
def test_an_unsigned_count_is_written_exactly(tmp_path, kind):
    """A GeoParquet's unsigned counts (uint64 up to 2**64 - 1, beyond int64; uint32): their
    own values, not an internal error (found at the command line: "cannot safely cast
    non-equivalent uint64 to int64")."""
    n = len(heights_table([NOT_CONVERGED]))
    top = int(np.iinfo(kind).max)
    counts = np.array([top] + [7] * (n - 1), dtype=kind)
    _, model = typed_model(tmp_path, n_signals=counts, iterations=counts)
    attributes = [o["attributes"] for o in model["CityObjects"].values() if "attributes" in o]
    written = sorted({a["+n_signals"] for a in attributes if "+n_signals" in a})
    assert top in written and 7 in written
    assert all(isinstance(a["+iterations"], int) for a in attributes if "+iterations" in a)


def _tampered(tmp_path, change) -> dict:
    _, model = typed_model(tmp_path)
    change(model["CityObjects"]["courtyard"]["attributes"], model)
    path = tmp_path / "tampered.city.json"
    path.write_text(json.dumps(model))
    report = validate_file(path)
    return {"valid": report.valid, "errors": report.errors, "notes": report.notes}


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda a, m: a.update({"+n_signals": "many"}), "'+n_signals': 'many' is not of type"),
        (lambda a, m: a.update({"+n_signals": -3}), "'+n_signals': -3 is less than the minimum"),
        (lambda a, m: a.update({"+converged": "yes"}), "'+converged': 'yes' is not of type"),
        (lambda a, m: a.update({"+height": None}), "'+height': None is not of type 'number'"),
        (lambda a, m: a.update({"+colour": "red"}), "'+colour' of a Building is defined by none"),
    ],
)
def test_attributes_that_break_the_extension_are_invalid(tmp_path, change, message):
    result = _tampered(tmp_path, change)
    assert not result["valid"]
    ((issue),) = result["errors"]
    assert (issue.object_id, issue.rule) == ("courtyard", "extension")
    assert message in issue.message


def test_another_extension_is_noted_not_checked(tmp_path):
    def declare(attributes, model):
        attributes["+noise"] = "loud"
        model["extensions"]["Noise"] = {
            "url": "https://example.org/noise.ext.json",
            "version": "2.0",
        }

    result = _tampered(tmp_path, declare)
    assert result["valid"] and any("'Noise' not checked" in n for n in result["notes"])

    def other_version(attributes, model):
        model["extensions"][EXT["name"]]["version"] = "0.9"
        attributes["+n_signals"] = "many"

    result = _tampered(tmp_path, other_version)
    assert result["valid"] and any("'GnssCityGML' not checked" in n for n in result["notes"])


def test_the_command_line(tmp_path, capsys):
    source = tmp_path / "heights.gpkg"
    heights_table([NOT_CONVERGED]).to_file(source, layer="heights", driver="GPKG")
    out = tmp_path / "city.city.jsonl"
    code, stdout, err = run(["convert", str(source), "-o", str(out), "--typed-attributes"], capsys)
    assert code == 0 and "valid (json, structure, geometry, extension)" in stdout, err
    header, feature = [json.loads(line) for line in out.read_text().splitlines()[:2]]
    assert header["extensions"] == DECLARED
    assert feature["CityObjects"][feature["id"]]["attributes"]["+n_signals"] == 250

    lines = out.read_text().splitlines()
    lines[1] = lines[1].replace('"+n_signals":250', '"+n_signals":250.5')
    out.write_text("\n".join(lines) + "\n")
    code, stdout, _ = run(["validate", str(out)], capsys)
    assert code == 1
    assert "\textension\tline 2: attribute '+n_signals': 250.5 is not of type 'integer'" in stdout

    code, stdout, err = run(["convert", str(source), "-o", "-", "--typed-attributes"], capsys)
    header, feature = [json.loads(line) for line in stdout.splitlines()[:2]]
    assert code == 0 and header["extensions"] == DECLARED and "extension" in err
    assert feature["CityObjects"][feature["id"]]["attributes"]["+converged"] is True

    gml = tmp_path / "city.gml"
    code, _, err = run(["convert", str(source), "-o", str(gml), "--typed-attributes"], capsys)
    assert code == 2 and "typed attributes are for CityJSON" in err
    assert not gml.exists()


def test_export_of_a_heights_table_with_gaps(tmp_path, capsys):
    """``export`` joins a CSV heights table (a footprint without a row gets gaps): the counts
    are integers and the flags booleans all the same."""
    frame = heights_table()
    frame[["id", "geometry", "ground"]].to_file(tmp_path / "fp.gpkg", driver="GPKG")
    table = pd.DataFrame(frame.drop(columns=["geometry", "ground"])).iloc[1:]
    table.to_csv(tmp_path / "h.csv", index=False)
    out = tmp_path / "city.city.json"
    args = ["export", str(tmp_path / "h.csv"), "--footprints", str(tmp_path / "fp.gpkg")]
    code, stdout, err = run([*args, "-o", str(out), "--typed-attributes"], capsys)
    assert code == 0 and "extension" in stdout, err
    attributes = json.loads(out.read_text())["CityObjects"]["courtyard"]["attributes"]
    assert attributes["+n_signals"] == 250 and attributes["+converged"] is True


@pytest.mark.parametrize("writer", [write_cityjson, write_cityjsonseq])
def test_cjio_reads_typed_attributes(tmp_path, writer):
    """cjio (CityJSON's own command line) reads the files: it lists the Extension and the
    attributes without fetching the Extension (cjio 0.10 has no validation of its own)."""
    stream = writer is write_cityjsonseq
    path = tmp_path / ("t.city.jsonl" if stream else "t.city.json")
    writer(heights_table(), path, typed_attributes=True)
    text = cjio_info(path, stream)
    assert f"Extensions = ['{EXT['name']}']" in text.splitlines()
    assert "'+height'" in text and "'+n_signals'" in text
