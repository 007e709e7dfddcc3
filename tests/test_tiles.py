"""Tiles of British National Grid (gnss_citygml.tiling.grid): names, buildings' and receivers'
tiles, against OS grid references of known places and a brute-force reach."""

import geopandas as gpd
import numpy as np
import pandas as pd
import pytest
import shapely
from shapely.geometry import Polygon, box

from gnss_citygml.errors import InputError
from gnss_citygml.raycast import footprint_entries
from gnss_citygml.tiling.grid import (
    building_tiles,
    plan_tiles,
    receiver_tiles,
    tile_index,
    tile_names,
)


def name(e, n, size=1000.0):
    return tile_names(*tile_index([e], [n], size), size)[0]


@pytest.mark.parametrize(
    ("e", "n", "size", "expected"),
    [
        (529540, 182293, 1000, "TQ2982"),  # Gower Street, London
        (529540, 182293, 10_000, "TQ28"),
        (529540, 182293, 100_000, "TQ"),
        (529540, 182293, 100, "TQ295822"),
        (216600, 771200, 1000, "NN1671"),  # Ben Nevis
        (447000, 1141000, 1000, "HU4741"),  # Lerwick, Shetland
        (0, 0, 1000, "SV0000"),  # the false origin, off the Scillies
        (699_999, 1_299_999, 1000, "JM9999"),  # the grid's far corner
        (529540, 182293, 500, "TQ2950082000-500m"),
    ],
)
def test_tiles_are_named_by_their_os_grid_reference(e, n, size, expected):
    assert name(e, n, size) == expected


@pytest.mark.parametrize(("e", "n"), [(-1, 5), (700_000, 5), (5, 1_300_000)])
def test_a_tile_outside_the_national_grid_is_refused(e, n):
    with pytest.raises(InputError, match="outside the OS national grid"):
        name(e, n)


@pytest.mark.parametrize(
    "size", [0, 0.5, 250.5, float("nan"), -1000, 1, 10, 49, 100_001, float("inf"), 1e12]
)
def test_a_tile_size_must_be_whole_metres(size):
    """Whole metres from 50 m (a few buildings) to 100 km (an OS lettered square): 1 m tiles
    were a MemoryError of 318 GiB in a run, and a folder per square metre in a partition."""
    with pytest.raises(InputError, match="whole number of metres from 50 to 100,000"):
        tile_index([0.0], [0.0], size)


@pytest.mark.parametrize("size", ["1", "0", "-5", "nan", "inf", "1.5", "1e9", "49"])
@pytest.mark.parametrize("command", ["partition", "estimate"])
def test_a_tile_size_out_of_bounds_is_one_line_from_the_commands(
    tmp_path, capsys, grid_args, command, size
):
    from test_cli import run
    from test_outputs import CITY, estimate

    if command == "partition":
        args = ["partition", str(CITY / "observations.parquet"), "-o", str(tmp_path / "p")]
        args += ["--dem", str(CITY / "dem.tif"), *grid_args]
    else:
        args = [*estimate(tmp_path, grid_args, "h.gpkg"), "--scheduler", "local"]
    code, _, err = run([*args, "--tile-size", size], capsys)
    assert code == 2 and err.startswith("error: a tile size must be a whole number"), err
    assert err.count("\n") == 1 and "--tile-size" in err
    assert list(tmp_path.iterdir()) == []


def test_tiles_much_smaller_than_the_rays_reach_are_refused():
    """A tile at least a tenth of the reach: each receiver is tested against at most 441
    tiles around it (the candidates of 1 m tiles and 500 m rays were 10^6 a receiver)."""
    one = gpd.GeoDataFrame(geometry=[box(529_000, 182_000, 529_010, 182_010)], crs=27700)
    with pytest.raises(InputError, match="tiles of 60 m are too small for rays of 1000 m"):
        receiver_tiles([529_000.0], [182_000.0], one, 1000.0, 60.0)
    with pytest.raises(InputError, match="give --tile-size 100 or more"):
        plan_tiles([529_000.0], [182_000.0], one, 1000.0, 60.0)
    assert receiver_tiles([529_000.0], [182_000.0], one, 1000.0, 100.0)["tile"].tolist() == [
        "TQ290820"
    ]


def test_a_run_of_more_tiles_than_the_national_grid_has_is_refused_before_naming_them():
    """1,001,000 buildings 50 m apart, in 50 m tiles: refused with the count, before a tile
    is named or planned (no allocation per tile)."""
    x, y = np.meshgrid(np.arange(1001) * 50.0, np.arange(1000) * 50.0)
    corners = np.column_stack([x.ravel() + 100_000, y.ravel() + 100_000])
    many = gpd.GeoDataFrame(geometry=shapely.box(*corners.T, *(corners + 5).T), crs=27700)
    with pytest.raises(InputError, match="would make 1,001,000 tiles, more than a run takes"):
        plan_tiles([100_000.0], [100_000.0], many, 500.0, 50.0)
    assert len(set(building_tiles(many.iloc[:1000], 50.0))) == 1000


def test_a_building_belongs_to_the_tile_of_a_point_inside_it():
    across = box(529_990, 182_100, 530_030, 182_120)  # 10 m in TQ2982, 30 m in TQ3082
    ell = Polygon(  # an L whose centroid lies outside it, in the next tile
        [
            (528_999, 182_000),
            (528_999, 182_990),
            (529_001, 182_990),
            (529_001, 182_002),
            (529_990, 182_002),
            (529_990, 182_000),
        ]  # fmt: skip
    )
    assert not ell.contains(ell.centroid)
    buildings = gpd.GeoDataFrame(geometry=[across, ell], crs=27700)
    tiles = building_tiles(buildings).tolist()
    assert tiles[0] in ("TQ2982", "TQ3082")
    assert tiles[0] == name(*shapely.point_on_surface(across).coords[0])
    assert ell.contains(shapely.point_on_surface(ell))
    assert tiles[1] == name(*shapely.point_on_surface(ell).coords[0])


def test_receivers_serve_every_tile_whose_buildings_their_rays_reach():
    rng = np.random.default_rng(3)
    x0, y0 = 528_000.0, 181_000.0  # a 3 km x 3 km city: 9 tiles, buildings across edges
    corners = rng.uniform(0, 3000, (300, 2)) + (x0, y0)
    sizes = rng.uniform(8, 60, (300, 2))
    buildings = gpd.GeoDataFrame(
        geometry=[box(x, y, x + w, y + h) for (x, y), (w, h) in zip(corners, sizes, strict=True)],
        crs=27700,
    )
    e, n = (rng.uniform(-800, 3800, 4000) + o for o in (x0, y0))
    max_range = 300.0
    got = receiver_tiles(e, n, buildings, max_range)
    # brute force: each tile's buildings' bounding box, grown by the reach
    names = building_tiles(buildings)
    expected = set()
    for tile in set(names):
        bx0, by0, bx1, by1 = shapely.total_bounds(buildings.geometry[names == tile])
        inside = (e >= bx0 - max_range) & (e <= bx1 + max_range)
        inside &= (n >= by0 - max_range) & (n <= by1 + max_range)
        expected |= {(int(r), tile) for r in np.flatnonzero(inside)}
    assert set(zip(got["row"], got["tile"], strict=True)) == expected
    assert len(got) == len(expected)  # no pair twice
    assert (np.diff(got["row"]) >= 0).all()
    assert len(set(names)) >= 9
    # the receivers near a tile edge serve both tiles; the far ones serve none
    per_row = got.groupby("row").size()
    assert per_row.max() >= 4 and 0 < per_row.size < e.size


def test_no_buildings_no_tiles():
    empty = gpd.GeoDataFrame(geometry=[], crs=27700)
    assert receiver_tiles([529_000.0], [182_000.0], empty, 500.0).empty


def test_the_reach_must_be_positive():
    one = gpd.GeoDataFrame(geometry=[box(0, 0, 10, 10)], crs=27700)
    with pytest.raises(InputError, match="max_range"):
        receiver_tiles([5.0], [5.0], one, 0.0)


@pytest.mark.parametrize("by_ray", [False, True])
def test_each_tile_casts_every_crossing_of_the_signals_that_cross_its_buildings(by_ray):
    """The per-tile casts give the single cast's rows: every (signal, building) row of a tile's
    own buildings exactly once over all tiles, and for each such signal every other building
    it crosses, neighbours across the tile's edge included, with the same distances."""
    rng = np.random.default_rng(8)
    x0, y0 = 528_000.0, 181_000.0  # 2.5 km square, 500 m tiles: rays cross tile edges
    corners = rng.uniform(0, 2500, (400, 2)) + (x0, y0)
    sizes = rng.uniform(10, 40, (400, 2))
    geometry = [box(x, y, x + w, y + h) for (x, y), (w, h) in zip(corners, sizes, strict=True)]
    buildings = gpd.GeoDataFrame(geometry=geometry, crs=27700)
    e, n = (rng.uniform(0, 2500, 3000) + o for o in (x0, y0))
    bearing = rng.uniform(0, 360, e.size)
    max_range = 300.0
    whole = pd.DataFrame(
        dict(
            zip(
                ["ray", "building", "distance"],
                footprint_entries(e, n, bearing, geometry, max_range)[:3],
                strict=True,
            )
        )
    )
    tiles = plan_tiles(e, n, buildings, max_range, 500.0, bearing if by_ray else None)
    assert len(tiles) >= 25 and sum(t.buildings.size for t in tiles) == len(buildings)
    assert all(np.intersect1d(t.buildings, t.halo).size == 0 for t in tiles)
    parts = []
    for t in tiles:
        cast = np.concatenate([t.buildings, t.halo])
        ray, fp, dist = footprint_entries(
            e[t.receivers],
            n[t.receivers],
            bearing[t.receivers],
            buildings.geometry.to_numpy()[cast],
            max_range,
        )[:3]
        rows = pd.DataFrame({"ray": t.receivers[ray], "building": cast[fp], "distance": dist})
        mine = rows.loc[np.isin(rows["building"], t.buildings), "ray"].unique()
        rows = rows[np.isin(rows["ray"], mine)]
        parts.append(rows.assign(own=np.isin(rows["building"], t.buildings)))
    tiled = pd.concat(parts)
    keys = ["ray", "building"]
    own = tiled[tiled["own"]].sort_values(keys).reset_index(drop=True)
    expected = whole.sort_values(keys).reset_index(drop=True)
    pd.testing.assert_frame_equal(
        own[["ray", "building", "distance"]], expected, check_dtype=False, check_exact=True
    )
    # every tile's signals carry all their crossings, the halo's included
    full = tiled.drop(columns="own").drop_duplicates(keys).sort_values(keys).reset_index(drop=True)
    crossing = whole[np.isin(whole["ray"], full["ray"])].sort_values(keys).reset_index(drop=True)
    pd.testing.assert_frame_equal(full, crossing, check_dtype=False, check_exact=True)
    assert tiled["own"].sum() < len(tiled)  # the halo was needed


def test_a_tile_no_receiver_serves_is_listed_empty():
    buildings = gpd.GeoDataFrame(
        geometry=[box(529_100, 182_100, 529_120, 182_120), box(540_100, 182_100, 540_120, 182_120)],
        crs=27700,
    )
    tiles = plan_tiles([529_050.0], [182_050.0], buildings, 300.0)
    assert [t.name for t in tiles] == ["TQ2982", "TQ4082"]
    near, far = tiles
    assert near.receivers.tolist() == [0] and near.buildings.tolist() == [0]
    assert far.receivers.size == 0 and far.halo.size == 0 and far.buildings.tolist() == [1]


def test_rays_serve_only_the_tiles_they_can_enter():
    rng = np.random.default_rng(5)
    x0, y0 = 528_000.0, 181_000.0
    corners = rng.uniform(0, 3000, (200, 2)) + (x0, y0)
    buildings = gpd.GeoDataFrame(
        geometry=[box(x, y, x + 30, y + 20) for x, y in corners], crs=27700
    )
    e, n = (rng.uniform(-400, 3400, 3000) + o for o in (x0, y0))
    bearing = rng.uniform(0, 360, e.size)
    bearing[:10] = [0, 90, 180, 270, 0, 90, 180, 270, 45, 135]  # along the axes too
    max_range = 300.0
    got = receiver_tiles(e, n, buildings, max_range, 1000.0, bearing)
    names = building_tiles(buildings, 1000.0)
    expected = set()
    way = np.radians(bearing)
    rays = shapely.linestrings(
        np.stack(
            [np.column_stack([e, n]),
             np.column_stack([e + max_range * np.sin(way), n + max_range * np.cos(way)])],
            axis=1,
        )
    )  # fmt: skip
    for tile in set(names):
        extent = shapely.box(*shapely.total_bounds(buildings.geometry[names == tile]))
        expected |= {(int(r), tile) for r in np.flatnonzero(shapely.intersects(rays, extent))}
    assert set(zip(got["row"], got["tile"], strict=True)) == expected
    everyone = receiver_tiles(e, n, buildings, max_range, 1000.0)
    assert len(got) < 0.6 * len(everyone)  # most rays point away from most tiles in reach
