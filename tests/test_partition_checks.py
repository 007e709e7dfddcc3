"""What a run from a partition trusts: every part of its index (sealed by a digest), the DEM
it was made on, and building ids unique across its tiles (issue 45)."""

import json
import shutil

import geopandas as gpd
import pytest
from test_cli import run
from test_outputs import CITY

from gnss_citygml.errors import InputError
from gnss_citygml.observations import read_observations, write_observations
from gnss_citygml.tiling.buildings import Footprints
from gnss_citygml.tiling.from_partition import partitioned_heights
from gnss_citygml.tiling.partition import INDEX, partition_observations

DEM = CITY / "dem.tif"


@pytest.fixture(scope="module")
def made(tmp_path_factory):
    """Half the city's receivers, partitioned in 100 m tiles with its footprints."""
    folder = tmp_path_factory.mktemp("made")
    obs = read_observations(CITY / "observations.parquet")
    half = obs[obs["receiver"].isin(sorted(obs["receiver"].unique())[::2])]
    write_observations(half.reset_index(drop=True), folder / "a.parquet")
    partition_observations(
        [folder / "a.parquet"], folder / "p", DEM, tile_size=100.0,
        footprints=Footprints(CITY / "footprints.gpkg"),
    )  # fmt: skip
    return folder / "p"


def _copy(made, tmp_path):
    folder = tmp_path / "p"
    shutil.copytree(made, folder)
    return folder, json.loads((folder / INDEX).read_text())


def _bounds_moved(folder, index):
    """The issue's case: one buildings tile's extent moved (its halo, its receivers change)."""
    spec = next(iter(index["buildings"]["tiles"].values()))
    spec["bounds"] = [v + 150.0 for v in spec["bounds"]]


def _file_moved(folder, index):
    """A buildings file moved to another tile, folder and index alike (its SHA-256 is right)."""
    tiles = index["buildings"]["tiles"]
    a, b = sorted(tiles)[:2]
    entry = tiles[a]["files"].pop("part-00000.parquet")
    tiles[b]["files"]["part-00001.parquet"] = entry
    tiles[a]["rows"] -= entry["rows"]
    tiles[b]["rows"] += entry["rows"]
    top = folder / "buildings"
    (top / f"tile={a}" / "part-00000.parquet").rename(top / f"tile={b}" / "part-00001.parquet")
    if not tiles[a]["files"]:
        del tiles[a]
        (top / f"tile={a}").rmdir()


def _tile_dropped(folder, index):
    """A receivers tile taken out of the index and of the folder, the sums kept right."""
    name = next(iter(index["tiles"]))
    index["signals"] -= index["tiles"].pop(name)["rows"]
    shutil.rmtree(folder / "receivers" / f"tile={name}")


def _mask_changed(folder, index):
    """The elevation mask the rows were cut with, said otherwise."""
    index["rays"]["min_elevation"] = 20.0


def _rows_recounted(folder, index):
    """A file's rows said otherwise, its tile's and the signals' with them."""
    spec = next(iter(index["tiles"].values()))
    next(iter(spec["files"].values()))["rows"] += 7
    spec["rows"] += 7
    index["signals"] += 7


def _ids_renamed(folder, index):
    index["buildings"]["id_field"] = "toid"


def _square_moved(folder, index):
    """A receivers tile renamed with its square, folder and index alike."""
    name, spec = next(iter(index["tiles"].items()))
    other = f"{name[:2]}{int(name[2:5]) + 5:03d}{name[5:]}"
    index["tiles"][other] = {**index["tiles"].pop(name), "ix": spec["ix"] + 5}
    (folder / "receivers" / f"tile={name}").rename(folder / "receivers" / f"tile={other}")


EDITS = {
    "a buildings tile's bounds": _bounds_moved,
    "a file moved to another tile": _file_moved,
    "a tile dropped with its folder": _tile_dropped,
    "the elevation mask": _mask_changed,
    "a file's rows, with the sums": _rows_recounted,
    "the id field's name": _ids_renamed,
    "a tile's square": _square_moved,
}


@pytest.mark.parametrize("edit", list(EDITS))
def test_an_index_edited_consistently_is_refused(made, tmp_path, edit):
    """Every part of partition.json decides what a worker reads or how its rows are taken: an
    edit that keeps the sums and the folder in agreement (it used to be read: the issue's
    moved bounds changed 25 of 30 heights, exit 0) is refused by the index's own digest."""
    folder, index = _copy(made, tmp_path)
    EDITS[edit](folder, index)
    (folder / INDEX).write_text(json.dumps(index, indent=1))
    with pytest.raises(InputError, match=r"partition\.json is not the index partition wrote"):
        partitioned_heights(folder, rays=_rays(index))


def _rays(index):
    from gnss_citygml.settings import Rays

    return Rays(min_elevation=index["rays"]["min_elevation"])


def test_an_edited_index_is_one_line_and_exit_2_from_the_command(made, tmp_path, capsys):
    folder, index = _copy(made, tmp_path)
    _bounds_moved(folder, index)
    (folder / INDEX).write_text(json.dumps(index))
    args = ["estimate", str(folder), "-o", str(tmp_path / "h.gpkg"), "--scheduler", "local",
            "--workers", "1", "-q"]  # fmt: skip
    code, _, err = run(args, capsys)
    assert code == 2 and err.startswith("error: ") and err.count("\n") == 1, err
    assert "partition.json is not the index partition wrote" in err and "partition" in err
    assert not (tmp_path / "h.gpkg").exists()


def _id_in_two_tiles(folder):
    """A buildings file copied into another tile, the index sealed again: a partition whose
    ids are not unique across its tiles (partition refuses to write one); the tiles named."""
    from gnss_citygml.tiling.partition import _index_digest

    index = json.loads((folder / INDEX).read_text())
    tiles = index["buildings"]["tiles"]
    a, b = sorted(tiles)[:2]
    entry = tiles[a]["files"]["part-00000.parquet"]
    top = folder / "buildings"
    shutil.copy(top / f"tile={a}" / "part-00000.parquet", top / f"tile={b}" / "part-00001.parquet")
    tiles[b]["files"]["part-00001.parquet"] = dict(entry)
    tiles[b]["rows"] += entry["rows"]
    index["buildings"]["rows"] += entry["rows"]
    index["sha256"] = _index_digest(index)
    (folder / INDEX).write_text(json.dumps(index, indent=1))
    first = gpd.read_parquet(top / f"tile={a}" / "part-00000.parquet")["id"].iloc[0]
    return first, a, b


def test_an_id_in_two_tiles_of_a_partition_is_named_with_both(made, tmp_path, capsys):
    """It made every tile fail (ValueError: Categorical categories must be unique), exit 0,
    written per tile; gathered, the run named the id without its tiles."""
    folder, _ = _copy(made, tmp_path)
    building, a, b = _id_in_two_tiles(folder)
    expected = rf"building id\(s\) held by two buildings.* {building} in tiles {a} and {b}"
    with pytest.raises(InputError, match=expected):
        partitioned_heights(folder)  # each tile's worker reads its own buildings
    tiled = ["--scheduler", "local", "--workers", "1", "-q"]
    for output in ("tiles", "h.gpkg"):  # per tile, and gathered
        args = ["estimate", str(folder), "-o", str(tmp_path / output), *tiled]
        code, _, err = run(args, capsys)
        assert code == 2 and err.startswith("error: ") and err.count("\n") == 1, err
        assert f"{building} in tiles {a} and {b}" in err, err
        assert not (tmp_path / output).exists()


@pytest.fixture(scope="module")
def scene():
    from test_tiled import city

    return city(0)


def test_a_run_whose_every_tile_failed_is_an_error(scene, engine, tmp_path):
    """Not a run of failed tiles only, exit 0 (their warnings aside): nothing is written."""
    import numpy as np

    from gnss_citygml.tiling.output import TileFolder
    from gnss_citygml.tiling.run import tiled_heights

    rx, buildings = scene
    broken = rx.assign(position_sd=np.full(len(rx), -1.0))
    with pytest.raises(InputError, match=r"every one of the \d+ tiles failed, e.g. tile TQ"):
        tiled_heights(broken, buildings, tile_size=100.0, engine=engine)
    out = TileFolder(str(tmp_path / "t"), "4PL-B", "id", 100.0)
    with pytest.raises(InputError, match="height_sd must be a finite number"):
        tiled_heights(broken, buildings.assign(ground=0.0), tile_size=100.0, engine=engine,
                      output=out)  # fmt: skip


@pytest.fixture(scope="module")
def other_dem(tmp_path_factory):
    """The city's DEM 3 m higher (another survey), and a copy of it as it is."""
    import rasterio

    folder = tmp_path_factory.mktemp("dems")
    with rasterio.open(DEM) as src:
        profile, z = src.profile, src.read(1)
    with rasterio.open(folder / "higher.tif", "w", **profile) as dst:
        dst.write(z + 3.0, 1)
    shutil.copy(DEM, folder / "same.tif")
    return folder / "higher.tif", folder / "same.tif"


@pytest.fixture(scope="module")
def bare(made):
    """The same receivers partitioned without footprints."""
    folder = made.parent / "bare"
    partition_observations([made.parent / "a.parquet"], folder, DEM, tile_size=100.0)
    return folder


def _estimate(capsys, tmp_path, *args):
    out = tmp_path / "h.gpkg"
    code, _, err = run(["estimate", *map(str, args), "-o", str(out), "--scheduler", "local",
                        "--workers", "1", "-q"], capsys)  # fmt: skip
    return code, err, out


def test_a_run_on_another_dem_than_its_partitions_is_refused_naming_both(
    made, bare, other_dem, tmp_path, capsys
):
    """The receivers' heights were taken on the partition's DEM: grounds from another would
    mix two surveys (it ran, exit 0). Refused before any work, with or without footprints in
    the partition."""
    higher, _ = other_dem
    for args in ((bare, CITY / "footprints.gpkg", "--dem", higher), (made, "--dem", higher)):
        code, err, out = _estimate(capsys, tmp_path, *args)
        assert code == 2 and err.startswith("error: ") and err.count("\n") == 1, err
        assert "higher.tif is not the DEM the partition was made on (dem.tif)" in err, err
        assert "by up to 3.00 m" in err and not out.exists()


def test_the_partitions_own_dem_given_again_is_taken(made, bare, other_dem, tmp_path):
    """A copy of the partition's DEM is the same ground: the run goes on."""
    from gnss_citygml.jobs import estimate_file
    from gnss_citygml.settings import Tiling

    _, same = other_dem
    tiling = Tiling("local", workers=1)
    a = estimate_file(bare, CITY / "footprints.gpkg", same, tmp_path / "a.gpkg", tiling=tiling)
    b = estimate_file(made, None, same, tmp_path / "b.gpkg", tiling=tiling)
    assert a.heights["converged"].sum() >= 5
    assert sorted(a.heights["ground"]) == pytest.approx(sorted(b.heights["ground"]))


def test_footprints_given_to_a_partition_holding_its_own_are_refused(made, tmp_path, capsys):
    """Two sets of buildings for one run: which one counts is not a guess to make."""
    code, err, out = _estimate(capsys, tmp_path, made, CITY / "footprints.gpkg", "--dem", DEM)
    assert code == 2 and err.startswith("error: ") and err.count("\n") == 1, err
    assert "the partition holds its own footprints" in err and not out.exists()
