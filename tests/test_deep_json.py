"""JSON nested deeper than the readers go (100,000 levels, where Python's own parser stops with a
RecursionError; 200 or 900, which it reads but a JSON Schema check or json.dumps does not): in
every JSON a user's file holds, one line of error naming the file, or, for `validate`, the
report's ``json-nesting`` error. Real files throughout."""

import json

import geopandas as gpd
import pyarrow.parquet as pq
import pytest
import shapely

from gnss_citygml.errors import InputError
from gnss_citygml.files.tables import read_table
from gnss_citygml.files.userjson import MAX_DEPTH, NotJSON, parse_json
from gnss_citygml.footprints import read_footprints
from gnss_citygml.tiling.partition import INDEX, read_index
from gnss_citygml.validate import validate_file, validate_tileset


def deep(depth: int, inner: str = "") -> str:
    return "[" * depth + inner + "]" * depth


@pytest.mark.parametrize("depth", [MAX_DEPTH + 1, 900, 100_000])
@pytest.mark.parametrize("opening", ["[", '{"a": '])
def test_the_loader_refuses_past_its_bound_whatever_python_reads(depth, opening):
    closing = "]" if opening == "[" else "}"
    with pytest.raises(NotJSON, match=f"nested deeper than {MAX_DEPTH} levels"):
        parse_json((opening * depth + "1" + closing * depth).encode())


def test_the_loader_counts_no_bracket_inside_a_string():
    quoted = json.dumps({"a": "[" * 5000 + '\\"{' * 300, "b": "\\" * 7 + "]]]"})
    text = "[" * (MAX_DEPTH - 1) + quoted + "]" * (MAX_DEPTH - 1)  # (the object: one more)
    assert parse_json(text.encode())[0] is not None
    with pytest.raises(NotJSON):
        parse_json(("[" + text + "]").encode())


@pytest.mark.parametrize("depth", [200, 100_000])
def test_validate_names_a_deep_tileset(depth, tmp_path, tiles3d_schema_dir, node_dir):
    path = tmp_path / "tileset.json"
    doc = '{"asset": {"version": "1.1", "extras": {"x": ' + deep(depth) + "}}, "
    path.write_text(doc + '"geometricError": 1, "root": {"geometricError": 0}}')
    report = validate_tileset(path, schema_dir=tiles3d_schema_dir, node_dir=node_dir)
    assert [e.rule for e in report.errors] == ["json-nesting"]


@pytest.mark.parametrize("name", ["c.city.json", "c.city.jsonl"])
@pytest.mark.parametrize("depth", [200, 100_000])
def test_validate_names_a_deep_city_model(name, depth, tmp_path):
    path = tmp_path / name
    path.write_text(
        '{"type": "CityJSON", "version": "2.0", "transform": {"scale": [1, 1, 1], '
        '"translate": [0, 0, 0]}, "CityObjects": {}, "vertices": [], "metadata": {"x": '
        + deep(depth)
        + "}}\n"
    )
    report = validate_file(path)
    assert "json-nesting" in [e.rule for e in report.errors] and not report.valid


@pytest.mark.parametrize("depth", [200, 100_000])
def test_a_deep_partition_index_is_one_line(depth, tmp_path):
    (tmp_path / INDEX).write_text('{"format": "gnss-citygml partition", "x": ' + deep(depth) + "}")
    with pytest.raises(InputError, match="cannot read partition.json") as error:
        read_index(tmp_path)
    assert "\n" not in error.value.one_line()


def parquet_with(path, key: bytes, text: str):
    """A GeoParquet file (one footprint) whose ``key`` metadata is ``text``."""
    frame = gpd.GeoDataFrame(
        {"id": ["a"]}, geometry=[shapely.box(529500, 182300, 529510, 182310)], crs="EPSG:27700"
    )
    frame.to_parquet(path)
    table = pq.read_table(path)
    pq.write_table(table.replace_schema_metadata({**table.schema.metadata, key: text}), path)
    return path


@pytest.mark.parametrize("key", [b"geo", b"pandas"])
@pytest.mark.parametrize("depth", [200, 100_000])
def test_deep_parquet_metadata_is_one_line_naming_it(key, depth, tmp_path):
    path = parquet_with(tmp_path / "f.parquet", key, '{"x": ' + deep(depth) + "}")
    with pytest.raises(InputError, match=f"its {key.decode()} metadata cannot be read") as error:
        read_footprints(path)
    assert str(path) in error.value.one_line()
    with pytest.raises(InputError, match=f"its {key.decode()} metadata cannot be read"):
        read_table(path)


def test_a_geoparquet_written_with_nan_bounds_is_read(tmp_path):
    frame = gpd.read_parquet(parquet_with(tmp_path / "f.parquet", b"other", "x"))
    geo = json.loads(pq.read_schema(tmp_path / "f.parquet").metadata[b"geo"])
    geo["columns"]["geometry"]["bbox"] = [float("nan")] * 4
    path = parquet_with(tmp_path / "g.parquet", b"geo", json.dumps(geo))
    assert len(read_footprints(path)) == len(frame) == 1


@pytest.mark.parametrize(
    "text", ['{"x": 1}', '{"columns": 5}', '{"columns": [1], "index_columns": "a"}', "[]"]
)
def test_pandas_metadata_of_another_shape_is_one_line(text, tmp_path):
    """Valid JSON that is not pandas' metadata (GeoPandas then fails with KeyError or
    AttributeError deep inside pyarrow) is the footprints' error, not an internal one."""
    path = parquet_with(tmp_path / "f.parquet", b"pandas", text)
    with pytest.raises(InputError) as error:
        read_footprints(path)
    assert str(path) in error.value.one_line()
    with pytest.raises(InputError):
        read_table(path)
