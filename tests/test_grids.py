"""Where the OSTN15/OSGM15 grids come from (gnss_citygml.geodesy.grids): the bundled copy,
searched last after --grid-dir, $GNSS_CITYGML_GRID_DIR and PROJ's folders; downloads;
`gnss-citygml grids`. Each search is checked in a fresh interpreter (conftest.isolated), as a
user's run starts."""

import hashlib
import json
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest
import rasterio
from conftest import commands, isolated

from gnss_citygml.geodesy import to_osgb
from gnss_citygml.geodesy.grids import (
    BUNDLED_GRID_DIR,
    GRID_DIR_ENV,
    GRIDS,
    GridError,
    fetch_grids,
    grid_status,
)

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))
import pack_grids  # noqa: E402


@pytest.fixture(scope="module")
def grid_dir():
    """The grids' folder given explicitly: the copy bundled with the package."""
    return BUNDLED_GRID_DIR


def test_the_bundled_grids_are_the_reference_files(shared_data):
    """PROJ-data's files re-encoded by tools/pack_grids.py: the size and checksum their README
    gives; the geoid's values bit for bit the reference data's, the OSTN15 shifts exactly the
    tool's steps of the reference, each within half a step; the same extent, CRS, bands, units
    and grid type; with Ordnance Survey's notice."""
    readme = (BUNDLED_GRID_DIR / "README.md").read_text()
    for name in GRIDS:
        data = (BUNDLED_GRID_DIR / name).read_bytes()
        assert f"`{name}` | {len(data)} | `{hashlib.sha256(data).hexdigest()}`" in readme
        assert len(data) < 2_000_000
    with (
        rasterio.open(BUNDLED_GRID_DIR / pack_grids.GEOID) as ours,
        rasterio.open(shared_data / "geodesy" / pack_grids.GEOID) as ref,
    ):
        assert np.array_equal(ours.read().view(np.uint32), ref.read().view(np.uint32))
        assert (ours.crs, ours.transform, ours.nodata) == (ref.crs, ref.transform, ref.nodata)
        assert (ours.descriptions, ours.units) == (ref.descriptions, ref.units)
        kept = {k: v for k, v in ref.tags().items() if k != "TIFFTAG_IMAGEDESCRIPTION"}
        assert kept.items() <= ours.tags().items() and kept["TYPE"].startswith("VERTICAL_OFFSET")
    reference = shared_data / "geodesy" / pack_grids.NAME
    steps, scales = pack_grids.quantised(reference)
    with (
        rasterio.open(BUNDLED_GRID_DIR / pack_grids.NAME) as ours,
        rasterio.open(reference) as ref,
    ):
        assert np.array_equal(ours.read(), steps) and list(ours.scales) == scales
        assert (ours.crs, ours.transform, ours.shape) == (ref.crs, ref.transform, ref.shape)
        assert (ours.descriptions, ours.units) == (ref.descriptions, ref.units)
        assert ours.tags()["TYPE"] == ref.tags()["TYPE"] == "HORIZONTAL_OFFSET"
        shifts = ours.read(masked=False).astype(float) * np.array(scales)[:, None, None]
        error = np.abs(shifts - ref.read()).max(axis=(1, 2))
        assert (error <= np.array(scales) / 2 * (1 + 1e-6)).all()
    notice = (BUNDLED_GRID_DIR / "LICENSE").read_text()
    assert "Ordnance Survey Limited 2016" in notice and "2. Redistributions in binary" in notice


_POSITIONS = """
    import json, numpy as np
    from pyproj import Transformer
    from pyproj.datadir import append_data_dir
    append_data_dir({folder!r})
    t = Transformer.from_crs("EPSG:4258", "EPSG:27700", always_xy=True, allow_ballpark=False)
    assert "uk_os_OSTN15_NTv2_OSGBtoETRS.tif" in t.definition
    rng = np.random.default_rng(1)
    lat, lon = np.sort(rng.uniform(49.5, 60.9, 200_000)), rng.uniform(-8.9, 1.9, 200_000)
    print(json.dumps(np.column_stack(t.transform(lon, lat)).tolist()))
"""


def test_the_bundled_shifts_move_positions_by_under_a_fifth_of_a_millimetre(shared_data, tmp_path):
    """Through PROJ (a fresh interpreter per grid: PROJ takes the first file of a name on its
    path), 200,000 points over the grid's extent land within 0.2 mm of where PROJ-data's own
    file puts them."""
    moved = [
        np.array(json.loads(isolated(_POSITIONS.format(folder=str(folder)), tmp_path / label)[0]))
        for label, folder in (("ours", BUNDLED_GRID_DIR), ("ref", shared_data / "geodesy"))
    ]
    distance = np.hypot(*(moved[0] - moved[1]).T)
    assert np.isfinite(distance).all() and distance.max() < 0.0002


def test_a_user_without_grids_gets_the_bundled_copy(os_points, tmp_path):
    """An empty home, no grid folder, nothing in PROJ's user folder (fresh interpreter): the
    bundled grids are used, and match all 40 OS test points."""
    points = [os_points[c].tolist() for c in ("lat", "lon", "h")]
    code = f"""
        import json
        from gnss_citygml.geodesy import to_osgb
        from gnss_citygml.geodesy.grids import grid_status
        print(grid_status().to_json(orient="records"))
        print(json.dumps([a.tolist() for a in to_osgb(*{points!r})]))
    """
    status, result = isolated(code, tmp_path)
    status = json.loads(status)
    assert [row["source"] for row in status] == ["bundled with gnss-citygml"] * 2
    assert [row["path"] for row in status] == [str(BUNDLED_GRID_DIR / name) for name in GRIDS]
    e, n, odn = map(np.array, json.loads(result))
    assert np.hypot(e - os_points["e"], n - os_points["n"]).max() < 0.008  # as with grid_dir
    assert np.abs(odn - os_points["odn"]).max() < 0.002


def test_an_explicit_grid_dir_wins_over_the_bundled_copy(shared_data, tmp_path):
    """grid_dir's copy is the one PROJ uses: a good copy there is reported and gives TP09; a
    wrong geoid there (Malin Head's, under the GB geoid's name) is refused by the TP09 check,
    never quietly replaced by the bundled copy."""
    good, wrong = tmp_path / "good", tmp_path / "wrong"
    for folder in (good, wrong):
        folder.mkdir()
        shutil.copy(BUNDLED_GRID_DIR / "uk_os_OSTN15_NTv2_OSGBtoETRS.tif", folder)
    shutil.copy(BUNDLED_GRID_DIR / "uk_os_OSGM15_GB.tif", good)
    shutil.copy(shared_data / "geodesy" / "uk_os_OSGM15_Malin.tif", wrong / "uk_os_OSGM15_GB.tif")
    tp09 = "51.48936564950, -0.11992557180, 66.057"
    code = f"""
        from gnss_citygml.geodesy import to_osgb
        from gnss_citygml.geodesy.grids import GridError, grid_status
        print(grid_status({str(good)!r}).to_json(orient="records"))
        print(to_osgb({tp09}, grid_dir={str(good)!r})[2])
    """
    status, odn = isolated(code, tmp_path / "1")
    assert [row["path"] for row in json.loads(status)] == [str(good / name) for name in GRIDS]
    assert {row["source"] for row in json.loads(status)} == {"grid_dir"}
    assert float(odn) == pytest.approx(20.544, abs=2e-3)
    code = f"""
        from gnss_citygml.geodesy import to_osgb
        from gnss_citygml.geodesy.grids import GridError
        try:
            print(to_osgb({tp09}, grid_dir={str(wrong)!r})[2])
        except GridError as error:
            print(error)
    """
    (message,) = isolated(code, tmp_path / "2")
    assert message.startswith("the grids do not reproduce Ordnance Survey test point TP09")


def test_missing_grids_name_the_files_and_how_to_get_them(grid_dir, unbundled, tmp_path):
    """An install that lost its bundled grids: a run with the real grids first (so their
    folder is on PROJ's search path), then an empty grid folder must still fail, naming both
    files, instead of reusing the first."""
    empty = tmp_path / "empty"
    empty.mkdir()
    code = f"""
        from gnss_citygml.geodesy import to_osgb
        from gnss_citygml.geodesy.grids import GridError, grid_status
        print(to_osgb(51.5, -0.12, 60.0, grid_dir={str(grid_dir)!r})[2])
        print(grid_status({str(empty)!r}).to_json(orient="records"))
        try:
            to_osgb(51.5, -0.12, 60.0, grid_dir={str(empty)!r})
        except GridError as error:
            print(error)
    """
    first, status, message = isolated(code, tmp_path, package=unbundled)
    assert 14.0 < float(first) < 15.0  # ODN = 60 m - ~45.5 m of geoid in London
    assert [row["found"] for row in json.loads(status)] == [False, False]
    assert "missing PROJ grid(s) uk_os_OSTN15_NTv2_OSGBtoETRS.tif, uk_os_OSGM15_GB.tif" in message
    assert str(empty) in message and str(tmp_path / "user") in message
    assert f"{unbundled / 'gnss_citygml' / 'data' / 'grids'} (bundled with gnss-citygml)" in message
    assert "reinstall gnss-citygml" in message and "gnss-citygml grids --fetch" in message
    assert "projsync --file uk_os_OSGM15_GB.tif" in message


def test_network_fetches_missing_grids_into_the_user_directory(grid_dir, unbundled, tmp_path):
    code = """
        from gnss_citygml.geodesy import to_osgb
        from gnss_citygml.geodesy.grids import grid_status
        print(to_osgb(51.48936564950, -0.11992557180, 66.057, network=True)[2])
        print(grid_status().to_json(orient="records"))
    """
    odn, status = isolated(
        code, tmp_path, endpoint=_fake_cdn(tmp_path, grid_dir), package=unbundled
    )
    assert float(odn) == pytest.approx(20.544, abs=2e-3)
    assert {row["source"] for row in json.loads(status)} == {"pyproj user data directory"}
    assert sorted(p.name for p in (tmp_path / "user").iterdir()) == sorted(GRIDS)


def test_network_is_not_used_while_the_bundled_grids_are_there(tmp_path):
    """network=True with the CDN unreachable: the bundled grids, no download, no error."""
    code = """
        from gnss_citygml.geodesy import to_osgb
        print(to_osgb(51.48936564950, -0.11992557180, 66.057, network=True)[2])
    """
    (odn,) = isolated(code, tmp_path, endpoint=(tmp_path / "offline").as_uri())
    assert float(odn) == pytest.approx(20.544, abs=2e-3)
    assert not (tmp_path / "user").exists() or not list((tmp_path / "user").iterdir())


def test_network_unreachable_is_a_clear_error(unbundled, tmp_path):
    code = """
        from gnss_citygml.geodesy import to_osgb
        from gnss_citygml.geodesy.grids import GridError
        try:
            to_osgb(51.5, -0.12, 60.0, network=True)
        except GridError as error:
            print(error)
    """
    (message,) = isolated(
        code, tmp_path, endpoint=(tmp_path / "offline").as_uri(), package=unbundled
    )
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


def test_grids_says_which_copy_is_used(unbundled, tmp_path):
    """`gnss-citygml grids` for a user without grids (the bundled copy), with --grid-dir (that
    folder's copy), and in an install without its bundled copy (exit 1, both missing)."""
    copy, empty = tmp_path / "copy", tmp_path / "empty"
    shutil.copytree(BUNDLED_GRID_DIR, copy)
    empty.mkdir()
    bundled, given = commands([["grids"], ["grids", "--grid-dir", copy]], tmp_path / "1")
    assert bundled[0] == given[0] == 0
    for name, purpose in GRIDS.items():
        line = f"{name}  {purpose}: {BUNDLED_GRID_DIR / name} (bundled with gnss-citygml)"
        assert line in bundled[1].splitlines()
        assert f"{name}  {purpose}: {copy / name} (grid_dir)" in given[1].splitlines()
    ((code, out, err),) = commands([["grids", "--grid-dir", empty]], tmp_path / "2", unbundled)
    assert code == 1 and out.count("MISSING") == 2
    assert "reinstall gnss-citygml" in err and "grids --fetch" in err
