"""Observations partitioned by tile (gnss-citygml partition) and a run in tiles that reads
them tile by tile: the single run's heights, bit for bit."""

import json
import os
import shutil

import geopandas as gpd
import numpy as np
import pandas as pd
import pytest
from test_cli import run
from test_outputs import CITY, estimate
from test_tiled import assert_close_heights, assert_same_heights, killer

from gnss_citygml.errors import InputError
from gnss_citygml.footprints import read_footprints
from gnss_citygml.jobs import estimate_file
from gnss_citygml.model.estimate import estimate_heights, heights_and_signal_model
from gnss_citygml.observations import read_observations, write_observations
from gnss_citygml.pipeline import in_mask, intersections, open_sky, receivers, run_partitioned
from gnss_citygml.settings import Estimator, PositionError, Rays, ReceiverHeights, Tiling
from gnss_citygml.terrain import building_ground
from gnss_citygml.tiling.buildings import Footprints
from gnss_citygml.tiling.from_partition import partitioned_heights
from gnss_citygml.tiling.grid import building_tiles
from gnss_citygml.tiling.output import TileFolder
from gnss_citygml.tiling.partition import INDEX, check_partition, partition_observations, read_index

DEM = CITY / "dem.tif"


@pytest.fixture(scope="module")
def halves(tmp_path_factory):
    """The sample city's observations as two files, one per half of its receivers."""
    folder = tmp_path_factory.mktemp("halves")
    obs = read_observations(CITY / "observations.parquet")
    first = obs["receiver"].isin(sorted(obs["receiver"].unique())[::2])
    paths = [folder / "a.parquet", folder / "b.parquet"]
    for path, rows in zip(paths, (obs[first], obs[~first]), strict=True):
        write_observations(rows.reset_index(drop=True), path)
    return paths


def test_a_partition_holds_each_receiver_under_its_tile(halves, tmp_path):
    index = partition_observations(halves, tmp_path / "p", DEM, tile_size=100.0)
    assert read_index(tmp_path / "p") == index
    assert json.loads((tmp_path / "p" / INDEX).read_text())["tile_size"] == 100.0
    tiles = sorted((tmp_path / "p" / "receivers").iterdir())
    assert [t.name for t in tiles] == [f"tile={name}" for name in index["tiles"]]
    assert all(name.startswith("TQ3") and len(name) == 8 for name in index["tiles"])
    hive = pd.read_parquet(tmp_path / "p" / "receivers")  # the hive layout, as pyarrow reads it
    assert len(hive) == index["signals"] == sum(t["rows"] for t in index["tiles"].values())
    assert hive["signal"].sort_values().tolist() == list(range(index["signals"]))
    for name, rows in hive.groupby("tile", observed=True):
        spec = index["tiles"][name]
        assert (rows["e"] // 100 == spec["ix"]).all() and (rows["n"] // 100 == spec["iy"]).all()
    # the receivers are the pipeline's, file by file, numbered on across the files
    a = receivers(in_mask(read_observations(halves[0])), DEM)
    part = hive.sort_values("signal").iloc[: len(a)]
    np.testing.assert_array_equal(part["e"], a["e"])
    np.testing.assert_array_equal(part["bearing"], a["bearing"])
    assert part["recording"].str.startswith(tuple(a["receiver"].unique())).all()


def test_a_run_from_a_partition_holds_for_the_mixture_signal_model(halves, tmp_path):
    """The partition's files give the run's signals (each in one file), so the mixture
    learns from those crossing no footprint as the single run does."""
    partition_observations(halves, tmp_path / "p", DEM, tile_size=100.0)
    both = pd.concat([read_observations(p) for p in halves], ignore_index=True)
    buildings = building_ground(read_footprints(CITY / "footprints.gpkg"), DEM)
    rx = receivers(in_mask(both), DEM)
    inter = intersections(rx, buildings)
    estimator = Estimator(signal_model="mixture")
    single = estimate_heights(inter, estimator, open_sky=open_sky(rx, inter))
    assert single["converged"].sum() >= 10
    tiled = partitioned_heights(tmp_path / "p", buildings, estimator=estimator).table
    assert_close_heights(tiled, single)


def test_a_run_from_a_partition_gives_the_single_runs_heights(halves, tmp_path):
    """Two observation files, partitioned into 100 m tiles, read tile by tile: equal to the
    single run over both files (in one process here; on Dask in the command's test)."""
    partition_observations(halves, tmp_path / "p", DEM, tile_size=100.0)
    both = pd.concat([read_observations(p) for p in halves], ignore_index=True)
    buildings = building_ground(read_footprints(CITY / "footprints.gpkg"), DEM)
    # a building 750 m east of the city, in the (twice the reach) halo of its eastern tiles
    # but out of every ray's reach: its tile is left out of the run
    far = buildings.iloc[[0]].assign(id="far")
    east = buildings.total_bounds[2] + 750.0 - far.total_bounds[0]
    far = far.set_geometry(far.geometry.translate(east, 0.0))
    buildings = pd.concat([buildings, far], ignore_index=True)
    rx = receivers(in_mask(both), DEM)
    inter = intersections(rx, buildings)
    single, model = heights_and_signal_model(inter, open_sky=open_sky(rx, inter))
    assert "far" not in set(single["id"])
    said = []
    done = partitioned_heights(tmp_path / "p", buildings, progress=said.append)
    assert said[0] == "tile plan: 12 tiles of 100 m from 15 partitions"
    assert single["converged"].sum() >= 10
    assert_same_heights(done, (single, model))
    # written tile by tile: the same heights, read back whole; the far tile has its building
    out = TileFolder(str(tmp_path / "t"), "4PL-B", "id", 100.0)
    index = partitioned_heights(tmp_path / "p", buildings, output=out).table
    written = gpd.read_parquet(tmp_path / "t" / "heights")
    assert sorted(written["id"]) == sorted(buildings["id"])
    assert written.crs == buildings.crs
    alone = written.set_index("id").loc["far"]
    assert alone["status"] == "no signal's ray enters the footprint" and not alone["converged"]
    assert alone["tile"] == building_tiles(far, 100.0)[0]
    kept = written.set_index("id").drop(index="far").sort_index()
    one = single.set_index("id").sort_index()
    assert kept.index.tolist() == one.index.tolist() and (kept["status"] == one["status"]).all()
    for column in ("height", "height_lower", "height_upper", "c", "n_signals", "iterations"):
        np.testing.assert_array_equal(kept[column], one[column], err_msg=column)
    assert len(index) == 13 and index["tile"].is_unique and (index["failed"] == "").all()
    assert index["buildings"].sum() == len(buildings)
    assert index["with_height"].sum() == single["converged"].sum()
    for row in index.itertuples():  # each tile's square holds its buildings; its file is there
        mine = written[written["tile"] == row.tile]
        assert len(mine) == row.buildings and mine["converged"].sum() == row.with_height
        assert row.geometry.area == 100.0**2
        assert row.geometry.contains(mine.geometry.representative_point()).all()
        assert (tmp_path / "t" / row.location).is_file()


def test_the_commands_partition_and_estimate_from_it_on_a_local_cluster(
    halves, grid_args, tmp_path, capsys
):
    folder = tmp_path / "p"
    args = ["partition", *map(str, halves), "-o", str(folder), "--dem", str(DEM), *grid_args]
    code, out, err = run([*args, "--tile-size", "100", "-q"], capsys)
    assert code == 0, err
    assert out.strip() == f"38475 signals in 15 tiles of 100 m -> {folder}"
    code, _, err = run([*args, "-q"], capsys)  # the folder exists now
    assert code == 2 and "output exists" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["p"]  # no half-written folder
    tiled = estimate(tmp_path, grid_args, "tiled.gpkg", "--scheduler", "local", "--workers", "2")
    tiled[1] = str(folder)  # the partition folder in place of the observations
    code, out, err = run(tiled, capsys)
    assert code == 0, err
    assert "buildings have a height" in out
    both = pd.concat([read_observations(p) for p in halves], ignore_index=True)
    write_observations(both, tmp_path / "both.parquet")
    single = estimate(tmp_path, grid_args, "single.gpkg")
    single[1] = str(tmp_path / "both.parquet")
    code, _, err = run(single, capsys)
    assert code == 0, err
    a, b = (
        gpd.read_file(tmp_path / f"{n}.gpkg", layer="heights").set_index("id").sort_index()
        for n in ("single", "tiled")
    )
    assert (a["status"] == b["status"]).all() and a["converged"].sum() >= 10
    # the tile index: each building's tile, of the partition's size
    footprints = read_footprints(CITY / "footprints.gpkg")
    tiles = pd.Series(building_tiles(footprints, 100.0), index=footprints["id"].astype(str))
    assert "tile" not in a.columns
    assert b["tile"].tolist() == tiles.reindex(b.index).tolist()
    assert b["tile"].nunique() == 12
    for column in ("height", "height_lower", "height_upper", "relative_height"):
        np.testing.assert_array_equal(b[column], a[column], err_msg=column)
    # written tile by tile into a folder (no suffix), by the workers
    tiled[tiled.index("-o") + 1] = str(tmp_path / "tiles")
    code, out, err = run(tiled, capsys)
    assert code == 0, err
    assert out.strip().endswith(f"buildings have a height -> {tmp_path / 'tiles'} (12 tiles)")
    c = gpd.read_parquet(tmp_path / "tiles" / "heights").set_index("id").sort_index()
    assert c.index.tolist() == b.index.tolist() and (c["status"] == b["status"]).all()
    assert c["tile"].astype(str).tolist() == b["tile"].tolist()
    for column in ("height", "height_lower", "height_upper", "relative_height"):
        np.testing.assert_array_equal(c[column], a[column], err_msg=column)
    index = gpd.read_file(tmp_path / "tiles" / "tiles.gpkg", layer="tiles")
    assert sorted(index["tile"]) == sorted(b["tile"].unique())
    assert index["with_height"].sum() == a["converged"].sum()
    code, _, err = run(tiled, capsys)  # the folder exists now
    assert code == 2 and "output exists" in err and "--overwrite" in err
    code, _, err = run([*tiled, "--overwrite"], capsys)
    assert code == 0, err
    # the city model of every tile, or of one, from the folder (GeoParquet in, CityJSONSeq out)
    city = tmp_path / "city.city.jsonl"
    code, out, err = run(["convert", str(tmp_path / "tiles" / "heights"), "-o", str(city)], capsys)
    assert code == 0, err
    assert out.strip().startswith(f"{a['converged'].sum()} buildings, ") and "valid" in out
    whole = tmp_path / "whole.city.jsonl"  # the folder itself, as it was written
    code, out, err = run(["convert", str(tmp_path / "tiles"), "-o", str(whole)], capsys)
    assert code == 0, err
    assert out.strip().startswith(f"{a['converged'].sum()} buildings, ") and "valid" in out
    assert sorted(whole.read_text().splitlines()[1:]) == sorted(city.read_text().splitlines()[1:])
    first = index.sort_values("tile").iloc[0]
    one = tmp_path / "tiles" / first["location"]
    code, out, err = run(
        ["convert", str(one.parent), "-o", str(tmp_path / "one.city.json")], capsys
    )
    assert code == 0, err
    assert out.strip().startswith(f"{first['with_height']} buildings, ")
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith(".")) == []


@pytest.mark.parametrize(
    "extra, message",
    [
        ([], "a partition folder is read by a run in tiles"),
        (["--scheduler", "local", "--min-elevation", "20"], "written with elevations 10-85 deg"),
        (
            ["--scheduler", "local", "--position-window", "30"],
            "grouped position errors by stretches of 50 m, not by windows of 30 s",
        ),
        (
            ["--scheduler", "local", "--position-distance", "80"],
            "grouped position errors by stretches of 50 m, not by stretches of 80 m",
        ),
        (["--scheduler", "local", "--antenna-height", "1.5"], "took the receivers' heights"),
        (["--scheduler", "local", "--tile-size", "500"], "tiles are 100 m, not 500"),
        (["--scheduler", "local", "--tile-size", "1000"], "tiles are 100 m, not 1000"),
    ],
)
def test_a_run_unlike_its_partition_is_refused(halves, grid_args, tmp_path, capsys, extra, message):
    partition_observations(halves[:1], tmp_path / "p", DEM, tile_size=100.0)
    args = estimate(tmp_path, grid_args, "h.gpkg", *extra)
    args[1] = str(tmp_path / "p")
    code, _, err = run(args, capsys)
    assert code == 2 and err.startswith("error: ") and message in err, err
    assert not (tmp_path / "h.gpkg").exists()


def test_a_partition_from_before_the_distance_grouped_whole_recordings(halves, tmp_path):
    """partition.json without a position distance (written by 0.1) grouped each moving
    receiver's errors over its whole recording: a run asking that reads it, the default is told
    how to match it."""
    index = partition_observations(halves[:1], tmp_path / "p", DEM, tile_size=100.0)
    assert index["position_distance"] == PositionError().distance
    del index["position_distance"]
    check_partition(index, Rays(), PositionError(distance=None))
    with pytest.raises(InputError, match="by whole recordings, not by stretches of 50 m"):
        check_partition(index, Rays(), PositionError())


def test_a_folder_that_is_not_a_partition_is_a_clear_error(tmp_path):
    with pytest.raises(InputError, match="not a partition folder: cannot read partition.json"):
        read_index(tmp_path)
    (tmp_path / INDEX).write_text('{"format": "something else"}')
    with pytest.raises(InputError, match="is not gnss-citygml's"):
        read_index(tmp_path)


def test_a_failed_partition_leaves_no_folder(halves, tmp_path):
    with pytest.raises(InputError, match="nope.parquet"):
        partition_observations([halves[0], tmp_path / "nope.parquet"], tmp_path / "p", DEM)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("change", ["same", "flipped", "another zone", "svid as text"])
def test_a_signal_in_two_files_is_refused(halves, tmp_path, capsys, change):
    """Each file is read alone (its own repeats count once): a signal in two of them, the same
    or contradicting, would count twice or both ways. The command names both files and writes
    nothing."""
    obs = read_observations(halves[1]).iloc[:50]
    if change == "flipped":
        obs["cn0"] = np.where(obs["cn0"].isna(), 40.0, np.nan)
    copy = tmp_path / "copy.csv"
    obs.to_csv(copy, index=False)
    if change == "another zone":
        table = pd.read_csv(copy)
        times = pd.to_datetime(table["time_utc"]).dt.tz_convert("Europe/Berlin")
        table.assign(time_utc=times.map(lambda t: t.isoformat())).to_csv(copy, index=False)
    if change == "svid as text":
        table = pd.read_csv(copy, dtype={"svid": str})
        table.assign(svid=table["svid"].str.zfill(3)).to_csv(copy, index=False)
    args = ["partition", *halves, copy, "--dem", DEM, "-o", tmp_path / "p"]
    code, _, err = run([str(a) for a in args], capsys)
    assert code == 2 and err.count("\n") == 1, err
    assert "signal(s) in two of the files" in err and "b.parquet and " in err, err
    assert "copy.csv" in err and "give each recording once" in err
    assert not (tmp_path / "p").exists()


def test_footprints_no_partition_reaches_are_refused(halves, tmp_path):
    partition_observations(halves[:1], tmp_path / "p", DEM, tile_size=100.0)
    far = building_ground(read_footprints(CITY / "footprints.gpkg"), DEM)
    far = far.set_geometry(far.geometry.translate(5000.0, 0.0))
    with pytest.raises(InputError, match="no building has a receiver within the rays' reach"):
        partitioned_heights(tmp_path / "p", far)


def test_a_run_in_tiles_tells_its_progress_within_the_stages(halves, tmp_path):
    """The job's progress (the command's bar, QGIS's): the stages in order, and between
    them the tiles' news, at the share of the stage they belong to."""
    partition_observations(halves, tmp_path / "p", DEM, tile_size=100.0)
    said = []
    estimate_file(
        tmp_path / "p",
        CITY / "footprints.gpkg",
        DEM,
        tmp_path / "h.gpkg",
        tiling=Tiling("local", workers=1),
        progress=lambda what, done: said.append((what, done)),
    )
    names = [what for what, _ in said]
    assert names[:4] == ["observations", "receivers", "buildings", "ray casting"]
    assert names[4].startswith("tile plan: 12 tiles of 100 m")
    assert " phones levelled by their open sky: offsets " in names[5]
    assert names[6] == "iteration 1" and names[-3:] == ["height model", "output", "done"]
    shares = [done for _, done in said]
    assert shares == sorted(shares) and shares[-1] == 1.0
    assert all(done == shares[3] for _, done in said[4:-3])


def test_a_partition_with_its_own_receiver_heights_is_read_with_them(halves, tmp_path):
    """The run checks the receivers' heights once, against the run's own settings (it used to
    check them again against the defaults, refusing a partition made with --antenna-height)."""
    heights = ReceiverHeights(antenna_height=1.5)
    partition_observations(halves, tmp_path / "p", DEM, receiver_heights=heights, tile_size=100.0)
    footprints = read_footprints(CITY / "footprints.gpkg")
    kept = run_partitioned(
        tmp_path / "p", footprints, DEM, receiver_heights=heights, tiling=Tiling("local", 1)
    ).table
    assert kept["converged"].sum() >= 10
    with pytest.raises(InputError, match="took the receivers' heights"):
        run_partitioned(tmp_path / "p", footprints, DEM, tiling=Tiling("local", 1))


def test_a_damaged_partition_is_named(halves, tmp_path):
    index = partition_observations(halves[:1], tmp_path / "p", DEM, tile_size=100.0)
    name = next(iter(index["tiles"]))
    shutil.rmtree(tmp_path / "p" / "receivers" / f"tile={name}")
    buildings = building_ground(read_footprints(CITY / "footprints.gpkg"), DEM)
    with pytest.raises(
        InputError, match=f"damaged partition: receivers/tile={name} of partition.json is missing"
    ):
        partitioned_heights(tmp_path / "p", buildings)


@pytest.fixture(scope="module")
def written(halves, tmp_path_factory):
    """One partition of both halves in 100 m tiles, to copy and tamper with."""
    folder = tmp_path_factory.mktemp("written") / "p"
    partition_observations(halves, folder, DEM, tile_size=100.0)
    return folder


@pytest.fixture(scope="module")
def city_buildings():
    return building_ground(read_footprints(CITY / "footprints.gpkg"), DEM)


def _two_file_tile(folder):
    """A tile folder of the partition with two files (the halves both have receivers there)."""
    return next(t for t in sorted((folder / "receivers").iterdir()) if len(list(t.iterdir())) > 1)


def _edit_index(edit):
    def tamper(folder):
        index = json.loads((folder / INDEX).read_text())
        edit(index)
        (folder / INDEX).write_text(json.dumps(index))

    return tamper


def _flip_bytes(path):
    """The same size, other bytes: a file replaced by another of the same length."""
    data = bytearray(path.read_bytes())
    middle = len(data) // 2
    data[middle : middle + 8] = bytes(b ^ 0xFF for b in data[middle : middle + 8])
    path.write_bytes(bytes(data))


def _drop_first_tile(index):
    """A tile taken out of the index, its signals too (the sums agree)."""
    index["signals"] -= index["tiles"].pop(next(iter(index["tiles"])))["rows"]


def _drop_key(*keys):
    def edit(index):
        at = index
        for key in keys[:-1]:
            at = at[key] if key != "*" else next(iter(at.values()))
        del at[keys[-1]]

    return edit


def _old_version(index):
    index["version"] = 1
    for spec in index["tiles"].values():
        del spec["files"]


TAMPERING = {
    "a stray copy beside a part (a sync tool's)": (
        lambda f: shutil.copy(
            _two_file_tile(f) / "part-00000.parquet", _two_file_tile(f) / "part-00000 (1).parquet"
        ),
        r"part-00000 \(1\)\.parquet.* not in partition\.json",
    ),
    "a part deleted": (
        lambda f: (_two_file_tile(f) / "part-00001.parquet").unlink(),
        r"part-00001\.parquet.* is missing",
    ),
    "a part cut short": (
        lambda f: (_two_file_tile(f) / "part-00000.parquet").write_bytes(
            (_two_file_tile(f) / "part-00000.parquet").read_bytes()[:-100]
        ),
        r"part-00000\.parquet.* bytes, not",
    ),
    "a part of another schema": (
        lambda f: pd.DataFrame({"x": [1.0, 2.0]}).to_parquet(
            _two_file_tile(f) / "part-00000.parquet"
        ),
        r"part-00000\.parquet.* bytes, not",
    ),
    "a part's bytes replaced, its size kept": (
        lambda f: _flip_bytes(_two_file_tile(f) / "part-00001.parquet"),
        r"part-00001\.parquet.* not the file partition wrote \(its SHA-256 differs",
    ),
    "a tile taken out of partition.json": (
        _edit_index(_drop_first_tile),
        r"partition\.json is not the index partition wrote \(its content's SHA-256 differs",
    ),
    "a tile folder renamed": (
        lambda f: _two_file_tile(f).rename(f / "receivers" / "tile=TQ999999"),
        r"tile=TQ\S+.* (is missing|not in partition\.json)",
    ),
    "an extra tile folder": (
        lambda f: shutil.copytree(_two_file_tile(f), f / "receivers" / "tile=TQ000000"),
        r"tile=TQ000000.* not in partition\.json",
    ),
    "partition.json not JSON": (
        lambda f: (f / INDEX).write_text('{"format": "gnss-citygml partition", "vers'),
        r"cannot read partition\.json",
    ),
    "partition.json without its tiles": (
        _edit_index(_drop_key("tiles")),
        r"damaged partition\.json: no 'tiles'",
    ),
    "partition.json without a tile's files": (
        _edit_index(_drop_key("tiles", "*", "files")),
        r"damaged partition\.json: no 'files'",
    ),
    "partition.json with a tile's rows changed": (
        _edit_index(lambda i: next(iter(i["tiles"].values())).update(rows=1)),
        r"damaged partition\.json",
    ),
    "partition.json with a file's row count changed": (
        _edit_index(
            lambda i: next(iter(next(iter(i["tiles"].values()))["files"].values())).update(rows=1)
        ),
        r"damaged partition\.json",
    ),
    "partition.json with a file outside its tile": (
        _edit_index(
            lambda i: next(iter(i["tiles"].values()))["files"].update(
                {"../../x.parquet": {"rows": 0, "bytes": 1, "sha256": "0" * 64}}
            )
        ),
        r"damaged partition\.json",
    ),
    "a partition of the previous version, without its file list": (
        _edit_index(_old_version),
        r"partition format version 1, this toolkit reads 3",
    ),
    "partition.json with its version as text": (
        _edit_index(lambda i: i.update(version="3")),
        r"partition format version '3', this toolkit reads 3",
    ),
    "partition.json in another CRS": (
        _edit_index(lambda i: i.update(crs="EPSG:4326")),
        r"damaged partition\.json: 'crs' is 'EPSG:4326', not 'EPSG:27700'",
    ),
}


@pytest.mark.parametrize("tampering", list(TAMPERING))
def test_a_partition_that_does_not_match_its_index_is_refused(
    written, city_buildings, tmp_path, tampering
):
    """Every file of a partition is listed in its index with its rows, size and SHA-256: a
    stray file, a missing or changed one, a tile folder the index does not know or an index
    edited by hand is refused, naming the file (it used to be read: a stray copy gave other
    heights, a tile taken out of the index dropped its rows; all silently)."""
    folder = tmp_path / "p"
    shutil.copytree(written, folder)
    tamper, message = TAMPERING[tampering]
    tamper(folder)
    with pytest.raises(InputError, match=message) as caught:
        partitioned_heights(folder, city_buildings)
    assert "\n" not in caught.value.one_line() and "partition" in caught.value.fix


def test_a_stray_copy_in_a_partition_is_refused_by_the_command(
    written, grid_args, tmp_path, capsys
):
    """The issue's case: a sync tool's copy of a part; one line, exit 2, nothing written."""
    folder = tmp_path / "p"
    shutil.copytree(written, folder)
    tile = _two_file_tile(folder)
    shutil.copy(tile / "part-00000.parquet", tile / "part-00000 (1).parquet")
    args = estimate(tmp_path, grid_args, "h.gpkg", "--scheduler", "local", "--workers", "1")
    args[1] = str(folder)
    code, _, err = run(args, capsys)
    assert code == 2 and err.startswith("error: ") and err.count("\n") == 1, err
    assert "part-00000 (1).parquet" in err and "remove it" in err
    assert not (tmp_path / "h.gpkg").exists()


def test_a_part_replaced_with_its_size_kept_is_refused_by_the_command(
    written, grid_args, tmp_path, capsys
):
    """The SHA-256 is checked by the workers, before any tile is cast: one line, exit 2 (not
    a failed tile and exit 0)."""
    folder = tmp_path / "p"
    shutil.copytree(written, folder)
    _flip_bytes(_two_file_tile(folder) / "part-00000.parquet")
    args = estimate(tmp_path, grid_args, "h.gpkg", "--scheduler", "local", "--workers", "1")
    args[1] = str(folder)
    code, _, err = run(args, capsys)
    assert code == 2 and err.startswith("error: ") and err.count("\n") == 1, err
    assert "part-00000.parquet" in err and "SHA-256" in err
    assert not (tmp_path / "h.gpkg").exists()


def test_a_partition_whose_tiles_are_too_small_for_the_runs_rays_is_refused(
    written, city_buildings
):
    """100 m tiles serve rays of up to 1000 m; longer ones are refused before any tile is
    read (their candidate tiles around each receiver grow as the square of the reach)."""
    from gnss_citygml.settings import Rays

    with pytest.raises(InputError, match="tiles of 100 m are too small for rays of 2000 m"):
        partitioned_heights(written, city_buildings, rays=Rays(max_range=2000.0))


@pytest.fixture(scope="module")
def with_buildings(halves, tmp_path_factory):
    """A partition written with the city's footprints and DEM (copies, deleted after), read
    4 footprints at a time: it is all a run needs."""
    folder = tmp_path_factory.mktemp("with-buildings")
    footprints, dem = folder / "footprints.gpkg", folder / "dem.tif"
    shutil.copy(CITY / "footprints.gpkg", footprints)
    shutil.copy(DEM, dem)
    said = []
    index = partition_observations(
        halves, folder / "p", dem, tile_size=100.0,
        footprints=Footprints(footprints, batch=4), progress=said.append,
    )  # fmt: skip
    footprints.unlink(), dem.unlink()
    return folder / "p", index, said


def test_a_partition_with_its_footprints_holds_each_building_with_its_ground(with_buildings):
    folder, index, said = with_buildings
    whole = building_ground(read_footprints(CITY / "footprints.gpkg"), DEM)
    entry = index["buildings"]
    assert read_index(folder) == index
    assert entry["rows"] == len(whole) and entry["id_field"] == "id"
    assert "footprints.gpkg: buildings 1-4" in said and len(said) == 2 + -(-len(whole) // 4)
    hive = gpd.read_parquet(folder / "buildings")
    assert len(hive) == len(whole) and not (folder / "_ids").exists()
    tiles = pd.Series(building_tiles(whole, 100.0), index=whole["id"])
    assert (hive["tile"].astype(str).to_numpy() == tiles[hive["id"]].to_numpy()).all()
    mine = hive.set_index("id").loc[whole["id"]]
    np.testing.assert_array_equal(mine["ground"], whole["ground"])
    assert mine.geometry.geom_equals(whole.set_index("id").geometry).all()


def test_a_run_from_the_partition_alone_gives_the_single_runs_heights(with_buildings, tmp_path):
    """The footprint file and the DEM are gone: the heights are the single run's (same
    converged set, within 1 mm)."""
    folder, _, _ = with_buildings
    made = estimate_file(folder, None, None, tmp_path / "h.gpkg", tiling=Tiling("local", 1))
    single = estimate_file(
        CITY / "observations.parquet", CITY / "footprints.gpkg", DEM, tmp_path / "s.gpkg"
    )
    a = made.heights.set_index("id").sort_index()
    b = single.heights.set_index("id").sort_index()
    assert a.index.tolist() == b.index.tolist() and b["converged"].sum() >= 10
    assert (a["converged"] == b["converged"]).all() and (a["status"] == b["status"]).all()
    for column in ("height", "height_lower", "height_upper", "ground"):
        np.testing.assert_allclose(a[column], b[column], atol=1e-3, err_msg=column)


def test_a_tile_without_neighbours_reads_no_halo(halves, tmp_path):
    """Every building in one tile (10 km): no other tile is within the rays' reach, and the
    tile's run reads its own buildings only, with the single run's heights."""
    folder = tmp_path / "p"
    partition_observations(
        halves, folder, DEM, tile_size=10_000.0, footprints=Footprints(CITY / "footprints.gpkg")
    )
    assert len(read_index(folder)["buildings"]["tiles"]) == 1
    made = partitioned_heights(folder).table
    single = estimate_file(
        CITY / "observations.parquet", CITY / "footprints.gpkg", DEM, tmp_path / "s.gpkg"
    )
    assert single.heights["converged"].sum() >= 10
    assert_close_heights(made, single.heights)


def test_heights_written_per_tile_from_the_partition_alone(with_buildings, tmp_path, monkeypatch):
    """Written tile by tile, the client holds the plan only: each worker reads its tile's
    buildings and its halo's from the partition (reading them all here would fail), and the
    heights are the single run's, each tile's file with its footprints' attributes."""
    import gnss_citygml.tiling.partition as partition

    def everything(*args):
        raise AssertionError("the client read every building")

    monkeypatch.setattr(partition, "read_buildings", everything)
    folder, index, _ = with_buildings
    made = estimate_file(folder, None, None, tmp_path / "tiles", tiling=Tiling("local", 1))
    single = estimate_file(
        CITY / "observations.parquet", CITY / "footprints.gpkg", DEM, tmp_path / "s.gpkg"
    )
    assert made.tiles["buildings"].sum() == index["buildings"]["rows"]
    a = gpd.read_parquet(tmp_path / "tiles" / "heights").set_index("id").sort_index()
    b = single.heights.set_index("id").sort_index()
    assert a.index.tolist() == b.index.tolist() and b["converged"].sum() >= 10
    assert (a["converged"] == b["converged"]).all() and (a["status"] == b["status"]).all()
    for column in ("height", "height_lower", "height_upper", "ground", "relative_height"):
        np.testing.assert_allclose(a[column], b[column], atol=1e-3, err_msg=column)
    assert set(b.columns) - {"geometry"} <= set(a.columns)  # the footprints' attributes too


def test_a_worker_killed_mid_run_from_the_partition_alone_changes_nothing(
    with_buildings, engine, tmp_path
):
    """SIGKILL to one of two workers after the second iteration of a run whose workers read
    their own buildings: Dask recomputes what it held, and the tiles written are the same."""
    folder, index, _ = with_buildings
    kill_one, killed = killer(engine)
    written = {}
    for name, progress in (("calm", None), ("killed", kill_one)):
        out = TileFolder(str(tmp_path / name), "4PL-B", "id", float(index["tile_size"]))
        partitioned_heights(folder, engine=engine, output=out, progress=progress)
        written[name] = gpd.read_parquet(tmp_path / name / "heights").sort_values("id")
    assert killed and killed[0] not in engine.client.run(os.getpid).values()
    pd.testing.assert_frame_equal(
        written["killed"].reset_index(drop=True), written["calm"].reset_index(drop=True)
    )
    assert written["calm"]["converged"].sum() >= 10


def test_a_building_id_in_two_batches_is_named_with_both_tiles(halves, tmp_path):
    footprints = read_footprints(CITY / "footprints.gpkg")
    footprints.loc[len(footprints) - 1, "id"] = footprints["id"].iloc[0]  # far apart
    path = tmp_path / "twice.gpkg"
    footprints.to_file(path, layer="buildings")
    tiles = building_tiles(footprints, 100.0)
    with pytest.raises(InputError, match="1 building id.* held by two footprints, e.g. ") as bad:
        partition_observations(halves, tmp_path / "p", DEM, tile_size=100.0,
                               footprints=Footprints(path, batch=7))  # fmt: skip
    assert f"in tiles {tiles[0]} and {tiles[-1]}" in str(bad.value) and bad.value.where == str(path)
    assert not (tmp_path / "p").exists()


def test_footprints_with_a_tile_column_are_refused(halves, tmp_path):
    """A previous run's heights have a ``tile`` column: the partition's folders are named by
    it, so it would be read back as another tile's name."""
    footprints = read_footprints(CITY / "footprints.gpkg").assign(tile="TQ3181")
    footprints.to_file(tmp_path / "with-tile.gpkg", layer="buildings")
    with pytest.raises(InputError, match="a column 'tile', the name of the partition's folders"):
        partition_observations(halves, tmp_path / "p", DEM, tile_size=100.0,
                               footprints=Footprints(tmp_path / "with-tile.gpkg"))  # fmt: skip
    assert not (tmp_path / "p").exists()


def test_a_partitions_buildings_are_checked_before_a_run_reads_them(with_buildings, tmp_path):
    folder, index, _ = with_buildings
    copy = tmp_path / "p"
    shutil.copytree(folder, copy)
    tile = next(iter(index["buildings"]["tiles"]))
    part = next((copy / "buildings" / f"tile={tile}").iterdir())
    frame = gpd.read_parquet(part)
    frame.assign(ground=frame["ground"] + 10.0).to_parquet(part)  # another ground
    shutil.copy(part, part.with_name("part-99999.parquet"))
    with pytest.raises(InputError, match="part-99999.parquet is not in partition") as bad:
        estimate_file(copy, None, None, tmp_path / "h.gpkg", tiling=Tiling("local", 1))
    assert f"buildings/tile={tile}" in bad.value.where
    part.with_name("part-99999.parquet").unlink()
    with pytest.raises(InputError, match="(SHA-256 differs|bytes, not the)"):
        estimate_file(copy, None, None, tmp_path / "h.gpkg", tiling=Tiling("local", 1))


def test_without_footprints_or_a_dem_the_run_says_what_to_give(halves, tmp_path, capsys):
    partition_observations(halves, tmp_path / "p", DEM, tile_size=100.0)
    tiled = ["--scheduler", "local", "--workers", "1"]
    code, _, err = run(["estimate", str(tmp_path / "p"), "-o", str(tmp_path / "h.gpkg"), *tiled],
                       capsys)  # fmt: skip
    assert code == 2 and "no footprints" in err and "--footprints" in err, err
    code, _, err = run(["estimate", str(halves[0]), str(CITY / "footprints.gpkg"),
                        "-o", str(tmp_path / "h.gpkg")], capsys)  # fmt: skip
    assert code == 2 and "no DEM" in err and "--dem" in err, err


def test_the_partition_command_with_footprints_then_estimate_with_nothing_else(
    halves, tmp_path, capsys
):
    args = ["partition", *map(str, halves), "-o", str(tmp_path / "p"), "--dem", str(DEM),
            "--tile-size", "100", "--footprints", str(CITY / "footprints.gpkg"),
            "--quiet"]  # fmt: skip
    code, out, err = run(args, capsys)
    assert code == 0, err
    assert " signals in " in out and " buildings in " in out
    code, out, err = run(["estimate", str(tmp_path / "p"), "-o", str(tmp_path / "h.gpkg"),
                          "--scheduler", "local", "--workers", "1", "--quiet"], capsys)  # fmt: skip
    assert code == 0, err
    heights = gpd.read_file(tmp_path / "h.gpkg", layer="heights")
    assert heights["converged"].sum() >= 10 and heights["ground"].notna().all()
