"""`gnss-citygml update` (issue 13): a GeoPackage map kept up to date in place, never at risk.

A map here is the sample city's footprints with a second layer, a style, a column of the
user's own, and two halves of the observations arriving one after the other."""

import contextlib
import hashlib
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
from gnss_citygml.paths import stale_parts
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
    from gnss_citygml.styles import save_default_style

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


def test_older_evidence_reads_as_it_was_fitted():
    import pyarrow as pa

    from gnss_citygml.update import _columns

    older = pa.table({"signal_key": [1, 2], "building": ["a", "b"], "receiver": ["r", "s"]})
    wanted = ["signal_key", "satellite", "building", "height_sd", "recording"]
    table = _columns(older, wanted)
    assert table.column_names == wanted
    # no satellites; cast from positions taken as exact, one recording per receiver
    assert table.column("satellite").null_count == 2
    assert table.column("height_sd").to_pylist() == [0.0, 0.0]
    assert table.column("recording").to_pylist() == ["r", "s"]
