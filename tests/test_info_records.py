"""`gnss-citygml info` on records it did not write: of the wrong shape, nested 100,000 deep, with
numbers JSON cannot print, with line ends and terminal escapes in their values, in a page made
to slow the search down. Each is one line of error or a record printed safely, in every
container (GeoPackage, CityJSON, CityJSONSeq, CityGML, 3D Tiles, report page)."""

import json
import time

import pytest
from fuzz.records import CONTAINERS, holding
from test_cli import run

from gnss_citygml.errors import InputError
from gnss_citygml.files.provenance import read_provenance

DEEP = "[" * 100_000 + "]" * 100_000


def good(**changes):
    """A record as the toolkit writes it, with ``changes`` (an input's fields: ``input_*``)."""
    item = {"role": "source", "name": "h.gpkg", "bytes": 1234, "sha256": "ab" * 32}
    item.update({k[6:]: v for k, v in changes.items() if k.startswith("input_")})
    record = {
        "software": "gnss-citygml 1.0",
        "created": "2026-11-27T12:00:00Z",
        "command": "convert",
        "settings": {"title": "T"},
        "inputs": [item],
    }
    record.update({k: v for k, v in changes.items() if not k.startswith("input_")})
    return json.dumps(record)


def one_error(args, capsys):
    """The exit code and stderr of ``info``, checked to be one error line, no traceback."""
    code, out, err = run(["info", *args], capsys)
    assert code == 2, (out, err)
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), err
    assert "internal error" not in err
    return lines[0]


WRONG_SHAPES = [
    good(inputs=None),
    good(inputs="june.parquet"),
    good(inputs=[1, 2]),
    good(inputs={"role": "source"}),
    good(input_bytes="1234"),
    good(input_bytes=None),
    good(input_bytes=-1),
    good(input_bytes=1.5),
    good(input_bytes=10**30),
    good(input_bytes=True),
    good(input_role=["source"]),
    good(input_sha256=12),
    good(input_name={"a": 1}),
    good(software=7),
    good(command=[]),
    good(created={"when": "now"}),
    good(settings="fast"),
    good(settings=[1]),
]


@pytest.mark.parametrize("text", WRONG_SHAPES)
@pytest.mark.parametrize("name", ["c.city.json", "h.gpkg"])
def test_a_record_of_the_wrong_shape_is_one_line_naming_the_field(name, text, tmp_path, capsys):
    path = holding(tmp_path, name, text)
    with pytest.raises(InputError, match="the provenance record's"):
        read_provenance(path)
    line = one_error([str(path)], capsys)
    assert str(path) in line


@pytest.mark.parametrize(
    "text",
    [
        '{"asset": 5}',
        '{"asset": "1.1"}',
        '{"asset": [1]}',
        '{"asset": {"extras": 3}}',
        '{"metadata": [1]}',
        "[1, 2]",
        "12",
    ],
)
def test_a_tileset_or_model_of_the_wrong_shape_holds_no_record(text, tmp_path, capsys):
    path = tmp_path / "tileset.json"
    path.write_text(text)
    assert "no provenance record in it" in one_error([str(path)], capsys)


def test_missing_fields_are_shown_as_missing(tmp_path, capsys):
    path = holding(tmp_path, "c.city.json", '{"command": "convert", "inputs": [{"role": "x"}]}')
    code, out, err = run(["info", str(path)], capsys)
    assert code == 0, err
    assert "software: -" in out and "command:  convert" in out and "x" in out


@pytest.mark.parametrize("name", CONTAINERS)
def test_a_record_nested_100000_deep_is_one_line_naming_the_file(name, tmp_path, capsys):
    path = holding(tmp_path, name, DEEP)
    line = one_error([str(path)], capsys)
    assert "nested deeper than 128 levels" in line and str(path) in line


@pytest.mark.parametrize("depth", [129, 900])
def test_a_record_nested_past_the_bound_is_refused_before_python_fails(depth, tmp_path, capsys):
    text = good(settings=json.loads("[" * depth + "]" * depth))
    line = one_error([str(holding(tmp_path, "c.city.json", text))], capsys)
    assert "nested deeper than 128 levels" in line


def test_a_seq_whose_first_line_is_deep_is_one_line(tmp_path, capsys):
    path = tmp_path / "c.city.jsonl"
    path.write_text('{"type": "CityJSON", "metadata": {}, "x": ' + DEEP + "}\n{}\n")
    assert "nested deeper than 128 levels" in one_error([str(path)], capsys)


@pytest.mark.parametrize("number", ["1e999", "-1e999", "1e400"])
def test_info_json_prints_strict_json_whatever_the_numbers(number, tmp_path, capsys):
    text = good().replace('"title": "T"', f'"title": "T", "tolerance": {number}')
    path = holding(tmp_path, "c.city.json", text)
    code, out, err = run(["info", str(path), "--json"], capsys)
    assert code == 0, err

    def refuse(name):
        raise AssertionError(f"{name} printed")

    record = json.loads(out, parse_constant=refuse)
    assert record["settings"]["tolerance"] in ("inf", "-inf")
    code, out, err = run(["info", str(path)], capsys)
    assert code == 0 and "Infinity" not in out and "inf" in out


@pytest.mark.parametrize("constant", ["NaN", "Infinity", "-Infinity"])
def test_a_record_with_nan_is_not_json(constant, tmp_path, capsys):
    text = good().replace('"title": "T"', f'"title": {constant}')
    line = one_error([str(holding(tmp_path, "report.html", text)), "--json"], capsys)
    assert f"{constant.lstrip('-')} is not a JSON number" in line


FORGED = ["\n error: forged", "\x1b[31mred", "a\rerror: over", "\u202egnp.", "\x00\x85"]


@pytest.mark.parametrize("name", ["c.city.json", "report.html", "h.gpkg"])
@pytest.mark.parametrize("value", FORGED)
def test_every_value_info_prints_is_escaped(name, value, tmp_path, capsys):
    text = good(
        software=value,
        created=value,
        command=value,
        settings={value: value},
        input_role=value,
        input_name=value,
        input_sha256=value,
    )
    path = holding(tmp_path, name, text)
    code, out, err = run(["info", str(path)], capsys)
    assert code == 0, err
    forged = "\x1b\r\x00\x85\u202e"
    assert not any(c in out for c in forged), out
    assert not any(line.lstrip().startswith("error:") for line in out.splitlines()), out
    assert len(out.splitlines()) == 7  # software, created, command, inputs: and 1, settings: and 1


def test_a_long_sha256_is_printed_whole_and_other_values_cut(tmp_path, capsys):
    path = holding(tmp_path, "c.city.json", good(input_name="n" * 5000))
    code, out, err = run(["info", str(path)], capsys)
    assert code == 0, err
    assert "ab" * 32 in out and "(5000 characters)" in out and "n" * 100 not in out


@pytest.mark.parametrize(
    "page",
    [
        b'<script type="application/json" id="provenance">' * 22_000,
        b'<script type="application/json" id="provenance">{' + b"</scrip" * 150_000,
        b"<!doctype html><p>" + b"<script " * 130_000,
    ],
)
def test_a_hostile_page_is_read_in_linear_time(page, tmp_path, capsys):
    path = tmp_path / "report.html"
    path.write_bytes(page)
    assert len(page) > 1_000_000
    start = time.perf_counter()
    line = one_error([str(path)], capsys)
    assert time.perf_counter() - start < 5  # (a hang guard: quadratic took minutes)
    assert str(path) in line


def test_a_page_whose_record_comes_after_its_head_holds_none(tmp_path, capsys):
    path = tmp_path / "report.html"
    figures = b"<img src='data:image/png;base64," + b"A" * 5_000_000 + b"'>"
    script = b'<script type="application/json" id="provenance">' + good().encode() + b"</script>"
    path.write_bytes(b"<html><body>" + figures + script + b"</body></html>")
    assert "no provenance record in it" in one_error([str(path)], capsys)
