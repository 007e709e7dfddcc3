"""Footprints read in batches (a national map never whole in memory): the same buildings
table as read whole, batch after batch, from each kind of source."""

import warnings

import geopandas as gpd
import pandas as pd
import pytest
import shapely
from test_footprints import BNG, write_footprints

from gnss_citygml.errors import InputError
from gnss_citygml.files.ids import id_field
from gnss_citygml.footprints import footprint_batches, read_footprints


def whole_and_batches(path, size, **options):
    """The footprints read whole, and read ``size`` at a time (concatenated), with the
    id field each names; the warnings of both silenced."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        whole = read_footprints(path, **options)
        batches = list(footprint_batches(path, size=size, **options))
    assert all(len(b) <= size for b in batches)
    assert {id_field(b) for b in batches} == {id_field(whole)}
    together = pd.concat(batches, ignore_index=True)
    return whole, gpd.GeoDataFrame(together, geometry="geometry", crs=batches[0].crs)


def assert_same_buildings(whole, together):
    assert together["id"].tolist() == whole["id"].tolist()
    assert list(together.columns) == list(whole.columns)
    assert together.crs == whole.crs
    assert shapely.equals(together.geometry.to_numpy(), whole.geometry.to_numpy()).all()
    others = [c for c in whole.columns if c not in ("id", "geometry")]
    pd.testing.assert_frame_equal(together[others], whole[others], check_dtype=False)


@pytest.mark.parametrize("size", [1, 3, 100])
def test_a_geopackage_in_batches_is_the_geopackage(tmp_path, size):
    whole, together = whole_and_batches(write_footprints(tmp_path), size)
    assert_same_buildings(whole, together)
    assert id_field(whole) == "toid"


def test_feature_ids_in_batches_are_the_sources_own(tmp_path):
    """Without an id field the id is the feature id: a batch's features keep theirs."""
    path = tmp_path / "fids.gpkg"
    boxes = [shapely.box(500000 + 30 * i, 200000, 500020 + 30 * i, 200020) for i in range(7)]
    gpd.GeoDataFrame({"storeys": range(7)}, geometry=boxes, crs=BNG).to_file(path)
    whole, together = whole_and_batches(path, 2)
    assert_same_buildings(whole, together)
    assert together["id"].tolist() == [str(i) for i in range(1, 8)]  # GeoPackage fids


def test_geoparquet_in_batches(tmp_path):
    folder = tmp_path / "parts"
    for tile, k in (("A", 0), ("B", 1)):
        boxes = [shapely.box(500000 + 30 * i, 200000 + 50 * k, 500020 + 30 * i, 200020 + 50 * k)
                 for i in range(4)]  # fmt: skip
        frame = gpd.GeoDataFrame(
            {"toid": [f"{tile}{i}" for i in range(4)], "storeys": range(4)},
            geometry=boxes,
            crs=BNG,
        )
        (folder / f"tile={tile}").mkdir(parents=True)
        frame.to_parquet(folder / f"tile={tile}" / "part-0.parquet")
    whole, together = whole_and_batches(folder, 3)
    assert_same_buildings(whole, together)
    assert sorted(together["tile"].unique()) == ["A", "B"]


def test_mastermap_in_batches_keeps_the_buildings_only(shared_data):
    gml = shared_data / "footprints" / "mastermap-topo_3473984_0.gml"
    whole, together = whole_and_batches(gml, 50)
    assert_same_buildings(whole, together)
    assert id_field(together) == "toid" and len(together) == len(whole) > 0


def test_an_empty_source_in_batches_is_an_error(tmp_path):
    path = tmp_path / "empty.gpkg"
    gpd.GeoDataFrame({"toid": []}, geometry=[], crs=BNG).to_file(path)
    with pytest.raises(InputError, match="the layer has no features"):
        list(footprint_batches(path, size=10))


def test_geoparquet_in_geoarrows_own_encoding_in_batches(tmp_path):
    """GeoArrow's native encodings (which GeoPandas writes on request) are read as WKB is."""
    boxes = [shapely.box(500000 + 30 * i, 200000, 500020 + 30 * i, 200020) for i in range(5)]
    frame = gpd.GeoDataFrame({"toid": [f"b{i}" for i in range(5)]}, geometry=boxes, crs=BNG)
    frame.to_parquet(tmp_path / "native.parquet", geometry_encoding="geoarrow")
    whole, together = whole_and_batches(tmp_path / "native.parquet", 2)
    assert_same_buildings(whole, together)


def test_a_missing_id_in_a_later_batch_is_named_by_its_row_in_the_source(tmp_path):
    boxes = [shapely.box(500000 + 30 * i, 200000, 500020 + 30 * i, 200020) for i in range(5)]
    frame = gpd.GeoDataFrame({"toid": ["a", "b", "c", None, "e"]}, geometry=boxes, crs=BNG)
    frame.to_file(tmp_path / "missing.gpkg")
    with pytest.raises(InputError, match=r"without an id .*: rows 3 \(") as whole:
        read_footprints(tmp_path / "missing.gpkg")
    with pytest.raises(InputError) as batches:
        list(footprint_batches(tmp_path / "missing.gpkg", size=2))
    assert str(batches.value) == str(whole.value)


def test_a_layer_without_geometry_is_named_whole_or_in_batches(tmp_path):
    """A table (a CSV of ids) is no footprint layer: its features are named, never a
    traceback."""
    (tmp_path / "ids.csv").write_text("toid\na\nb\n")
    for read in (read_footprints, lambda path: list(footprint_batches(path, size=2))):
        with pytest.raises(InputError, match=r"2 feature\(s\) are not polygons \(missing\): a, b"):
            read(tmp_path / "ids.csv")
