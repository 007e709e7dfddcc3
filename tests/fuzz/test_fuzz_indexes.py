"""Fuzzing the JSON indexes the toolkit reads back: a partition's ``partition.json`` (read by
every run from a partition) and a 3D Tiles ``tileset.json`` (``gnss-citygml validate``).

Seeds: the index of the sample city's observations partitioned by the toolkit, and the tileset
it writes for three buildings (its content left out: the glTF files are fuzzed elsewhere) with
an external tileset below it. Each case is the seed's bytes mutated (:func:`mutated`), its
values replaced at any depth (:func:`json_mutated`), or a value nested up to 100,000 deep; it
must end as an index, a report, or one line of error, never another exception.
"""

from __future__ import annotations

import json
from pathlib import Path

import geopandas as gpd
import pytest
import shapely
from hypothesis import event, given
from hypothesis import strategies as st

from gnss_citygml.export import write_3dtiles
from gnss_citygml.tiling.partition import INDEX, partition_observations, read_index
from gnss_citygml.validate import Report, validate_tileset

from .conftest import mutated
from .test_fuzz_validate import json_mutated

CITY = Path(__file__).resolve().parents[2] / "examples" / "city"


@pytest.fixture(scope="module")
def partition(module_folder) -> Path:
    """The sample city's observations partitioned in tiles of 100 m."""
    path = module_folder / "partition"
    partition_observations([CITY / "observations.parquet"], path, CITY / "dem.tif", tile_size=100.0)
    return path


@pytest.fixture(scope="module")
def tileset(module_folder) -> bytes:
    """The tileset.json the toolkit writes for three buildings."""
    e, n = 529500.0, 182300.0
    buildings = gpd.GeoDataFrame(
        {"id": ["a", "b", "c"], "ground": [20.0, 21.0, 22.0], "height": [32.5, 30.0, 31.0]},
        geometry=[shapely.box(e + 20 * k, n, e + 20 * k + 10, n + 8) for k in range(3)],
        crs="EPSG:27700",
    )
    path = module_folder / "written" / "tileset.json"
    write_3dtiles(buildings, path, validate=False, title="T")
    return path.read_bytes()


@st.composite
def variants(draw, seed: bytes) -> bytes:
    """``seed`` mutated as bytes, as JSON values, or with a value nested deep."""
    kind = draw(st.sampled_from(["bytes", "values", "deep"]))
    if kind == "bytes":
        return draw(mutated(seed))
    doc = json.loads(seed)
    if kind == "values":
        return json.dumps(draw(json_mutated(doc))).encode()
    depth = draw(st.sampled_from([100, 129, 1000, 100_000]))
    key = draw(st.sampled_from(sorted(doc)))
    text = json.dumps({**doc, key: None}).replace("null", "[" * depth + "]" * depth)
    return text.encode()


@given(data=st.data())
def test_partition_index(data, partition, clean):
    seed = (partition / INDEX).read_bytes()
    mutant = data.draw(variants(seed), label="index")
    path = partition / INDEX
    try:
        path.write_bytes(mutant)
        index = clean(read_index, partition)
    finally:
        path.write_bytes(seed)
    event("read" if index is not None else "one-line error")


SUB = {
    "asset": {"version": "1.1"},
    "geometricError": 0,
    "root": {"geometricError": 0, "boundingVolume": {"sphere": [0, 0, 0, 1]}},
}


@given(data=st.data())
def test_tileset(data, tileset, module_folder, tiles3d_schema_dir, clean):
    doc = json.loads(tileset)
    doc["root"].setdefault("children", []).append(
        {
            "geometricError": 0,
            "boundingVolume": doc["root"]["boundingVolume"],
            "content": {"uri": "sub.json"},
        }
    )
    seed = json.dumps(doc, indent=1).encode()
    case = module_folder / "case"
    case.mkdir(exist_ok=True)
    (case / "sub.json").write_bytes(data.draw(variants(json.dumps(SUB).encode()), label="sub"))
    (case / "tileset.json").write_bytes(data.draw(variants(seed), label="tileset"))
    report = clean(validate_tileset, case / "tileset.json", schema_dir=tiles3d_schema_dir)
    if report is None:
        event("could not validate (one-line error)")
        return
    assert isinstance(report, Report)
    assert all("\n" not in issue.line() for issue in report.errors)
    event("valid" if report.valid else f"invalid, first error: {report.errors[0].rule}")
