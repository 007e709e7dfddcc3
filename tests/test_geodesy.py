"""ETRS89 <-> BNG + ODN against the 40 Ordnance Survey test points; meridian convergence;
every transformation of the toolkit (footprints in another CRS through `read_footprints`,
`estimate`, `convert`, `export`) on the one OSTN15/OSGM15 path, or the grid error. Where the
grids come from: test_grids.py."""

import contextlib
import io
import json
from pathlib import Path

import geopandas as gpd
import numpy as np
import pandas as pd
import pyproj
import pytest
import shapely
from conftest import commands, isolated
from pyproj import Geod

from gnss_citygml.cli import main
from gnss_citygml.errors import InputError
from gnss_citygml.footprints import read_footprints
from gnss_citygml.geodesy import (
    CrsError,
    OutsideExtentError,
    from_osgb,
    grid_bearing,
    meridian_convergence,
    to_bng,
    to_osgb,
)
from gnss_citygml.geodesy.grids import BUNDLED_GRID_DIR
from gnss_citygml.pipeline import receivers
from gnss_citygml.settings import ReceiverHeights

GRS80 = Geod(ellps="GRS80")
CITY = Path(__file__).resolve().parents[1] / "examples" / "city"


@pytest.fixture(scope="module")
def grid_dir():
    """The grids' folder given explicitly: the copy bundled with the package (byte for byte the
    reference data's, see test_the_bundled_grids_are_the_reference_files)."""
    return BUNDLED_GRID_DIR


def test_etrs_to_osgb_matches_all_40_os_points(os_points, grid_dir):
    e, n, odn = to_osgb(os_points["lat"], os_points["lon"], os_points["h"], grid_dir=grid_dir)
    horizontal = np.hypot(e - os_points["e"], n - os_points["n"])
    vertical = np.abs(odn - os_points["odn"])
    assert horizontal.max() < 0.008  # measured 7.8 mm (TP15): NTv2 vs OS's own interpolation
    assert vertical.max() < 0.002  # measured 1.96 mm (TP10): the resampled OSGM15 grid
    assert np.sqrt(np.mean(horizontal**2)) < 0.003
    # The islands (OS datum flag != 1) get the geoid too, not the ellipsoidal height.
    islands = os_points["flag"] != 1
    assert islands.sum() == 12
    assert np.all(np.abs(odn - os_points["h"])[islands] > 40.0)


def test_osgb_to_etrs_matches_all_40_os_points(os_points, grid_dir):
    lat, lon, h = from_osgb(
        os_points["e_in"], os_points["n_in"], os_points["odn_in"], grid_dir=grid_dir
    )
    *_, horizontal = GRS80.inv(lon, lat, os_points["lon_out"], os_points["lat_out"])
    assert np.max(horizontal) < 0.008  # measured 7.8 mm (TP15)
    assert np.max(np.abs(h - os_points["h_out"])) < 0.002  # measured 1.9 mm (TP10)


def test_round_trip_and_shapes(grid_dir):
    lat = np.array([[51.5246, 53.4808], [55.9533, 50.3755]])
    lon = np.array([[-0.1340, -2.2426], [-3.1883, -4.1427]])
    e, n, odn = to_osgb(lat, lon, 80.0, grid_dir=grid_dir)
    assert e.shape == n.shape == odn.shape == (2, 2)
    lat2, lon2, h2 = from_osgb(e, n, odn, grid_dir=grid_dir)
    np.testing.assert_allclose(lat2, lat, atol=1e-9)
    np.testing.assert_allclose(lon2, lon, atol=1e-9)
    np.testing.assert_allclose(h2, 80.0, atol=1e-4)


def test_missing_height_keeps_the_plan_position(grid_dir):
    e, n, odn = to_osgb(
        [51.48936564950] * 2, [-0.11992557180] * 2, [66.057, np.nan], grid_dir=grid_dir
    )
    assert e[1] == e[0] and n[1] == n[0]
    assert np.isfinite(odn[0]) and np.isnan(odn[1])


def test_spread_points_are_sorted_and_put_back(grid_dir, os_points):
    """All of Great Britain at once (the sorted path) gives the same as point by point."""
    args = os_points["lat"].to_numpy(), os_points["lon"].to_numpy(), os_points["h"].to_numpy()
    together = to_osgb(*args, grid_dir=grid_dir)
    one_by_one = [to_osgb(*(a[k : k + 1] for a in args), grid_dir=grid_dir) for k in range(40)]
    np.testing.assert_array_equal(np.concatenate(one_by_one, axis=1), np.array(together))


@pytest.mark.parametrize(
    ("lat", "lon", "named"),
    [
        ([51.5, 48.0], [-0.12, -3.0], "(point 1 (lat 48.000000, lon -3.000000))"),  # Brittany
        ([52.52, 51.5], [13.40, -0.12], "(point 0 (lat 52.520000, lon 13.400000))"),  # Berlin
        ([-0.12, 51.5], [51.5, -0.12], "(point 0 (lat -0.120000, lon 51.500000))"),  # swapped
    ],
)
def test_outside_the_grids_is_an_error_naming_the_points(grid_dir, lat, lon, named):
    with pytest.raises(OutsideExtentError, match="1 point") as info:
        to_osgb(lat, lon, [50.0, 50.0], grid_dir=grid_dir)
    assert named in str(info.value)


def test_outside_the_grids_from_osgb(grid_dir):
    with pytest.raises(OutsideExtentError) as info:
        from_osgb([530000.0, -400000.0], [180000.0, 180000.0], [10.0, 10.0], grid_dir=grid_dir)
    assert "(point 1 (E -400000.000, N 180000.000))" in str(info.value)


def test_errors_name_points_by_the_callers_labels(grid_dir):
    """A caller's labels (an observation's receiver and time, a footprint's id) name the
    points, each label once however many of its points are bad, never an index "#0"."""
    labels = ["footprint a", "footprint a", "footprint b", "footprint a", "footprint c"]
    lat, lon = [48.0, 48.1, 48.2, 51.5, 52.0], [-3.0, -3.0, -3.0, -0.12, 13.4]
    with pytest.raises(OutsideExtentError, match=r"^4 point\(s\) outside") as info:
        to_osgb(lat, lon, np.nan, grid_dir=grid_dir, labels=labels)
    assert info.value.where == (
        "footprint a (lat 48.000000, lon -3.000000), footprint b (lat 48.200000, lon -3.000000), "
        "footprint c (lat 52.000000, lon 13.400000)"
    )
    assert "#" not in str(info.value) and "point 0" not in str(info.value)
    with pytest.raises(OutsideExtentError, match=r"non-finite.*\(receiver B at 10:00:02 \(E nan"):
        from_osgb(
            [530000.0, np.nan], [180000.0, 180000.0], 0.0,
            grid_dir=grid_dir, labels=["receiver A at 10:00:00", "receiver B at 10:00:02"],
        )  # fmt: skip


def test_labels_of_another_length_are_an_input_error(grid_dir):
    """Labels that do not match the points one for one are the caller's mistake, said in one
    line (was an IndexError); a few of many bad points are named, the others counted."""
    with pytest.raises(InputError, match=r"^3 labels for 20 points \(labels\)"):
        to_osgb(np.full(20, 48.0), np.full(20, -3.0), np.nan, grid_dir=grid_dir, labels=list("abc"))
    with pytest.raises(OutsideExtentError, match=r"point 0 \(.*point 4 \(.* and 99995 more"):
        to_osgb(np.full(100_000, 48.0), np.full(100_000, -3.0), np.nan, grid_dir=grid_dir)


def test_non_finite_coordinates_are_an_error(grid_dir):
    with pytest.raises(OutsideExtentError, match="non-finite") as info:
        to_osgb(
            [51.5, np.nan, 51.5], [-0.12, -0.12, -0.12], [50.0, 50.0, np.inf], grid_dir=grid_dir
        )
    assert "point 1 (lat nan" in str(info.value) and "point 2 (lat 51.5" in str(info.value)


def test_meridian_convergence_sign_with_a_point_due_north(grid_dir):
    """1 km due true north of Gower Street: its grid bearing is -convergence (~1.46 deg)."""
    lat, lon = 51.5246, -0.1340
    lon2, lat2, _ = GRS80.fwd(lon, lat, 0.0, 1000.0)
    e, n, _ = to_osgb([lat, lat2], [lon, lon2], [50.0, 50.0], grid_dir=grid_dir)
    measured = np.degrees(np.arctan2(e[1] - e[0], n[1] - n[0]))
    convergence = meridian_convergence(lat, lon)
    assert 1.4 < convergence < 1.5  # (2 deg W - 0.134 deg W) x sin(51.5 deg)
    assert measured == pytest.approx(-convergence, abs=0.002)
    assert grid_bearing(lat, lon, 0.0) == pytest.approx(360.0 + measured, abs=0.002)
    # 100 m along the ray, ignoring the convergence moves it sideways by ~2.5 m.
    assert 100.0 * np.radians(convergence) == pytest.approx(2.55, abs=0.05)
    # West of the central meridian the sign flips.
    assert meridian_convergence(51.5, -4.0) < 0.0


# --- every transformation through the grids -----------------------------------------------------

#: CRSs on WGS 84 / ETRS89 (taken as ETRS89), as EPSG codes, OGC, ESRI WKT and PROJ strings.
ETRS89_LIKE = [
    "EPSG:4326",
    "EPSG:4258",
    "OGC:CRS84",
    "EPSG:4979",
    "EPSG:32630",
    "EPSG:25830",
    "EPSG:3857",
    pyproj.CRS("EPSG:32630").to_wkt("WKT1_ESRI"),
    "+proj=longlat +datum=WGS84 +no_defs",
]


def in_crs(e, n, crs, grid_dir):
    """BNG coordinates in a CRS on ETRS89 or WGS 84, made as a user's data would be: OSTN15 to
    ETRS89 latitude and longitude, then the CRS's own projection (no datum change)."""
    lat, lon, _ = from_osgb(e, n, 0.0, grid_dir=grid_dir)
    crs = pyproj.CRS(crs)
    return pyproj.Transformer.from_crs(crs.geodetic_crs, crs, always_xy=True).transform(lon, lat)


@pytest.mark.parametrize("crs", ETRS89_LIKE, ids=lambda c: c.split("[")[0][:30])
def test_to_bng_through_ostn15_within_a_millimetre(os_points, grid_dir, crs):
    """All 40 OS test points, Scilly to Shetland, back from the CRS to within 1 mm."""
    e, n = os_points["e"].to_numpy(), os_points["n"].to_numpy()
    x, y = in_crs(e, n, crs, grid_dir)
    e2, n2 = to_bng(x, y, crs, grid_dir=grid_dir)
    assert np.hypot(e2 - e, n2 - n).max() < 1e-3


def test_to_bng_from_osgb36_is_a_conversion(os_points):
    """OSGB36 latitude and longitude, or BNG bound to WGS 84 by a PROJ string's +towgs84 (a
    Helmert that must not be used), reach BNG without any grid."""
    e, n = os_points["e"].to_numpy(), os_points["n"].to_numpy()
    lon, lat = pyproj.Transformer.from_crs("EPSG:27700", "EPSG:4277", always_xy=True).transform(
        e, n
    )
    e2, n2 = to_bng(lon, lat, "EPSG:4277", grid_dir="/nonexistent")  # never looked at
    assert np.hypot(e2 - e, n2 - n).max() < 1e-6
    bound = (
        "+proj=tmerc +lat_0=49 +lon_0=-2 +k=0.9996012717 +x_0=400000 +y_0=-100000 +ellps=airy "
        "+towgs84=446.448,-125.157,542.06,0.15,0.247,0.842,-20.489 +units=m +no_defs"
    )
    assert np.array_equal(to_bng(e, n, bound, grid_dir="/nonexistent"), (e, n))
    assert np.array_equal(to_bng(e, n, "EPSG:7405"), (e, n))


@pytest.mark.parametrize(
    ("crs", "named"),
    [
        ("EPSG:23030", "ED50 / UTM zone 30N (datum European Datum 1950)"),
        ("EPSG:29903", "TM75 / Irish Grid"),
        ("EPSG:9057", "WGS 84 (G1762) (datum World Geodetic System 1984 (G1762))"),
        ("+proj=longlat +ellps=WGS84 +no_defs", "datum Unknown based on WGS 84 ellipsoid"),
    ],
)
def test_to_bng_refuses_a_datum_without_a_grid(grid_dir, crs, named):
    """PROJ would take a Helmert (ED50: "OSGB36 to ED50 (1)", 2 m) or ballpark transformation."""
    with pytest.raises(CrsError, match="no exact transformation from") as info:
        to_bng([500000.0], [5700000.0], crs, grid_dir=grid_dir)
    message = str(info.value)
    assert named in message and "EPSG:4258, EPSG:4326 or EPSG:27700" in message


def test_receivers_outside_the_grids_are_named_by_receiver_and_time(grid_dir):
    obs = pd.DataFrame(
        {
            "time_utc": pd.to_datetime(["2020-06-01 10:00:00", "2020-06-01 10:00:01"]),
            "receiver": ["phone1", "phone2"],
            "lat": [51.5, 48.0],
            "lon": [-0.12, -3.0],
            "h": [60.0, 60.0],
            "azimuth": [10.0, 20.0],
        }
    )
    with pytest.raises(OutsideExtentError) as info:
        receivers(obs, heights=ReceiverHeights(source="log"), grid_dir=grid_dir)
    assert (
        info.value.where == "receiver phone2 at 2020-06-01 10:00:01 (lat 48.000000, lon -3.000000)"
    )


@pytest.fixture(scope="module")
def city(tmp_path_factory, grid_dir):
    """The bundled city's footprints in EPSG:27700 and, made from them with OSTN15, in
    EPSG:4326, EPSG:4258 and EPSG:32630; its heights (`estimate` on the BNG footprints) as a
    layer in each CRS and as a CSV table; its model by `convert` and by `export` from BNG."""
    folder = tmp_path_factory.mktemp("city")
    bng = read_footprints(CITY / "footprints.gpkg")
    code, out, err = _run_main(
        ["estimate", CITY / "observations.parquet", CITY / "footprints.gpkg", "--dem",
         CITY / "dem.tif", "-o", folder / "heights.gpkg", "--grid-dir", grid_dir, "-q"]
    )  # fmt: skip
    assert code == 0, err
    heights = gpd.read_file(folder / "heights.gpkg", layer="heights")
    heights.drop(columns="geometry").to_csv(folder / "heights.csv", index=False)
    xy = shapely.get_coordinates(bng.geometry.to_numpy())
    for crs in ("EPSG:4326", "EPSG:4258", "EPSG:32630"):
        name = crs.replace(":", "")
        moved = np.column_stack(in_crs(xy[:, 0], xy[:, 1], crs, grid_dir))
        geoms = shapely.set_coordinates(bng.geometry.to_numpy().copy(), moved)
        bng.set_geometry(geoms, crs=crs).to_file(folder / f"footprints_{name}.gpkg")
        heights.set_geometry(geoms, crs=crs).to_file(folder / f"heights_{name}.gpkg")
    for args in (
        ["convert", folder / "heights.gpkg", "-o", folder / "convert.city.json"],
        ["export", folder / "heights.csv", "--footprints", CITY / "footprints.gpkg", "-o",
         folder / "export.city.json"],
    ):  # fmt: skip
        assert _run_main([*args, "-q"])[0] == 0
    return folder


def _run_main(args):
    """``gnss-citygml ARGS`` in this process: exit code, stdout, stderr."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        with pytest.raises(SystemExit) as exit_:
            main([str(a) for a in args])
    return exit_.value.code, out.getvalue(), err.getvalue()


def test_read_footprints_in_other_crs_within_a_millimetre(city, grid_dir, unbundled, tmp_path):
    """In a fresh interpreter (no grid on PROJ's path yet, as for a user), and without the
    grids (an install without its bundled copy) the grid error, never PROJ's 2 m Helmert
    transformation (1.805 m before)."""
    empty = tmp_path / "empty"
    empty.mkdir()
    code = f"""
        import numpy as np, shapely
        from gnss_citygml.footprints import read_footprints
        from gnss_citygml.geodesy.grids import GridError
        try:
            read_footprints({str(city / "footprints_EPSG4326.gpkg")!r}, grid_dir={str(empty)!r})
        except GridError as error:
            print(error)
        bng = read_footprints({str(CITY / "footprints.gpkg")!r})
        for name in ("EPSG4326", "EPSG4258", "EPSG32630"):
            path = {str(city)!r} + f"/footprints_{{name}}.gpkg"
            got = read_footprints(path, grid_dir={str(grid_dir)!r})
            assert got["id"].tolist() == bng["id"].tolist() and got.crs == bng.crs
            d = shapely.get_coordinates(got.geometry) - shapely.get_coordinates(bng.geometry)
            print(np.hypot(*d.T).max())
    """
    message, *moved = isolated(code, tmp_path, package=unbundled)
    assert message.startswith("missing PROJ grid(s) uk_os_OSTN15_NTv2_OSGBtoETRS.tif")
    assert str(empty) in message
    assert len(moved) == 3 and max(map(float, moved)) < 1e-3


def test_estimate_with_footprints_in_wgs84_gives_the_same_heights(city, grid_dir, tmp_path):
    """24 buildings converge with either footprints, the same heights."""
    out = tmp_path / "heights.gpkg"
    args = ["estimate", CITY / "observations.parquet", city / "footprints_EPSG4326.gpkg",
            "--dem", CITY / "dem.tif", "-o", out, "--grid-dir", grid_dir, "-q"]  # fmt: skip
    ((code, stdout, err),) = commands([args], tmp_path)
    assert code == 0, err
    assert stdout.startswith("24 of 30 buildings have a height")
    got = gpd.read_file(out, layer="heights")
    want = gpd.read_file(city / "heights.gpkg", layer="heights")
    assert got["id"].tolist() == want["id"].tolist()
    d = shapely.get_coordinates(got.geometry) - shapely.get_coordinates(want.geometry)
    assert np.hypot(*d.T).max() < 1e-3
    assert got["converged"].tolist() == want["converged"].tolist()
    np.testing.assert_allclose(got["height"], want["height"], atol=1e-3)


def _model(path):
    """A CityJSON file's extent and its vertices in metres."""
    model = json.loads(path.read_text())
    scale, shift = np.array(model["transform"]["scale"]), np.array(model["transform"]["translate"])
    vertices = np.array(model["vertices"]) * scale + shift
    return np.array(model["metadata"]["geographicalExtent"]), vertices


def test_convert_and_export_footprints_in_other_crs_within_a_millimetre(city, grid_dir, tmp_path):
    """The models' extents and vertices as from the BNG footprints (1.79 m off before: the
    commands had no grid option). All runs in one fresh interpreter."""
    runs, outputs, references = [], [], []
    for crs in ("EPSG4326", "EPSG4258", "EPSG32630"):
        outputs.append(tmp_path / f"convert_{crs}.city.json")
        runs.append(["convert", city / f"heights_{crs}.gpkg", "-o", outputs[-1]])
        references.append(city / "convert.city.json")
    outputs.append(tmp_path / "export_EPSG4326.city.json")
    fp = city / "footprints_EPSG4326.gpkg"
    runs.append(["export", city / "heights.csv", "--footprints", fp, "-o", outputs[-1]])
    references.append(city / "export.city.json")
    results = commands([[*args, "--grid-dir", grid_dir, "-q"] for args in runs], tmp_path)
    for (code, _, err), got, want in zip(results, outputs, references, strict=True):
        assert code == 0, err
        (extent, vertices), (extent0, vertices0) = _model(got), _model(want)
        assert np.abs(extent - extent0).max() <= 1e-3 + 1e-9, got.name  # the files' millimetre
        assert np.abs(vertices - vertices0).max() <= 1e-3 + 1e-9, got.name


def test_commands_without_the_grids_are_the_grid_error(city, unbundled, tmp_path):
    """No grid folder, or an empty one, no PROJ user grids and an install without its bundled
    copy: one error line, no output."""
    empty = tmp_path / "empty"
    empty.mkdir()
    fp = city / "footprints_EPSG4326.gpkg"
    outputs = [tmp_path / "convert.city.json", tmp_path / "export.city.json", tmp_path / "h.gpkg"]
    runs = [
        ["convert", city / "heights_EPSG4326.gpkg", "--grid-dir", empty],
        ["export", city / "heights.csv", "--footprints", fp],
        ["estimate", CITY / "observations.parquet", fp, "--dem", CITY / "dem.tif"],
    ]
    results = commands(
        [[*a, "-o", out, "-q"] for a, out in zip(runs, outputs, strict=True)],
        tmp_path,
        package=unbundled,
    )
    for (code, stdout, err), out in zip(results, outputs, strict=True):
        assert code == 2 and stdout == "", out.name
        assert err.startswith("error: missing PROJ grid(s) uk_os_OSTN15_NTv2_OSGBtoETRS.tif")
        assert "gnss-citygml grids --fetch" in err and len(err.splitlines()) == 1
        assert not out.exists()
