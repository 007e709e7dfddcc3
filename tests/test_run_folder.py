"""A folder of heights written tile by tile (estimate -o FOLDER --scheduler ...) is read only
as its tile index lists it: a tile folder missing, a part file missing, added, cut short or
replaced is refused naming the tile, never converted as fewer or other buildings (issue 45)."""

import shutil

import geopandas as gpd
import pandas as pd
import pytest
from test_cli import run
from test_outputs import CITY

from gnss_citygml.errors import InputError
from gnss_citygml.jobs import convert_file, estimate_file, read_buildings
from gnss_citygml.settings import Tiling


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    """The city's heights written in 100 m tiles, with their tile index."""
    folder = tmp_path_factory.mktemp("run") / "run"
    made = estimate_file(
        CITY / "observations.parquet", CITY / "footprints.gpkg", CITY / "dem.tif", folder,
        tiling=Tiling("local", workers=1, size=100.0),
    )  # fmt: skip
    assert len(made.tiles) > 3
    return folder, made.tiles.sort_values("tile").reset_index(drop=True)


def _copy(written, tmp_path):
    folder, index = written
    shutil.copytree(folder, tmp_path / "run")
    return tmp_path / "run", index


def _largest(index):
    return index.sort_values(["buildings", "tile"]).iloc[-1]


def _tile_folder_removed(folder, index):
    tile = _largest(index)["tile"]
    shutil.rmtree(folder / "heights" / f"tile={tile}")
    return tile


def _part_removed(folder, index):
    row = _largest(index)
    (folder / row["location"]).unlink()
    return row["tile"]


def _part_cut_short(folder, index):
    row = _largest(index)
    path = folder / row["location"]
    path.write_bytes(path.read_bytes()[:-200])
    return row["tile"]


def _part_with_fewer_rows(folder, index):
    row = _largest(index)
    path = folder / row["location"]
    gpd.read_parquet(path).iloc[:-1].to_parquet(path)
    return row["tile"]


def _part_of_another_run(folder, index):
    """The same buildings, other heights: another run's file of the same tile."""
    row = _largest(index)
    path = folder / row["location"]
    frame = gpd.read_parquet(path)
    frame.assign(height=frame["height"] + 1.0).to_parquet(path)
    return row["tile"]


def _part_added(folder, index):
    row = _largest(index)
    path = folder / row["location"]
    shutil.copy(path, path.with_name("part-0 (1).parquet"))
    return row["tile"]


def _tile_folder_added(folder, index):
    row = _largest(index)
    shutil.copytree((folder / row["location"]).parent, folder / "heights" / "tile=TQ000000")
    return "TQ000000"


def _tile_removed_from_the_index_too(folder, index):
    """The tile's folder and its row of the index removed (found at the command line: 16
    buildings of 30 written, exit 0): the folder's list of what the run wrote still names it."""
    tile = _tile_folder_removed(folder, index)
    tiles = gpd.read_file(folder / "tiles.gpkg", layer="tiles")
    tiles[tiles["tile"] != tile].to_file(folder / "tiles.gpkg", layer="tiles")
    return tile


DAMAGE = {
    "a tile folder missing": _tile_folder_removed,
    "a part file missing": _part_removed,
    "a part file cut short": _part_cut_short,
    "a part file with fewer rows": _part_with_fewer_rows,
    "a part file of another run": _part_of_another_run,
    "a part file added": _part_added,
    "a tile folder added": _tile_folder_added,
    "a tile removed from the index too": _tile_removed_from_the_index_too,
}


@pytest.mark.parametrize("damage", list(DAMAGE))
def test_a_run_folder_unlike_its_tile_index_is_refused(written, tmp_path, damage):
    folder, index = _copy(written, tmp_path)
    tile = DAMAGE[damage](folder, index)
    for given in (folder, folder / "heights"):
        with pytest.raises(InputError, match=f"tile={tile}") as caught:
            read_buildings(given)
        assert "tiles.gpkg" in caught.value.one_line(), caught.value.one_line()


def test_the_issues_convert_of_a_folder_missing_a_tile_exits_2(written, tmp_path, capsys):
    """It wrote 19 buildings where the index lists 30, exit 0."""
    folder, index = _copy(written, tmp_path)
    tile = _tile_folder_removed(folder, index)
    out = tmp_path / "city.city.jsonl"
    code, _, err = run(["convert", str(folder), "-o", str(out)], capsys)
    assert code == 2 and err.startswith("error: ") and err.count("\n") == 1, err
    assert f"tile={tile}" in err and not out.exists()


def test_an_intact_run_folder_is_read_whole_and_tile_by_tile(written, tmp_path):
    folder, index = written
    whole = read_buildings(folder)
    assert len(whole) == index["buildings"].sum()
    row = _largest(index)
    one = read_buildings((folder / row["location"]).parent)
    assert len(one) == row["buildings"]
    made = convert_file(folder, tmp_path / "city.city.json")
    assert made.written == index["with_height"].sum()
    frames = [gpd.read_parquet(folder / loc) for loc in index["location"]]
    assert len(pd.concat(frames)) == len(whole)
