"""`gnss-citygml update` (issue 13): a GeoPackage map kept up to date in place, never at risk.

A map here is the sample city's footprints with a second layer, a style, a column of the
user's own, and two halves of the observations arriving one after the other."""

import contextlib
import hashlib
import io
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pyogrio
import pytest
import shapely
from test_cli import run

from gnss_citygml.errors import InputError
from gnss_citygml.files.paths import stale_parts
from gnss_citygml.footprints import read_footprints
from gnss_citygml.pipeline import run as run_pipeline
from gnss_citygml.settings import Calibration, Estimator, PositionError, RunSettings, Tiling
from gnss_citygml.update import COLUMNS, EVIDENCE, update_map

CITY = Path(__file__).resolve().parents[1] / "examples" / "city"
DEM = str(CITY / "dem.tif")


def digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture(scope="module")
def halves(tmp_path_factory):
    """The observations of the first four walkers, and of the other four."""
    folder = tmp_path_factory.mktemp("obs")
    obs = pd.read_parquet(CITY / "observations.parquet")
    first = obs["receiver"].isin(sorted(obs["receiver"].unique())[:4])
    obs[first].to_parquet(folder / "a.parquet")
    obs[~first].to_parquet(folder / "b.parquet")
    return folder / "a.parquet", folder / "b.parquet"


@pytest.fixture
def city_map(tmp_path):
    """The map: footprints with a column of the user's, a second layer and a style."""
    path = tmp_path / "map.gpkg"
    footprints = pyogrio.read_dataframe(CITY / "footprints.gpkg")
    footprints["owner"] = [f"owner {i}" for i in range(len(footprints))]
    pyogrio.write_dataframe(footprints, path, layer="buildings")
    roads = footprints.iloc[:3].assign(geometry=shapely.centroid(footprints.geometry[:3]))
    pyogrio.write_dataframe(roads, path, layer="points")
    from gnss_citygml.files.styles import save_default_style

    save_default_style(path, "buildings", "<qgis mine='1'/>")
    return path


def layer_rows(path: Path, layer: str) -> list[tuple]:
    with contextlib.closing(sqlite3.connect(path)) as db:
        return db.execute(f'SELECT * FROM "{layer}" ORDER BY 1').fetchall()


def test_columns_added_and_everything_else_kept(city_map, halves, grid_dir):
    before = {name: layer_rows(city_map, name) for name in ("buildings", "points", "layer_styles")}
    original = digest(city_map)
    result = update_map(city_map, [halves[0]], DEM, layer="buildings", grid_dir=grid_dir)
    assert result.written and result.new_signals > 0 and result.new_evidence > 0
    assert digest(result.backup) == original  # MAP.gpkg.bak: the map as it was
    layers = dict(pyogrio.list_layers(city_map))
    assert {"buildings", "points", "layer_styles", EVIDENCE} <= set(layers)
    assert layers[EVIDENCE] is None  # an attribute table: GDAL (and QGIS) list it
    assert layer_rows(city_map, "points") == before["points"]
    assert layer_rows(city_map, "layer_styles") == before["layer_styles"]
    after = layer_rows(city_map, "buildings")
    n_old = len(before["buildings"][0])
    assert [row[:n_old] for row in after] == before["buildings"]  # fids, geometry, owner
    table = pyogrio.read_dataframe(city_map, layer="buildings", read_geometry=False)
    assert list(table.columns[-len(COLUMNS) :]) == list(COLUMNS)
    assert table["converged"].sum() > 10 and table["height_gnss"].notna().sum() > 10
    assert (table["method"] == "4PL-B").all() and table["updated_utc"].notna().all()


def test_two_updates_equal_one_run_over_all_observations(city_map, halves, grid_dir, tmp_path):
    for half in halves:
        update_map(city_map, [half], DEM, layer="buildings", grid_dir=grid_dir)
    both = tmp_path / "both.parquet"
    pd.concat([pd.read_parquet(h) for h in halves], ignore_index=True).to_parquet(both)
    full = tmp_path / "full.gpkg"
    grids = [] if grid_dir is None else ["--grid-dir", str(grid_dir)]
    args = ["estimate", str(both), str(CITY / "footprints.gpkg"), "--dem", DEM, "-o", str(full)]
    assert (
        subprocess.run([sys.executable, "-m", "gnss_citygml", *args, *grids, "-q"]).returncode == 0
    )
    ours = pyogrio.read_dataframe(city_map, layer="buildings", read_geometry=False).set_index("id")
    theirs = pyogrio.read_dataframe(full, layer="heights", read_geometry=False).set_index("id")
    theirs = theirs.loc[ours.index]
    assert (ours["converged"].astype(bool) == theirs["converged"].astype(bool)).all()
    pairs = [("height_gnss", "height"), ("height_lower", "height_lower"),
             ("height_upper", "height_upper"), ("height_paper", "height_paper"),
             ("c_gnss", "c"), ("n_signals", "n_signals")]  # fmt: skip
    for mine, full_run in pairs:
        np.testing.assert_allclose(ours[mine], theirs[full_run], rtol=0, atol=1e-9)
    assert (ours["status_gnss"] == theirs["status"]).all()


def test_updates_with_the_mixture_equal_one_run(city_map, halves, grid_dir):
    """The mixture signal model learns from every signal cast, those that cross no footprint
    too: the evidence keeps them, so two updates give one run's heights."""
    estimator = Estimator(signal_model="mixture")
    for half in halves:
        update_map(city_map, [half], DEM, layer="buildings", grid_dir=grid_dir, estimator=estimator)
    both = pd.concat([pd.read_parquet(h) for h in halves], ignore_index=True)
    full = run_pipeline(
        both, read_footprints(CITY / "footprints.gpkg"), DEM, estimator=estimator, grid_dir=grid_dir
    ).heights.set_index("id")
    ours = pyogrio.read_dataframe(city_map, layer="buildings", read_geometry=False).set_index("id")
    full = full.loc[ours.index]
    assert full["converged"].sum() >= 10
    assert (ours["converged"].astype(bool) == full["converged"].astype(bool)).all()
    for mine, theirs in (("height_gnss", "height"), ("height_lower", "height_lower")):
        np.testing.assert_allclose(ours[mine], full[theirs], rtol=0, atol=1e-3)


def test_the_same_data_again_changes_nothing(city_map, halves, grid_dir, capsys):
    update_map(city_map, [halves[0]], DEM, layer="buildings", grid_dir=grid_dir)
    city_map.with_name("map.bak.gpkg").unlink()
    first = digest(city_map)
    stamps = pyogrio.read_dataframe(city_map, layer="buildings", read_geometry=False)
    result = update_map(city_map, [halves[0]], DEM, layer="buildings", grid_dir=grid_dir)
    assert result.new_signals == 0 and not result.written and result.updated.empty
    assert digest(city_map) == first and not city_map.with_name("map.bak.gpkg").exists()
    # a new half updates only the buildings it changes; the others keep their time
    update_map(city_map, [halves[1]], DEM, layer="buildings", grid_dir=grid_dir)
    later = pyogrio.read_dataframe(city_map, layer="buildings", read_geometry=False)
    same = later["height_gnss"].fillna(-1) == stamps["height_gnss"].fillna(-1)
    kept = later["updated_utc"] == stamps["updated_utc"]
    assert (kept[same & (later["n_signals"] == stamps["n_signals"])]).all()


def test_dry_run_and_no_backup(city_map, halves, grid_dir, capsys):
    original = digest(city_map)
    args = ["update", str(city_map), "--observations", str(halves[0]), "--dem", DEM,
            "--layer", "buildings", "-q"]  # fmt: skip
    grids = [] if grid_dir is None else ["--grid-dir", str(grid_dir)]
    code, out, err = run([*args, *grids, "--dry-run"], capsys)
    assert code == 0, err
    assert "buildings updated" in out and out.rstrip().endswith("dry run: nothing written")
    assert digest(city_map) == original and sorted(p.name for p in city_map.parent.iterdir()) == [
        "map.gpkg"
    ]
    code, out, err = run([*args, *grids, "--no-backup"], capsys)
    assert code == 0, err
    assert digest(city_map) != original and not city_map.with_name("map.bak.gpkg").exists()
    assert out.rstrip().endswith(f"updated -> {city_map}")


def test_min_signals_skips_the_thinly_seen(city_map, halves, grid_dir):
    result = update_map(
        city_map, [halves[0]], DEM, layer="buildings", grid_dir=grid_dir, min_signals=900
    )
    skipped = result.skipped
    assert len(skipped) > 0 and skipped["skipped"].str.startswith("fewer than 900 signals").all()
    table = pyogrio.read_dataframe(city_map, layer="buildings", read_geometry=False)
    thin = table["id"].isin(skipped["id"])
    assert (
        table.loc[thin, "height_gnss"].isna().all() and table.loc[~thin, "n_signals"].min() >= 900
    )
    assert any(
        line.startswith(f"skipped {len(skipped)}: fewer than 900") for line in result.lines()
    )


def test_a_failure_while_writing_leaves_the_map_as_it_was(city_map, halves, grid_dir):
    """A column of the user's named like one of ours, of another type: refused while writing
    (after the evidence went into the copy); the map is byte-identical, no copy left."""
    with contextlib.closing(sqlite3.connect(city_map)) as db, db:
        db.execute('ALTER TABLE buildings ADD COLUMN "n_signals" TEXT')
    original = digest(city_map)
    with pytest.raises(InputError, match="column 'n_signals' of type TEXT"):
        update_map(city_map, [halves[0]], DEM, layer="buildings", grid_dir=grid_dir)
    assert digest(city_map) == original
    assert sorted(p.name for p in city_map.parent.iterdir()) == ["map.gpkg"]


def test_a_folder_of_tiles_is_refused_with_what_to_do_instead(halves, tmp_path, capsys):
    """A run in tiles' output folder: the update says how to refresh it (a new run over the
    old and new observations), not that a directory is not a file; a plain folder is named
    as a folder."""
    tiles = tmp_path / "tiles"
    (tiles / "heights").mkdir(parents=True)
    (tiles / "tiles.gpkg").write_bytes(b"")
    code, _, err = run(
        ["update", str(tiles), "--observations", str(halves[0]), "--dem", str(DEM)], capsys
    )
    assert code == 2 and "a folder of tiles from a run in tiles" in err and "partition" in err
    code, _, err = run(
        ["update", str(tmp_path), "--observations", str(halves[0]), "--dem", str(DEM)], capsys
    )
    assert code == 2 and "map is a folder, not a file" in err


def test_a_map_another_program_is_writing_is_refused(city_map, halves, grid_dir):
    original = digest(city_map)
    with contextlib.closing(sqlite3.connect(city_map)) as other:
        other.execute("BEGIN IMMEDIATE")  # as an editor in the middle of saving
        with pytest.raises(InputError, match="cannot be locked for writing"):
            update_map(city_map, [halves[0]], DEM, layer="buildings", grid_dir=grid_dir)
        other.rollback()
    for side, size in (("-wal", 100), ("-wal", 0), ("-shm", 0)):
        # an open connection's write-ahead log, even empty: its later writes would be
        # applied to the new file, and damage it
        extra = Path(str(city_map) + side)
        extra.write_bytes(b"\0" * size)
        with pytest.raises(InputError, match=f"open in another program \\(map.gpkg{side}"):
            update_map(city_map, [halves[0]], DEM, layer="buildings", grid_dir=grid_dir)
        extra.unlink()
    assert digest(city_map) == original


def test_killed_at_any_moment_the_map_is_as_it_was_or_updated(city_map, halves, grid_dir):
    """SIGKILL at moments spread over the run: the map is always either byte-identical to
    before or the complete update (the rename is the only change); never anything else."""
    original = city_map.read_bytes()
    grids = [] if grid_dir is None else ["--grid-dir", str(grid_dir)]
    argv = [sys.executable, "-m", "gnss_citygml", "update", str(city_map), "--observations",
            str(halves[0]), "--dem", DEM, "--layer", "buildings", "--no-backup", "-q",
            *grids]  # fmt: skip
    subprocess.run(argv, check=True, capture_output=True)
    complete = _content(city_map)
    outcomes = set()
    for delay in (0.2, 0.6, 1.0, 1.3, 1.6, 2.0, 2.5):
        city_map.write_bytes(original)
        process = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        time.sleep(delay)
        process.send_signal(signal.SIGKILL)
        process.wait()
        untouched = city_map.read_bytes() == original
        assert untouched or _content(city_map) == complete, delay
        outcomes.add(untouched)
    assert True in outcomes  # some kills came before the end
    city_map.write_bytes(original)
    subprocess.run(argv, check=True, capture_output=True)  # a later run cleans up the parts
    assert not stale_parts(city_map)


def _content(path: Path) -> tuple:
    """What an update writes, but its time stamps: the buildings' values and the evidence."""
    table = pyogrio.read_dataframe(path, layer="buildings", read_geometry=False)
    evidence = pyogrio.read_dataframe(path, layer=EVIDENCE, read_geometry=False)
    evidence = evidence.drop(columns="created_utc")
    values = table.drop(columns="updated_utc").to_csv()
    return values, evidence.to_csv(), table["updated_utc"].notna().all()


def test_the_report_of_two_updates_is_that_of_one_run(city_map, halves, grid_dir, tmp_path):
    """The evidence keeps every signal cast: the report after two updates shows the same
    buildings, errors and signals as one run over all the observations."""
    from gnss_citygml.compare import compare, summary
    from gnss_citygml.pipeline import run

    truth = CITY / "truth.csv"
    update_map(city_map, [halves[0]], DEM, layer="buildings", grid_dir=grid_dir)
    update_map(city_map, [halves[1]], DEM, layer="buildings", grid_dir=grid_dir,
               report=tmp_path / "r", truth=truth)  # fmt: skip
    page = (tmp_path / "r" / "report.html").read_text()
    obs = pd.concat([pd.read_parquet(h) for h in halves], ignore_index=True)
    import gnss_citygml as gc

    one = run(obs, gc.read_footprints(CITY / "footprints.gpkg"), DEM, grid_dir=grid_dir)
    assert summary(compare(one.heights, pd.read_csv(truth))) in page
    assert f"{len(one.receivers)} signals from 8 receivers" in page


def test_repeated_observations_count_once(city_map, halves, grid_dir, tmp_path):
    twin = tmp_path / "twin.gpkg"
    twin.write_bytes(city_map.read_bytes())
    once = update_map(twin, [halves[0]], DEM, layer="buildings", grid_dir=grid_dir)
    with pytest.warns(UserWarning, match=r"repeated observation\(s\) .* counted once"):
        twice = update_map(
            city_map, [halves[0], halves[0]], DEM, layer="buildings", grid_dir=grid_dir
        )
    assert twice.new_signals == once.new_signals
    read = [
        pyogrio.read_dataframe(p, layer="buildings", read_geometry=False) for p in (twin, city_map)
    ]
    pd.testing.assert_frame_equal(*(t.drop(columns="updated_utc") for t in read))


@pytest.mark.parametrize("kind", ["ogc_fid key, text fid", "real ids", "integer fid only"])
def test_the_id_column_is_found_or_named(kind, halves, grid_dir, tmp_path):
    """Whatever holds the ids (a text column named fid beside another primary key, whole
    numbers stored as REAL, GDAL's fid itself), the rows written are the right ones, and a
    second run with the same data changes nothing."""
    footprints = pyogrio.read_dataframe(CITY / "footprints.gpkg")
    path = tmp_path / "m.gpkg"
    args = {}
    if kind == "ogc_fid key, text fid":
        footprints = footprints.rename(columns={"id": "fid"})
        pyogrio.write_dataframe(footprints, path, layer_options={"FID": "ogc_fid"})
    elif kind == "real ids":
        footprints["ref"] = np.arange(len(footprints), dtype=float) + 100.0
        pyogrio.write_dataframe(footprints.drop(columns="id"), path)
        args = {"id_field": "ref"}
    else:
        pyogrio.write_dataframe(footprints.drop(columns="id"), path)
    result = update_map(path, [halves[0]], DEM, grid_dir=grid_dir, **args)
    layer = pyogrio.list_layers(path)[0][0]
    table = pyogrio.read_dataframe(path, layer=layer, read_geometry=False)
    assert table["height_gnss"].notna().sum() == (~result.buildings["after"].isna()).sum() > 10
    again = update_map(path, [halves[0]], DEM, grid_dir=grid_dir, **args)
    assert not again.written and again.updated.empty


def test_a_layer_of_unknown_geometry_type(halves, grid_dir, tmp_path):
    path = tmp_path / "m.gpkg"
    footprints = pyogrio.read_dataframe(CITY / "footprints.gpkg")
    pyogrio.write_dataframe(footprints, path, geometry_type="Unknown")
    assert update_map(path, [halves[0]], DEM, grid_dir=grid_dir).written


def test_a_column_of_ours_in_another_case_or_type_is_refused_before_the_work(
    city_map, halves, grid_dir
):
    with contextlib.closing(sqlite3.connect(city_map)) as db, db:
        db.execute('ALTER TABLE buildings ADD COLUMN "Method" INTEGER')
    stages = []
    with pytest.raises(InputError, match="column 'method' of type INTEGER, not TEXT"):
        update_map(city_map, [halves[0]], DEM, layer="buildings", grid_dir=grid_dir,
                   progress=lambda what, done: stages.append(what))  # fmt: skip
    assert stages == ["reading"]  # refused before casting and fitting


def test_each_layer_keeps_its_own_evidence(halves, grid_dir, tmp_path):
    """Two footprint layers in one GeoPackage: an update of one does not feed the other."""
    path = tmp_path / "two.gpkg"
    footprints = pyogrio.read_dataframe(CITY / "footprints.gpkg")
    pyogrio.write_dataframe(footprints, path, layer="footprints")
    pyogrio.write_dataframe(footprints.iloc[:5], path, layer="other")
    update_map(path, [halves[0]], DEM, layer="other", grid_dir=grid_dir)
    result = update_map(path, [halves[0]], DEM, layer="footprints", grid_dir=grid_dir)
    assert result.new_signals > 0 and result.skipped.empty
    table = pyogrio.read_dataframe(path, layer="footprints", read_geometry=False)
    alone = tmp_path / "alone.gpkg"
    pyogrio.write_dataframe(footprints, alone, layer="footprints")
    update_map(alone, [halves[0]], DEM, grid_dir=grid_dir)
    expected = pyogrio.read_dataframe(alone, layer="footprints", read_geometry=False)
    pd.testing.assert_series_equal(table["height_gnss"], expected["height_gnss"])


def test_footprints_edited_between_updates(city_map, halves, grid_dir):
    """A footprint deleted: its evidence is left out; an outline added: the note says the old
    signals were not cast against it."""
    update_map(city_map, [halves[0]], DEM, layer="buildings", grid_dir=grid_dir)
    with contextlib.closing(sqlite3.connect(city_map)) as db, db:
        db.execute("DELETE FROM buildings WHERE id = 'city_0_0'")
    result = update_map(city_map, [halves[1]], DEM, layer="buildings", grid_dir=grid_dir)
    assert result.written and "city_0_0" not in set(result.buildings["id"])
    lines = result.lines()
    assert any("with footprints no longer in the layer left out" in line for line in lines)
    assert any(line.startswith("the footprints changed since the evidence") for line in lines)


def test_a_truth_table_without_a_report_is_refused(city_map, halves, grid_dir):
    original = digest(city_map)
    with pytest.raises(InputError, match="no report was asked for"):
        update_map(city_map, [halves[0]], DEM, layer="buildings", grid_dir=grid_dir,
                   truth=CITY / "truth.csv")  # fmt: skip
    assert digest(city_map) == original


@pytest.mark.parametrize(
    ("part", "named"),
    [
        ({"calibration": Calibration(prior_sd=5.0)}, "self-calibration"),
        ({"tiling": Tiling("local")}, "a run on a Dask scheduler"),
        ({"position_error": PositionError(sd=3.0)}, "a position error"),
    ],
)
def test_run_settings_an_update_has_no_use_for_are_refused(city_map, halves, part, named):
    """An update casts with each observation's own position error in one process: settings
    it would ignore are refused (the map untouched), whether given whole or by part."""
    original = digest(city_map)
    with pytest.raises(InputError, match=f"an update does not take {named}"):
        update_map(city_map, [halves[0]], DEM, **part)
    with pytest.raises(InputError, match=f"an update does not take {named}"):
        update_map(city_map, [halves[0]], DEM, settings=RunSettings(**part))
    assert digest(city_map) == original


def test_older_evidence_reads_as_it_was_fitted():
    import pyarrow as pa

    from gnss_citygml.update.evidence import _columns

    older = pa.table({"signal_key": [1, 2], "building": ["a", "b"], "receiver": ["r", "s"]})
    wanted = ["signal_key", "satellite", "building", "height_sd", "recording"]
    table = _columns(older, wanted)
    assert table.column_names == wanted
    # no satellites; cast from positions taken as exact, one recording per receiver
    assert table.column("satellite").null_count == 2
    assert table.column("height_sd").to_pylist() == [0.0, 0.0]
    assert table.column("recording").to_pylist() == ["r", "s"]


def _heights(path: Path, layer: str = "buildings") -> pd.Series:
    table = pyogrio.read_dataframe(path, layer=layer, read_geometry=False)
    return table["height_gnss"]


def test_a_layer_is_the_same_in_any_letter_case(city_map, halves, grid_dir, tmp_path):
    """SQLite's names are the same in any letter case, and so is the evidence they key
    (issue 26): BUILDINGS then buildings is two updates of one layer, as if spelled alike;
    so is evidence kept under another spelling by an earlier version."""
    twin = tmp_path / "twin.gpkg"
    twin.write_bytes(city_map.read_bytes())
    update_map(city_map, [halves[0]], DEM, layer="BUILDINGS", grid_dir=grid_dir)
    second = update_map(city_map, [halves[1]], DEM, layer="buildings", grid_dir=grid_dir)
    for half in halves:
        update_map(twin, [half], DEM, layer="buildings", grid_dir=grid_dir)
    pd.testing.assert_series_equal(_heights(city_map), _heights(twin))
    assert second.skipped.empty and not any("footprints changed" in x for x in second.lines())
    with contextlib.closing(sqlite3.connect(city_map)) as db, db:
        assert {r[0] for r in db.execute(f"SELECT layer FROM {EVIDENCE}")} == {"buildings"}
        db.execute(f"UPDATE {EVIDENCE} SET layer = 'Buildings'")  # as an earlier version kept it
    again = update_map(city_map, [*halves], DEM, layer="bUILDINGS", grid_dir=grid_dir)
    assert again.new_signals == 0 and not again.written


def _shifted_dem(folder: Path, by: float, name: str = "dem.tif") -> str:
    import rasterio

    with rasterio.open(DEM) as src:
        profile, data = src.profile, src.read(1)
    path = folder / name
    with rasterio.open(path, "w", **profile) as dst:
        dst.write(data + np.asarray(by, dtype=data.dtype), 1)
    return str(path)


def test_a_dem_changed_between_updates_is_refused(city_map, halves, grid_dir, tmp_path, capsys):
    """Evidence cast from one DEM and new signals from another would be fitted together
    (issue 26: 12 buildings lost their height); refused in one line, the map as it was. The
    same DEM under another name is no change."""
    update_map(city_map, [halves[0]], DEM, layer="buildings", grid_dir=grid_dir)
    original = digest(city_map)
    grids = [] if grid_dir is None else ["--grid-dir", str(grid_dir)]
    for by in (10.0, 0.25):
        higher = _shifted_dem(tmp_path, by, f"dem{by}.tif")
        args = ["update", str(city_map), "--observations", str(halves[1]), "--dem", higher,
                "--layer", "buildings", "-q", *grids]  # fmt: skip
        code, out, err = run(args, capsys)
        assert code == 2 and len(err.strip().splitlines()) == 1, err
        assert err.startswith("error: the DEM is not the one the evidence in the map was cast")
        assert f"by up to {by:.2f} m" in err and "delete the table gnss_evidence" in err
        assert digest(city_map) == original
    copy = _shifted_dem(tmp_path, 0.0, "same.tif")
    assert update_map(city_map, [halves[1]], copy, layer="buildings", grid_dir=grid_dir).written


@pytest.mark.parametrize(
    "setting, message",
    [
        ({"receiver_heights": "antenna"}, "antenna_height 1.0 \\(the evidence\\) vs 1.5 \\(now\\)"),
        ({"rays": "mask"}, "min_elevation 10.0 \\(the evidence\\) vs 15.0 \\(now\\)"),
        ({"receiver_heights": "log"}, "receiver_height dem \\(the evidence\\) vs log \\(now\\)"),
    ],
)
def test_other_cast_settings_between_updates_are_refused(
    setting, message, city_map, halves, grid_dir
):
    from gnss_citygml.settings import Rays, ReceiverHeights

    chosen = {
        "antenna": ReceiverHeights(antenna_height=1.5),
        "log": ReceiverHeights(source="log"),
        "mask": Rays(min_elevation=15.0),
    }
    update_map(city_map, [halves[0]], DEM, layer="buildings", grid_dir=grid_dir)
    original = digest(city_map)
    options = {k: chosen[v] for k, v in setting.items()}
    with pytest.raises(InputError, match="cast with other settings: .*" + message):
        update_map(city_map, [halves[1]], DEM, layer="buildings", grid_dir=grid_dir, **options)
    assert digest(city_map) == original


def test_a_map_through_a_symbolic_link(city_map, halves, grid_dir, tmp_path):
    """The file the link names is updated; the link stays a link (issue 26)."""
    link = tmp_path / "elsewhere" / "link.gpkg"
    link.parent.mkdir()
    link.symlink_to(city_map)
    result = update_map(link, [halves[0]], DEM, layer="buildings", grid_dir=grid_dir)
    assert result.written and link.is_symlink() and link.resolve() == city_map
    assert _heights(city_map).notna().sum() > 10
    assert result.backup == city_map.with_name("map.bak.gpkg") and result.backup.is_file()
    assert sorted(p.name for p in link.parent.iterdir()) == ["link.gpkg"]


@pytest.mark.parametrize("spelling", ["{:03d}", "{}.0", "{:02d}A", "{:02d}.50", "integer"])
def test_ids_are_kept_as_the_layer_stores_them(spelling, halves, grid_dir, tmp_path):
    """Text ids are text ("001" is not 1, "1.0" is not "1"); an INTEGER id column is
    written by its integers (issue 26). Two updates give the heights of the sample's ids."""
    footprints = pyogrio.read_dataframe(CITY / "footprints.gpkg")
    plain = tmp_path / "plain.gpkg"
    pyogrio.write_dataframe(footprints, plain, layer="buildings")
    numbers = np.arange(1, len(footprints) + 1)
    ids = numbers if spelling == "integer" else [spelling.format(i) for i in numbers]
    path = tmp_path / "m.gpkg"
    pyogrio.write_dataframe(footprints.assign(id=ids), path, layer="buildings")
    before = layer_rows(path, "buildings")
    for half in halves:
        update_map(plain, [half], DEM, layer="buildings", grid_dir=grid_dir)
        assert update_map(path, [half], DEM, layer="buildings", grid_dir=grid_dir).written
    after = layer_rows(path, "buildings")
    assert [row[: len(before[0])] for row in after] == before  # the ids as they were
    pd.testing.assert_series_equal(_heights(path), _heights(plain))
    assert not update_map(path, [halves[0]], DEM, layer="buildings", grid_dir=grid_dir).written


@pytest.fixture(scope="module")
def updated_map(tmp_path_factory, halves, grid_dir):
    """The sample's footprints after one update: a map with evidence."""
    path = tmp_path_factory.mktemp("updated") / "map.gpkg"
    pyogrio.write_dataframe(pyogrio.read_dataframe(CITY / "footprints.gpkg"), path,
                            layer="buildings")  # fmt: skip
    update_map(path, [halves[0]], DEM, layer="buildings", grid_dir=grid_dir, backup=False)
    return path


def _parquet(**columns) -> bytes:
    import pyarrow as pa
    import pyarrow.parquet as pq

    buffer = pa.BufferOutputStream()
    pq.write_table(pa.table(columns), buffer)
    return buffer.getvalue().to_pybytes()


_DAMAGE = {
    "random blob": ("UPDATE gnss_evidence SET data = randomblob(200)", "is not Parquet"),
    "NULL data": ("UPDATE gnss_evidence SET data = NULL", "a row holds NULL where"),
    "text data": ("UPDATE gnss_evidence SET data = 'hello'", "a row holds str where"),
    "dropped column": ("ALTER TABLE gnss_evidence DROP COLUMN kind", "column\\(s\\) kind"),
    "dropped data": ("ALTER TABLE gnss_evidence DROP COLUMN data", "column\\(s\\) data"),
    "another table": (
        "DROP TABLE gnss_evidence; CREATE TABLE GNSS_Evidence (a TEXT, b INTEGER)",
        "without the evidence's column\\(s\\) id, layer, kind",
    ),
    "a view": (
        "DROP TABLE gnss_evidence; CREATE VIEW gnss_evidence AS SELECT 1 AS x",
        "a view gnss_evidence is there",
    ),
    "rows counted wrong": ("UPDATE gnss_evidence SET n_rows = n_rows + 1", "rows of data, not"),
    "other parquet": ("UPDATE gnss_evidence SET data = ?", "has no column signal_key"),
    "heights as text": ("UPDATE gnss_evidence SET data = ?", "values of another type"),
    "settings": ("UPDATE gnss_evidence SET cast_with = 'x{'", "cast settings are not readable"),
}


@pytest.mark.parametrize("damage", list(_DAMAGE))
def test_a_damaged_evidence_table_is_one_line(damage, updated_map, halves, grid_dir, tmp_path):
    """Whatever happened to gnss_evidence: one line naming the map and the fix, before any
    work, the map as it was (issue 26: these were internal errors)."""
    path = tmp_path / "map.gpkg"
    path.write_bytes(updated_map.read_bytes())
    sql, message = _DAMAGE[damage]
    with contextlib.closing(sqlite3.connect(path)) as db, db:
        if damage == "other parquet":
            db.execute(sql, (_parquet(x=[1, 2]),))
        elif damage == "heights as text":
            (blob,) = db.execute("SELECT data FROM gnss_evidence WHERE kind = 'intersections'")
            columns = pd.read_parquet(io.BytesIO(blob[0])).head(3).assign(height="high")
            db.execute(sql + ", n_rows = 3 WHERE kind = 'intersections'",
                       (_parquet(**{c: columns[c].tolist() for c in columns}),))  # fmt: skip
        else:
            db.executescript(sql)
    original = digest(path)
    stages = []
    with pytest.raises(InputError, match=message) as error:
        update_map(path, [halves[1]], DEM, layer="buildings", grid_dir=grid_dir,
                   progress=lambda what, done: stages.append(what))  # fmt: skip
    text = str(error.value)
    assert "gnss_evidence" in text and str(path) in text and "\n" not in text
    assert "map.bak.gpkg" in text and stages == ["reading"]
    assert digest(path) == original


@pytest.mark.parametrize(
    "change", ["DELETE FROM gnss_evidence", "UPDATE gnss_evidence SET layer = 'gone'"]
)
def test_an_empty_evidence_table_or_other_layers_rows(change, updated_map, halves, grid_dir,
                                                       tmp_path):  # fmt: skip
    """No rows for the layer: everything is cast again, as for a new map."""
    path = tmp_path / "map.gpkg"
    path.write_bytes(updated_map.read_bytes())
    with contextlib.closing(sqlite3.connect(path)) as db, db:
        db.execute(change)
    result = update_map(path, [halves[0]], DEM, layer="buildings", grid_dir=grid_dir)
    assert result.new_signals > 0 and result.skipped.empty
