"""A DEM given as a folder of tiles (as OS Terrain 5 ships): read as their mosaic, with the
heights of the whole raster, and tiles that cannot be mosaicked without resampling refused."""

import shutil
from pathlib import Path

import geopandas as gpd
import numpy as np
import pandas as pd
import pytest
import rasterio
import shapely
from rasterio.windows import Window
from test_cli import run
from test_terrain import CELL, HEIGHT, NORTH, WEST, WIDTH, buildings_table, plane, write_dem

from gnss_citygml.errors import InputError
from gnss_citygml.terrain import DemCoverageError, building_ground, sample_ground

BNG = "EPSG:27700"
CITY = Path(__file__).resolve().parents[1] / "examples" / "city"


def cut(dem: Path, folder: Path, cols: list[int], rows: list[int], **changes) -> Path:
    """The raster ``dem`` cut at the given column and row numbers into tiles in ``folder``
    (GeoTIFF unless ``driver`` says otherwise), each with the profile's ``changes``."""
    folder.mkdir(parents=True, exist_ok=True)
    with rasterio.open(dem) as src:
        col_edges = [0, *cols, src.width]
        row_edges = [0, *rows, src.height]
        suffix = ".asc" if changes.get("driver") == "AAIGrid" else ".tif"
        for i, (r0, r1) in enumerate(zip(row_edges, row_edges[1:], strict=False)):
            for j, (c0, c1) in enumerate(zip(col_edges, col_edges[1:], strict=False)):
                window = Window(c0, r0, c1 - c0, r1 - r0)
                profile = {
                    key: src.profile[key] for key in ("driver", "dtype", "nodata", "count", "crs")
                } | {"width": c1 - c0, "height": r1 - r0, "transform": src.window_transform(window)}
                path = folder / f"t{i}{j}{suffix}"
                with rasterio.open(path, "w", **(profile | changes)) as out:
                    out.write(src.read(1, window=window), 1)
    return folder


@pytest.fixture
def dem(tmp_path):
    return write_dem(tmp_path / "dem.tif")


def test_a_folder_of_tiles_gives_the_whole_rasters_heights(dem, tmp_path, rng):
    """Cut at uneven places, with buildings across the seams and points on them: the same
    ground and the same interpolated heights, to the bit."""
    tiles = cut(dem, tmp_path / "tiles", [137, 300], [90, 251])
    west = rng.uniform(WEST + 2, WEST + WIDTH * CELL - 40, 300)
    south = rng.uniform(NORTH - HEIGHT * CELL + 2, NORTH - 40, 300)
    boxes = shapely.box(
        west, south, west + rng.uniform(1, 35, 300), south + rng.uniform(1, 35, 300)
    )
    b = buildings_table([f"b{i}" for i in range(300)], boxes)
    seam_e, seam_n = WEST + 137 * CELL, NORTH - 90 * CELL
    e = np.r_[rng.uniform(WEST + 1, WEST + WIDTH * CELL - 1, 2000), seam_e, seam_e + 0.7]
    n = np.r_[rng.uniform(NORTH - HEIGHT * CELL + 1, NORTH - 1, 2000), seam_n, seam_n - 0.3]
    for statistic in ("median", "min", "mean"):
        np.testing.assert_array_equal(
            building_ground(b, tiles, statistic)["ground"],
            building_ground(b, dem, statistic)["ground"],
        )
    np.testing.assert_array_equal(sample_ground(tiles, e, n), sample_ground(dem, e, n))
    assert sample_ground(tiles, e, n) == pytest.approx(plane(e, n), abs=1e-9)


def test_ascii_grid_tiles_without_a_crs_are_taken_as_told(dem, tmp_path):
    """OS Terrain 50's ASCII grids carry no CRS: the whole folder is in BNG when --dem-crs
    says so, as one such file is."""
    tiles = cut(dem, tmp_path / "asc", [250], [200], driver="AAIGrid", crs=None)
    assert not list(tiles.glob("*.prj"))
    e, n = np.array([WEST + 499.0, WEST + 500.5]), np.array([NORTH - 399.0, NORTH - 401.0])
    with pytest.raises(InputError, match="the DEM has no CRS") as caught:
        sample_ground(tiles, e, n)
    assert caught.value.where == str(tiles / "t00.asc")  # the first tile, checked alone
    heights = sample_ground(tiles, e, n, assume_crs=BNG)
    assert heights == pytest.approx(plane(e, n), abs=1e-6)


def test_a_gap_between_tiles_is_named_with_the_folder(dem, tmp_path):
    tiles = cut(dem, tmp_path / "gap", [250], [200])
    (tiles / "t11.tif").unlink()  # the south-east quarter
    boxes = [
        shapely.box(500010, 200900, 500020, 200910),
        shapely.box(500700, 200300, 500710, 200310),
    ]
    b = buildings_table(["ok", "in the gap"], boxes)
    with pytest.raises(DemCoverageError, match=r"1 building\(s\) over nodata.*: in the gap") as bad:
        building_ground(b, tiles)
    assert bad.value.where == str(tiles)
    assert building_ground(b.iloc[:1], tiles)["ground"].iloc[0] == pytest.approx(
        building_ground(b.iloc[:1], dem)["ground"].iloc[0]
    )


@pytest.mark.parametrize(
    ("changes", "differ"),
    [
        ({"res": 4.0}, "cell size"),
        ({"shift": 1.0}, "grid alignment"),
        ({"dtype": "float32"}, "data type"),
        ({"nodata": -1.0}, "nodata value"),
        ({"crs": "EPSG:7405"}, "CRS"),  # British National Grid + ODN height: still BNG
    ],
)
def test_tiles_that_would_need_resampling_are_refused_by_name(dem, tmp_path, changes, differ):
    tiles = cut(dem, tmp_path / "bad", [250], [])
    with rasterio.open(tiles / "t01.tif") as ds:
        profile, z = ds.profile, ds.read(1)
    cell = changes.pop("res", CELL)
    shift = changes.pop("shift", 0.0)
    a = ds.transform
    profile |= changes | {
        "transform": rasterio.Affine(cell, 0, a.c + shift, 0, -cell, a.f),
        "width": z.shape[1] * CELL // cell,
        "height": z.shape[0] * CELL // cell,
    }
    z = z[:: int(cell // CELL), :: int(cell // CELL)].astype(profile["dtype"])
    (tiles / "t01.tif").unlink()
    with rasterio.open(tiles / "t01.tif", "w", **profile) as out:
        out.write(z, 1)
    with pytest.raises(InputError, match=f"the DEM's tiles differ in {differ}") as caught:
        sample_ground(tiles, [WEST + 10.0], [NORTH - 10.0])
    assert caught.value.where == f"{tiles}: t01.tif against t00.tif"


def test_a_tile_in_another_crs_or_an_empty_folder_is_named(dem, tmp_path):
    tiles = cut(dem, tmp_path / "wgs", [250], [], crs="EPSG:3857")
    with pytest.raises(InputError, match="not in EPSG:27700") as caught:
        sample_ground(tiles, [WEST + 10.0], [NORTH - 10.0])
    assert caught.value.where == str(tiles / "t00.tif")
    (tmp_path / "empty").mkdir()
    (tmp_path / "empty" / "readme.txt").write_text("tiles to come")
    with pytest.raises(InputError, match=r"holds no raster tile \(.tif, .tiff, .asc\)"):
        building_ground(buildings_table(["a"], [shapely.box(500010, 200900, 500020, 200910)]),
                        tmp_path / "empty")  # fmt: skip


def test_estimate_with_the_dem_as_a_folder_of_tiles(tmp_path, grid_args, capsys):
    """The command, from files: the sample city's heights with its DEM cut in four."""
    tiles = cut(CITY / "dem.tif", tmp_path / "dem", [40], [35])
    out = {}
    for name, dem in (("file", CITY / "dem.tif"), ("tiles", tiles)):
        args = ["estimate", str(CITY / "observations.parquet"), str(CITY / "footprints.gpkg"),
                "--dem", str(dem), "-o", str(tmp_path / f"{name}.gpkg"), *grid_args]  # fmt: skip
        code, _, err = run(args, capsys)
        assert code == 0, err
        out[name] = gpd.read_file(tmp_path / f"{name}.gpkg", layer="heights")
    assert out["file"]["converged"].sum() >= 10
    pd.testing.assert_frame_equal(out["tiles"], out["file"])


def tile(dem: Path, path: Path, cols: tuple[int, int], rows: tuple[int, int], add=0.0) -> None:
    """The cells ``cols`` x ``rows`` (first, end) of ``dem`` as the tile ``path``, ``add``
    metres higher (an older survey of the same ground)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    window = Window(cols[0], rows[0], cols[1] - cols[0], rows[1] - rows[0])
    with rasterio.open(dem) as src:
        profile = src.profile | {
            "width": window.width,
            "height": window.height,
            "transform": src.window_transform(window),
        }
        z = src.read(1, window=window) + add
    with rasterio.open(path, "w", **profile) as out:
        out.write(z, 1)


@pytest.mark.parametrize(
    ("tiles", "pair", "cells"),
    [
        # the same tile twice (an older copy beside it)
        ({"t1.tif": ((0, 250), (0, 400)), "t1_old.tif": ((0, 250), (0, 400)),
          "t2.tif": ((250, 500), (0, 400))}, ("t1.tif", "t1_old.tif"), "250 x 400"),
        # partly, offset by whole cells
        ({"a.tif": ((0, 260), (0, 400)), "b.tif": ((250, 500), (0, 400))},
         ("a.tif", "b.tif"), "10 x 400"),
        # one inside another (in a sub-folder)
        ({"all.tif": ((0, 500), (0, 400)), "old/patch.tif": ((100, 120), (50, 80))},
         ("all.tif", "old/patch.tif"), "20 x 30"),
        # three tiles: two side by side, the third across their seam
        ({"w.tif": ((0, 250), (0, 400)), "e.tif": ((250, 500), (0, 400)),
          "x.tif": ((240, 260), (0, 10))}, ("e.tif", "x.tif"), "10 x 10"),
    ],
)  # fmt: skip
def test_overlapping_tiles_are_refused_naming_both(dem, tmp_path, tiles, pair, cells):
    """Which tile's heights a cell gets would depend on the files' names: an overlap is
    refused, naming the two files and the cells they share."""
    folder = tmp_path / "dem"
    for k, (name, (cols, rows)) in enumerate(tiles.items()):
        tile(dem, folder / name, cols, rows, add=float(k))
    with pytest.raises(InputError, match="the DEM's tiles overlap") as caught:
        sample_ground(folder, [WEST + 10.0], [NORTH - 10.0])
    assert caught.value.where == f"{folder}: {pair[0]} and {pair[1]}"
    assert f"{cells} cells" in caught.value.what and "remove" in caught.value.fix


def test_tiles_sharing_an_edge_or_a_corner_do_not_overlap(dem, tmp_path, rng):
    folder = tmp_path / "dem"
    tile(dem, folder / "nw.tif", (0, 250), (0, 200))
    tile(dem, folder / "se.tif", (250, 500), (200, 400))  # its corner on nw's
    tile(dem, folder / "ne.tif", (250, 500), (0, 200))
    e = rng.uniform(WEST + 1, WEST + 999, 200)
    n = rng.uniform(NORTH - 399, NORTH - 1, 200)
    assert sample_ground(folder, e, n) == pytest.approx(plane(e, n), abs=1e-9)


@pytest.mark.parametrize("command", ["estimate", "partition", "update"])
def test_every_command_refuses_overlapping_tiles(tmp_path, grid_args, capsys, command):
    """estimate, partition and update read the DEM alike: the error, no output (update's map
    untouched)."""
    folder = tmp_path / "dem"
    tile(CITY / "dem.tif", folder / "a.tif", (0, 95), (0, 83))
    tile(CITY / "dem.tif", folder / "a_old.tif", (0, 95), (0, 83), add=2.0)
    observations, footprints = str(CITY / "observations.parquet"), CITY / "footprints.gpkg"
    city_map = tmp_path / "map.gpkg"
    shutil.copy(footprints, city_map)
    out = tmp_path / "out"
    args = {
        "estimate": [observations, str(footprints), "-o", f"{out}.gpkg"],
        "partition": [observations, "--footprints", str(footprints), "-o", str(out)],
        "update": [str(city_map), "--observations", observations],
    }[command]
    code, _, err = run([command, *args, "--dem", str(folder), *grid_args], capsys)
    assert code == 2 and "the DEM's tiles overlap" in err and "a.tif and a_old.tif" in err, err
    assert not list(tmp_path.glob("out*"))
    assert city_map.read_bytes() == footprints.read_bytes()
