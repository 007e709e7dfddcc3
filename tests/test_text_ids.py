"""Ids read from a CSV table are text, as the source stores them (issue 45): pandas would read
``008`` as the number 8 (building ``8`` then gets ``008``'s height), ``1e3`` as 1000.0 and
``NA`` or ``null`` as missing. Every reader of ids in tables (export's heights, the truth of
``compare`` and the report, the observations' receivers, the intersections' buildings) reads
them as text."""

import json

import geopandas as gpd
import pandas as pd
import pytest
import shapely
from test_cli import run

from gnss_citygml.compare import check_truth
from gnss_citygml.files.tables import read_table
from gnss_citygml.observations import read_observations

#: Ids a number parser or pandas' missing values would change, each with its own height.
IDS = ["8", "008", "0012", "12", "1e3", "1000", "NA", "null", "N/A", "nan", " 5", "5", "5 "]


def footprints(path, name="id"):
    boxes = [shapely.box(529500 + 20 * k, 182300, 529510 + 20 * k, 182308) for k in range(13)]
    gpd.GeoDataFrame({name: IDS}, geometry=boxes, crs="EPSG:27700").to_file(path)
    return path


def heights_csv(path, name="id"):
    table = pd.DataFrame({name: IDS, "height": [20.0 + k for k in range(len(IDS))], "ground": 10.0})
    table.to_csv(path, index=False)
    return {i: 20.0 + k for k, i in enumerate(IDS)}


def model_heights(path):
    """Each building's absolute roof height in a CityJSON file (its highest vertex)."""
    model = json.loads(path.read_text())
    scale, shift = model["transform"]["scale"][2], model["transform"]["translate"][2]
    out = {}
    for key, obj in model["CityObjects"].items():
        rings = obj["geometry"][0]["boundaries"]
        zs = [model["vertices"][v][2] for shell in rings for face in shell for ring in face
              for v in ring]  # fmt: skip
        out[key] = round(max(zs) * scale + shift, 3)
    return out


@pytest.mark.parametrize("name", ["id", "ref"])
def test_export_joins_ids_as_text(tmp_path, capsys, name):
    """Each footprint gets its own row's height: `8` not `008`'s, `NA` its own."""
    gpkg = footprints(tmp_path / "f.gpkg", name)
    want = heights_csv(tmp_path / "h.csv", name)
    out = tmp_path / "city.city.json"
    extra = [] if name == "id" else ["--id-field", name]
    args = ["export", str(tmp_path / "h.csv"), "--footprints", str(gpkg), "-o", str(out)]
    code, _, err = run([*args, *extra], capsys)
    assert code == 0, err
    assert model_heights(out) == want


@pytest.mark.parametrize("column", ["id", "receiver", "building", "toid"])
def test_read_table_keeps_ids_as_text(tmp_path, column):
    path = tmp_path / "t.csv"
    pd.DataFrame({column: IDS, "height": range(len(IDS))}).to_csv(path, index=False)
    text = (column,) if column == "toid" else ()
    table = read_table(path, text=text)
    assert table[column].tolist() == IDS
    assert pd.api.types.is_numeric_dtype(table["height"])


def test_an_empty_id_is_missing_and_other_columns_keep_their_missing_values(tmp_path):
    path = tmp_path / "t.csv"
    path.write_text("id,height,status\n,1.5,NA\nNA,,ok\n")
    table = read_table(path)
    assert table["id"].isna().tolist() == [True, False] and table["id"][1] == "NA"
    assert table["height"].isna().tolist() == [False, True]
    assert table["status"].isna().tolist() == [True, False]


def test_receivers_007_and_7_are_two_receivers(tmp_path):
    """Two phones named `007` and `7` seeing one satellite at one time: two signals, not a
    repeat of one."""
    row = "2020-02-11T08:50:00Z,{},51.5,-0.1,,G,5,120.0,30.0,40.0,\n"
    path = tmp_path / "obs.csv"
    path.write_text(
        "time_utc,receiver,lat,lon,h,constellation,svid,azimuth,elevation,cn0,position_sd\n"
        + row.format("007")
        + row.format("7")
        + row.format("NA")
    )
    assert sorted(read_observations(path)["receiver"]) == ["007", "7", "NA"]


def test_a_height_for_008_is_not_building_8s(tmp_path, capsys):
    """The footprints hold `8` and `008`, the table only `008`: `8` is left without a height."""
    gpkg = footprints(tmp_path / "f.gpkg")
    (tmp_path / "h.csv").write_text("id,height,ground\n008,30.0,10.0\n")
    out = tmp_path / "city.city.json"
    args = ["export", str(tmp_path / "h.csv"), "--footprints", str(gpkg), "-o", str(out)]
    code, _, err = run(args, capsys)
    assert code == 0, err
    assert model_heights(out) == {"008": 30.0}


def test_a_heights_row_without_an_id_is_refused(tmp_path, capsys):
    gpkg = footprints(tmp_path / "f.gpkg")
    (tmp_path / "h.csv").write_text("id,height,ground\n008,30.0,10.0\n,31.0,10.0\n")
    args = ["export", str(tmp_path / "h.csv"), "--footprints", str(gpkg)]
    code, _, err = run([*args, "-o", str(tmp_path / "c.city.json")], capsys)
    assert code == 2 and "1 row(s) without a building id" in err and "data row 2" in err, err


def test_a_truth_table_keeps_008_and_8_apart(tmp_path):
    """compare's and the report's truth (read_table, check_truth): two buildings, not one id
    twice."""
    path = tmp_path / "truth.csv"
    path.write_text("id,height,ground\n008,20.0,10.0\n8,25.0,10.0\nNA,30.0,10.0\n")
    truth = check_truth(read_table(path), str(path))
    assert truth["id"].tolist() == ["008", "8", "NA"]
