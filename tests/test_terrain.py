"""The ground under footprints and at receivers, from DEMs on real files.

Synthetic DEMs are written to ``tmp_path`` with rasterio; the real OS MasterMap tile and OS
Terrain 50 zip are read in place from the shared data folder.
"""

import time

import geopandas as gpd
import numpy as np
import pytest
import rasterio
import shapely
from rasterio.transform import from_origin
from test_footprints import BNG, COURTYARD, SQUARE, write_footprints

from gnss_citygml.errors import InputError, escape_controls
from gnss_citygml.footprints import read_footprints
from gnss_citygml.terrain import DemCoverageError, building_ground, sample_ground

#: The synthetic DEM: 2 m cells, 500 x 400, west 500000, north 201000.
WEST, NORTH, CELL, WIDTH, HEIGHT = 500000.0, 201000.0, 2.0, 500, 400


def plane(e, n):
    """The synthetic DEM's heights: exact under bilinear interpolation."""
    return 10.0 + 0.01 * (np.asarray(e) - WEST) + 0.02 * (np.asarray(n) - 200000.0)


def write_dem(path, *, nodata_box=None, crs=BNG):
    """A float64 GeoTIFF of ``plane`` at the cell centres, with an optional nodata hole."""
    cols, rows = np.meshgrid(np.arange(WIDTH), np.arange(HEIGHT))
    e, n = WEST + (cols + 0.5) * CELL, NORTH - (rows + 0.5) * CELL
    z = plane(e, n)
    if nodata_box is not None:
        z[shapely.contains_xy(shapely.box(*nodata_box), e, n)] = -9999.0
    with rasterio.open(
        path, "w", driver="GTiff", width=WIDTH, height=HEIGHT, count=1, dtype="float64",
        crs=crs, transform=from_origin(WEST, NORTH, CELL, CELL), nodata=-9999.0,
    ) as ds:  # fmt: skip
        ds.write(z, 1)
    return path


def cells_under(geometry):
    """Heights of the DEM cells whose centres lie inside ``geometry`` (brute force)."""
    west, south, east, north = geometry.bounds
    cols = np.arange(
        max(int((west - WEST) // CELL) - 1, 0), min(int((east - WEST) // CELL) + 2, WIDTH)
    )
    rows = np.arange(
        max(int((NORTH - north) // CELL) - 1, 0), min(int((NORTH - south) // CELL) + 2, HEIGHT)
    )
    cols, rows = np.meshgrid(cols, rows)
    e, n = WEST + (cols + 0.5) * CELL, NORTH - (rows + 0.5) * CELL
    inside = shapely.contains_xy(geometry, e, n)
    return plane(e[inside], n[inside])


SHED = shapely.box(500601.2, 200701.2, 500601.9, 200701.7)  # smaller than a cell


@pytest.fixture
def dem(tmp_path):
    return write_dem(tmp_path / "dem.tif")


def buildings_table(ids, geometries):
    return gpd.GeoDataFrame({"id": ids}, geometry=geometries, crs=BNG)


def test_bilinear_sampling_is_exact_on_a_plane(dem, rng):
    e = rng.uniform(WEST + 1.0, WEST + WIDTH * CELL - 1.0, 10000)  # between cell centres
    n = rng.uniform(NORTH - HEIGHT * CELL + 1.0, NORTH - 1.0, 10000)
    assert np.abs(sample_ground(dem, e, n) - plane(e, n)).max() < 1e-9
    # the outer half cell takes the edge cells' value across the edge
    assert sample_ground(dem, [WEST + 0.3], [200500.0])[0] == pytest.approx(plane(WEST + 1, 200500))


@pytest.mark.parametrize("statistic", ["median", "min", "mean"])
def test_ground_statistics_match_the_cells_under_each_footprint(tmp_path, dem, statistic):
    with pytest.warns(UserWarning, match="repaired"):
        b = read_footprints(write_footprints(tmp_path))
    ground = building_ground(b, dem, statistic)["ground"].to_numpy()
    expected = [getattr(np, statistic)(cells_under(g)) for g in b.geometry]
    assert ground == pytest.approx(expected, abs=1e-9)


def test_ground_of_a_square_small_and_overlapping_footprints(dem):
    # 20 x 15 cell centres under SQUARE: the median is the plane at its centre
    inner = shapely.box(500110.0, 200310.0, 500130.0, 200320.0)  # inside SQUARE: overlaps it
    b = buildings_table(["sq", "shed", "inner"], [SQUARE, SHED, inner])
    ground = building_ground(b, dem)["ground"].to_numpy()
    assert ground[0] == pytest.approx(plane(500120.0, 200315.0))
    point = shapely.point_on_surface(SHED)
    assert ground[1] == pytest.approx(plane(point.x, point.y))
    assert ground[2] == pytest.approx(np.median(cells_under(inner)))
    assert len(cells_under(SQUARE)) == 20 * 15


def test_many_buildings_against_brute_force(dem, rng):
    west = rng.uniform(WEST + 2, WEST + WIDTH * CELL - 40, 400)
    south = rng.uniform(NORTH - HEIGHT * CELL + 2, NORTH - 40, 400)
    boxes = shapely.box(
        west, south, west + rng.uniform(3, 35, 400), south + rng.uniform(3, 35, 400)
    )
    b = buildings_table([f"b{i}" for i in range(400)], boxes)
    ground = building_ground(b, dem, "median")["ground"].to_numpy()
    expected = [np.median(cells_under(g)) for g in boxes]
    assert ground == pytest.approx(expected, abs=1e-9)


def test_nodata_under_a_building_is_an_error_but_not_under_its_courtyard(tmp_path):
    courtyard_hole = write_dem(tmp_path / "hole.tif", nodata_box=(500225, 200425, 500237, 200437))
    b = buildings_table(["court", "sq"], [COURTYARD, SQUARE])
    assert building_ground(b, courtyard_hole)["ground"][0] == pytest.approx(
        np.median(cells_under(COURTYARD))
    )
    under_square = write_dem(tmp_path / "gap.tif", nodata_box=(500120, 200310, 500124, 200314))
    with pytest.raises(DemCoverageError, match=r"1 building\(s\) over nodata.*: sq \(.*gap.tif"):
        building_ground(b, under_square)
    with pytest.raises(DemCoverageError, match=r"over nodata cells of the DEM: 0 "):
        sample_ground(under_square, [500121.0], [200311.0])


def test_buildings_and_receivers_off_the_dem(dem):
    far = [
        shapely.box(WEST - 10 + 100 * i, NORTH - 5, WEST + 5 + 100 * i, NORTH + 5)
        for i in range(12)
    ]
    b = buildings_table([f"edge{i}" for i in range(12)] + ["sq"], [*far, SQUARE])
    with pytest.raises(
        DemCoverageError, match=r"12 building\(s\) not wholly on the DEM: edge0, "
    ) as caught:
        building_ground(b, dem)
    assert caught.value.items == [f"edge{i}" for i in range(12)]
    assert "edge9 and 2 more" in str(caught.value)
    with pytest.raises(DemCoverageError, match=r"2 point\(s\) off the DEM: r1, r3 \("):
        sample_ground(dem, [500500, 499999, 501000, 502000], [200500, 200500, 200200, 200200],
                      labels=["r0", "r1", "r2", "r3"])  # fmt: skip


def test_dem_crs_rules(tmp_path, dem):
    b = buildings_table(["sq"], [SQUARE])
    no_crs = write_dem(tmp_path / "nocrs.tif", crs=None)
    with pytest.raises(InputError, match=r"the DEM has no CRS \(.*nocrs.tif\).*assume_crs"):
        building_ground(b, no_crs)
    assert building_ground(b, no_crs, assume_crs=BNG)["ground"][0] == pytest.approx(
        plane(500120.0, 200315.0)
    )
    utm = write_dem(tmp_path / "utm.tif", crs="EPSG:32630")
    with pytest.raises(InputError, match=r"not in EPSG:27700.*gdalwarp"):
        sample_ground(utm, [500500.0], [200500.0])
    with pytest.raises(InputError, match=r"unknown ground statistic 'max'"):
        building_ground(b, dem, "max")
    with pytest.raises(InputError, match=r"cannot open the DEM"):
        sample_ground(tmp_path / "none.tif", [500500.0], [200500.0])


def test_os_terrain_50_tile_in_its_zip(shared_data):
    tile = f"zip://{shared_data / 'footprints' / 'os_terrain50_asc_skye.zip'}!/asc_skye/NG33.asc"
    # NG33.asc: xllcorner 130000, yllcorner 830000, 50 m cells; its data row 10 (from the north)
    # reads "... 14.4 17.2 19 ..." at columns 19-21, and the south-east corner cell is 132.6
    e = np.array([130000 + 50 * 20 + 25, 130000 + 50 * 20 + 50, 140000 - 25])
    n = np.array([840000 - 50 * 10 - 25, 840000 - 50 * 10 - 25, 830000 + 25])
    heights = sample_ground(tile, e, n, assume_crs=BNG)
    assert heights == pytest.approx([17.2, (17.2 + 19.0) / 2, 132.6], abs=1e-5)
    with pytest.raises(InputError, match="no CRS"):
        sample_ground(tile, e, n)
    with pytest.raises(DemCoverageError, match=r"1 point\(s\) off the DEM: 1 \(zip://"):
        sample_ground(tile, [135000.0, 140100.0], [835000.0, 835000.0], assume_crs=BNG)


def test_mastermap_ground_on_a_synthetic_dem(shared_data, tmp_path):
    b = read_footprints(shared_data / "footprints" / "mastermap-topo_3473984_0.gml")
    path = tmp_path / "london.tif"
    west, north, cell = 529200.0, 182600.0, 1.0
    cols, rows = np.meshgrid(np.arange(600), np.arange(600))
    z = 20.0 + 0.01 * (west + cols + 0.5 - 529000) - 0.02 * (north - rows - 0.5 - 182000)
    with rasterio.open(
        path, "w", driver="GTiff", width=600, height=600, count=1, dtype="float64",
        crs=BNG, transform=from_origin(west, north, cell, cell),
    ) as ds:  # fmt: skip
        ds.write(z, 1)
    start = time.perf_counter()
    ground = building_ground(b, path, "mean")["ground"].to_numpy()
    seconds = time.perf_counter() - start
    # the mean of a plane over the cell centres in a footprint: the plane at their centroid
    for k in (0, 80, 159):
        ee, nn = np.meshgrid(west + np.arange(600) + 0.5, north - np.arange(600) - 0.5)
        inside = shapely.contains_xy(b.geometry[k], ee, nn)
        ce, cn = ee[inside].mean(), nn[inside].mean()
        assert ground[k] == pytest.approx(20.0 + 0.01 * (ce - 529000) - 0.02 * (cn - 182000))
    assert seconds < 5.0


def test_other_bad_arguments(dem):
    with pytest.raises(InputError, match=r"the DEM has no band 2 .*from 1 to 1"):
        sample_ground(dem, [500500.0], [200500.0], band=2)
    b = buildings_table(
        ["sq", "line"], [SQUARE, shapely.LineString([(500100, 200300), (500200, 200300)])]
    )
    with pytest.raises(InputError, match=r"1 feature\(s\) are not polygons \(LineString\): line"):
        building_ground(b, dem)
    with pytest.raises(InputError, match=r"in WGS 84 \(EPSG:4326\), not EPSG:27700"):
        building_ground(b.set_crs("EPSG:4326", allow_override=True), dem)
    with pytest.raises(InputError, match=r"must be a GeoDataFrame, not list"):
        building_ground([1, 2], dem)  # was an AttributeError


# --- heights in the units the DEM states (issue 26) ------------------------------------------


def write_stored_dem(path, units, per_unit, *, scale=1.0, offset=0.0, dtype="float64", crs=BNG):
    """The synthetic DEM stored as GDAL files hold heights: value = (metres / per_unit - offset)
    / scale, with the band's ``units`` (None: not stated), scale and offset."""
    cols, rows = np.meshgrid(np.arange(WIDTH), np.arange(HEIGHT))
    stored = plane(WEST + (cols + 0.5) * CELL, NORTH - (rows + 0.5) * CELL) / per_unit - offset
    stored /= scale
    with rasterio.open(
        path, "w", driver="GTiff", width=WIDTH, height=HEIGHT, count=1, dtype=dtype, crs=crs,
        transform=from_origin(WEST, NORTH, CELL, CELL),
    ) as ds:  # fmt: skip
        if units is not None:
            ds.units = (units,)
        ds.scales, ds.offsets = (scale,), (offset,)
        ds.write(np.round(stored) if dtype == "int16" else stored, 1)
    return path


@pytest.mark.parametrize(
    ("units", "per_unit"),
    [
        *[(u, 0.3048) for u in ("ft", "feet", "foot", "Foot", "international foot")],
        *[(u, 1200 / 3937) for u in ("US survey foot", "us-ft", "ftUS", "foot_us")],
        *[(u, 1.0) for u in (None, "", "m", "metre", "meter", "metres", "Meters")],
        ("cm", 0.01),
        ("mm", 0.001),
        ("dm", 0.1),
        ("km", 1000.0),
    ],
)
def test_heights_are_converted_from_the_units_the_dem_states(tmp_path, units, per_unit, rng):
    path = write_stored_dem(tmp_path / "dem.tif", units, per_unit)
    e, n = rng.uniform(500010, 500990, 50), rng.uniform(200210, 200990, 50)
    assert sample_ground(path, e, n) == pytest.approx(plane(e, n), abs=1e-9)
    ground = building_ground(buildings_table(["sq", "court"], [SQUARE, COURTYARD]), path)
    expected = [np.median(cells_under(SQUARE)), np.median(cells_under(COURTYARD))]
    assert ground["ground"].tolist() == pytest.approx(expected, abs=1e-9)


def test_the_band_scale_and_offset_are_applied(tmp_path, rng):
    # decimetres as int16 (scale 0.1), with an offset; and feet with a scale: GDAL's rule is
    # unit value = stored * scale + offset
    e, n = rng.uniform(500010, 500990, 50), rng.uniform(200210, 200990, 50)
    for units, per_unit, scale, offset in (("m", 1.0, 0.1, -5.0), ("ft", 0.3048, 0.5, 100.0)):
        path = write_stored_dem(
            tmp_path / f"{units}.tif", units, per_unit, scale=scale, offset=offset, dtype="int16"
        )
        half_step = scale * per_unit  # rounding to int16, then bilinear: within one step
        assert sample_ground(path, e, n) == pytest.approx(plane(e, n), abs=half_step)
        ground = building_ground(buildings_table(["sq"], [SQUARE]), path)["ground"]
        assert ground[0] == pytest.approx(np.median(cells_under(SQUARE)), abs=half_step)


@pytest.mark.parametrize("units", ["furlong", "dB", "degree", "hPa", "ft\n error: x", "m/s"])
def test_heights_in_units_not_of_length_are_refused(tmp_path, units):
    path = write_stored_dem(tmp_path / "dem.tif", units, 1.0)
    for read in (
        lambda: sample_ground(path, [500500.0], [200500.0]),
        lambda: building_ground(buildings_table(["sq"], [SQUARE]), path),
    ):
        with pytest.raises(InputError) as caught:
            read()
        message = caught.value.one_line()
        assert "dem.tif" in message and "gdal_edit.py -units m" in message, message
        assert escape_controls(units) in message and "\n" not in message


def test_a_compound_crs_must_hold_odn_heights_in_the_band_s_units(tmp_path):
    b = buildings_table(["sq"], [SQUARE])
    odn = write_stored_dem(tmp_path / "odn.tif", None, 1.0, crs="EPSG:27700+5701")
    assert building_ground(b, odn)["ground"][0] == pytest.approx(np.median(cells_under(SQUARE)))
    feet = write_stored_dem(tmp_path / "feet.tif", "ft", 0.3048, crs="EPSG:27700+5701")
    with pytest.raises(InputError, match=r"band says .*'ft' but its CRS says 'metre'"):
        building_ground(b, feet)
    navd = write_stored_dem(tmp_path / "navd.tif", "ft", 0.3048, crs="EPSG:27700+8228")
    with pytest.raises(InputError, match=r"NAVD88 height \(ft\), not ODN"):
        sample_ground(navd, [500500.0], [200500.0])
