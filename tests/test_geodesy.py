"""ETRS89 <-> BNG + ODN against the 40 Ordnance Survey test points; grids; meridian convergence."""

import hashlib
import json
import os
import subprocess
import sys
import textwrap

import numpy as np
import pandas as pd
import pytest
from pyproj import Geod

from gnss_citygml.geodesy import (
    GRID_DIR_ENV,
    GRIDS,
    GridError,
    OutsideExtentError,
    fetch_grids,
    from_osgb,
    grid_bearing,
    grid_status,
    meridian_convergence,
    to_osgb,
)

GRS80 = Geod(ellps="GRS80")


@pytest.fixture(scope="module")
def grid_dir(shared_data):
    return shared_data / "geodesy"


@pytest.fixture(scope="module")
def os_points(grid_dir):
    """The OS test inputs and expected outputs of both directions, one row per point."""
    etrs = pd.read_csv(grid_dir / "OSTN15_OSGM15_TestInput_ETRStoOSGB.txt")
    etrs.columns = ["point", "lat", "lon", "h"]
    osgb = pd.read_csv(grid_dir / "OSTN15_OSGM15_TestOutput_ETRStoOSGB.txt").iloc[:, :5]
    osgb.columns = ["point", "e", "n", "odn", "flag"]
    back_in = pd.read_csv(grid_dir / "OSTN15_OSGM15_TestInput_OSGBtoETRS.txt")
    back_in.columns = ["point", "e_in", "n_in", "odn_in"]
    back = pd.read_csv(grid_dir / "OSTN15_OSGM15_TestOutput_OSGBtoETRS.txt").iloc[:, :5]
    back.columns = ["point", "step", "lat_out", "lon_out", "h_out"]
    back = back[back["step"] == "RESULT"].drop(columns="step")
    table = etrs.merge(osgb, on="point").merge(back_in, on="point").merge(back, on="point")
    assert len(table) == 40
    return table


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
        ([51.5, 48.0], [-0.12, -3.0], "#1 (lat 48.000000, lon -3.000000)"),  # Brittany
        ([52.52, 51.5], [13.40, -0.12], "#0 (lat 52.520000, lon 13.400000)"),  # Berlin
        ([-0.12, 51.5], [51.5, -0.12], "#0 (lat -0.120000, lon 51.500000)"),  # lat/lon swapped
    ],
)
def test_outside_the_grids_is_an_error_naming_the_points(grid_dir, lat, lon, named):
    with pytest.raises(OutsideExtentError, match="1 point") as info:
        to_osgb(lat, lon, [50.0, 50.0], grid_dir=grid_dir)
    assert named in str(info.value)


def test_outside_the_grids_from_osgb(grid_dir):
    with pytest.raises(OutsideExtentError) as info:
        from_osgb([530000.0, -400000.0], [180000.0, 180000.0], [10.0, 10.0], grid_dir=grid_dir)
    assert "#1 (E -400000.000, N 180000.000)" in str(info.value)


def test_non_finite_coordinates_are_an_error(grid_dir):
    with pytest.raises(OutsideExtentError, match="non-finite") as info:
        to_osgb(
            [51.5, np.nan, 51.5], [-0.12, -0.12, -0.12], [50.0, 50.0, np.inf], grid_dir=grid_dir
        )
    assert "#1 (lat nan" in str(info.value) and "#2 (lat 51.5" in str(info.value)


def _isolated(code, tmp_path, endpoint=None):
    """Run ``code`` in a fresh interpreter whose PROJ user directory is ``tmp_path/user`` (so
    grids fetched on this machine do not count) and, if given, with another CDN endpoint."""
    env = dict(os.environ, PROJ_USER_WRITABLE_DIRECTORY=str(tmp_path / "user"))
    env.pop(GRID_DIR_ENV, None)
    if endpoint:
        env["PROJ_NETWORK_ENDPOINT"] = endpoint
    run = subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code)],
        env=env,
        capture_output=True,
        text=True,
        check=True,
    )
    return run.stdout.splitlines()


def test_missing_grids_name_the_files_and_how_to_get_them(grid_dir, tmp_path):
    """A run with the real grids first (so their folder is on PROJ's search path), then an
    empty grid folder must still fail, naming both files, instead of reusing the first."""
    empty = tmp_path / "empty"
    empty.mkdir()
    code = f"""
        from gnss_citygml.geodesy import GridError, grid_status, to_osgb
        print(to_osgb(51.5, -0.12, 60.0, grid_dir={str(grid_dir)!r})[2])
        print(grid_status({str(empty)!r}).to_json(orient="records"))
        try:
            to_osgb(51.5, -0.12, 60.0, grid_dir={str(empty)!r})
        except GridError as error:
            print(error)
    """
    first, status, message = _isolated(code, tmp_path)
    assert 14.0 < float(first) < 15.0  # ODN = 60 m - ~45.5 m of geoid in London
    assert [row["found"] for row in json.loads(status)] == [False, False]
    assert "missing PROJ grid(s) uk_os_OSTN15_NTv2_OSGBtoETRS.tif, uk_os_OSGM15_GB.tif" in message
    assert str(empty) in message and str(tmp_path / "user") in message
    assert "gnss-citygml grids --fetch" in message
    assert "projsync --file uk_os_OSGM15_GB.tif" in message


def test_network_fetches_missing_grids_into_the_user_directory(grid_dir, tmp_path):
    code = """
        from gnss_citygml.geodesy import grid_status, to_osgb
        print(to_osgb(51.48936564950, -0.11992557180, 66.057, network=True)[2])
        print(grid_status().to_json(orient="records"))
    """
    odn, status = _isolated(code, tmp_path, endpoint=_fake_cdn(tmp_path, grid_dir))
    assert float(odn) == pytest.approx(20.544, abs=2e-3)
    assert {row["source"] for row in json.loads(status)} == {"pyproj user data directory"}
    assert sorted(p.name for p in (tmp_path / "user").iterdir()) == sorted(GRIDS)


def test_network_unreachable_is_a_clear_error(tmp_path):
    code = """
        from gnss_citygml.geodesy import GridError, to_osgb
        try:
            to_osgb(51.5, -0.12, 60.0, network=True)
        except GridError as error:
            print(error)
    """
    (message,) = _isolated(code, tmp_path, endpoint=(tmp_path / "offline").as_uri())
    assert message.startswith("cannot read PROJ's grid catalogue")
    assert "--grid-dir" in message


def test_missing_grid_folder(tmp_path):
    with pytest.raises(GridError, match="does not exist"):
        to_osgb(51.5, -0.12, 60.0, grid_dir=tmp_path / "nowhere")


def test_grid_status_from_the_environment(grid_dir, monkeypatch):
    monkeypatch.setenv(GRID_DIR_ENV, str(grid_dir))
    status = grid_status()
    assert list(status["grid"]) == list(GRIDS)
    assert status["found"].all()
    assert set(status["source"]) == {f"${GRID_DIR_ENV}"}
    assert to_osgb(51.48936564950, -0.11992557180, 66.057)[2] == pytest.approx(20.544, abs=2e-3)


def _fake_cdn(tmp_path, grid_dir, checksums=None):
    """A local 'CDN' (file:// URL): the catalogue plus links to the real grid files."""
    cdn = tmp_path / "cdn"
    cdn.mkdir()
    features = []
    for name in GRIDS:
        (cdn / name).symlink_to(grid_dir / name)
        sha = hashlib.sha256((grid_dir / name).read_bytes()).hexdigest()
        sha = (checksums or {}).get(name, sha)
        features.append({"type": "Feature", "properties": {"name": name, "sha256": sha}})
    (cdn / "files.geojson").write_text(json.dumps({"features": features}))
    return cdn.as_uri()


def test_fetch_grids_downloads_and_checks(tmp_path, grid_dir):
    target = tmp_path / "grids"
    paths = fetch_grids(target, endpoint=_fake_cdn(tmp_path, grid_dir))
    assert [p.name for p in paths] == list(GRIDS)
    for path in paths:
        assert path.read_bytes() == (grid_dir / path.name).read_bytes()
    assert sorted(p.name for p in target.iterdir()) == sorted(GRIDS)  # no .part left
    assert grid_status(target)["source"].eq("grid_dir").all()
    assert to_osgb(51.48936564950, -0.11992557180, 66.057, grid_dir=target)[0] == pytest.approx(
        530624.974, abs=2e-3
    )


def test_fetch_grids_refuses_a_bad_checksum(tmp_path, grid_dir):
    endpoint = _fake_cdn(tmp_path, grid_dir, {"uk_os_OSGM15_GB.tif": "0" * 64})
    with pytest.raises(GridError, match="uk_os_OSGM15_GB.tif does not match its SHA-256"):
        fetch_grids(tmp_path / "grids", endpoint=endpoint)
    assert not (tmp_path / "grids" / "uk_os_OSGM15_GB.tif").exists()
    assert not (tmp_path / "grids" / "uk_os_OSGM15_GB.tif.part").exists()


def test_fetch_grids_unreachable_is_a_clear_error(tmp_path):
    with pytest.raises(GridError, match="cannot read PROJ's grid catalogue") as info:
        fetch_grids(tmp_path / "grids", endpoint=(tmp_path / "offline").as_uri())
    assert "--grid-dir" in str(info.value)


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
