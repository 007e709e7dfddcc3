"""Outputs from the user's side: never replaced without --overwrite, never destroyed with it,
written in the format their name says, and checked before the work starts (issue 10)."""

import os
import stat
import subprocess
import sys
import warnings
from pathlib import Path

import geopandas as gpd
import pandas as pd
import pyogrio
import pytest
import shapely
from test_cli import run

from gnss_citygml.errors import InputError
from gnss_citygml.files.folders import MANIFEST, atomic_folder
from gnss_citygml.files.paths import _HOST, atomic_path, stale_parts
from gnss_citygml.simulate.files import check_site
from gnss_citygml.validate import validate_file

CITY = Path(__file__).resolve().parents[1] / "examples" / "city"


def buildings(**columns) -> gpd.GeoDataFrame:
    """Three buildings in Bloomsbury with ground and absolute roof heights (m ODN)."""
    boxes = [shapely.box(529500 + 20 * i, 182300, 529510 + 20 * i, 182308) for i in range(3)]
    data = {"id": ["a", "b", "c"], "ground": [20.0, 21.0, 22.0], "height": [32.5, 30.0, 41.0]}
    data.update(columns)
    return gpd.GeoDataFrame(data, geometry=boxes, crs="EPSG:27700")


def heights_gpkg(folder: Path, **columns) -> Path:
    path = folder / "heights.gpkg"
    buildings(**columns).to_file(path, layer="heights", driver="GPKG")
    return path


def estimate(folder: Path, grid_args: list[str], output: str, *extra) -> list[str]:
    return [
        "estimate",
        str(CITY / "observations.parquet"),
        str(CITY / "footprints.gpkg"),
        "--dem",
        str(CITY / "dem.tif"),
        "-o",
        str(folder / output),
        *grid_args,
        "-q",
        *extra,
    ]


# --- a GeoPackage keeps its other layers ----------------------------------------------------


def test_estimate_into_a_geopackage_keeps_its_other_layers(grid_args, tmp_path, capsys):
    target = tmp_path / "map.gpkg"
    mine = buildings()
    mine.to_file(target, layer="buildings", driver="GPKG")
    code, _, err = run(estimate(tmp_path, grid_args, "map.gpkg"), capsys)  # a new layer: no flag
    assert code == 0, err
    assert sorted(pyogrio.list_layers(target)[:, 0]) == ["buildings", "heights", "layer_styles"]
    first = gpd.read_file(target, layer="heights")
    assert len(first) == 30
    code, _, err = run(estimate(tmp_path, grid_args, "map.gpkg"), capsys)
    assert code == 2 and "output exists and has a layer 'heights'" in err
    code, _, err = run(estimate(tmp_path, grid_args, "map.gpkg", "--overwrite"), capsys)
    assert code == 0, err
    assert sorted(pyogrio.list_layers(target)[:, 0]) == ["buildings", "heights", "layer_styles"]
    kept = gpd.read_file(target, layer="buildings")
    pd.testing.assert_frame_equal(
        pd.DataFrame(kept.drop(columns="geometry")),
        mine.drop(columns="geometry").pipe(pd.DataFrame),
    )
    assert kept.geometry.equals(mine.geometry)
    assert len(gpd.read_file(target, layer="heights")) == 30
    assert not stale_parts(target) and not list(tmp_path.glob(".*part*"))


@pytest.mark.parametrize("suffix, driver", [(".fgb", "FlatGeobuf"), (".parquet", None)])
def test_estimate_writes_the_format_its_name_says(suffix, driver, grid_args, tmp_path, capsys):
    code, _, err = run(estimate(tmp_path, grid_args, "h" + suffix), capsys)
    assert code == 0, err
    path = tmp_path / ("h" + suffix)
    if driver:
        assert pyogrio.read_info(path)["driver"] == driver
        table = gpd.read_file(path)
    else:
        table = gpd.read_parquet(path)
    assert len(table) == 30 and table.crs.to_epsg() == 27700
    assert {"id", "height", "height_lower", "height_upper", "converged"} <= set(table.columns)
    if driver is None:  # the GeoParquet layer is a heights table `export` takes, geometry and all
        model = tmp_path / "m.city.json"
        args = [
            "export",
            str(path),
            "--footprints",
            str(CITY / "footprints.gpkg"),
            "-o",
            str(model),
        ]
        code, _, err = run([*args, *grid_args, "-q"], capsys)
        assert code == 0, err
        assert validate_file(model).valid


@pytest.mark.parametrize(
    "name, message",
    [
        ("h.shp", "Shapefiles are not written"),
        ("h.txt", "unknown output format '.txt'"),
        ("missing/h.gpkg", "output folder does not exist"),
    ],
)
def test_a_bad_output_fails_before_any_work(name, message, tmp_path, capsys):
    """The output is checked first: here the inputs do not even exist, and the error is still
    about the output, so no minutes of work are lost to a typo in -o."""
    args = ["estimate", str(tmp_path / "none.parquet"), str(tmp_path / "none.gpkg")]
    args += ["--dem", str(tmp_path / "none.tif"), "-o", str(tmp_path / name)]
    code, _, err = run(args, capsys)
    assert code == 2 and message in err, err
    assert len(err.strip().splitlines()) == 1
    assert not list(tmp_path.rglob("h.*"))


def test_convert_checks_its_output_first(tmp_path, capsys):
    code, _, err = run(
        ["convert", str(tmp_path / "none.gpkg"), "-o", str(tmp_path / "c.obj")], capsys
    )
    assert code == 2 and "unknown output format '.obj'" in err
    (tmp_path / "c.gml").write_text("mine")
    code, _, err = run(
        ["convert", str(tmp_path / "none.gpkg"), "-o", str(tmp_path / "c.gml")], capsys
    )
    assert code == 2 and "output exists" in err
    assert (tmp_path / "c.gml").read_text() == "mine"


# --- permissions and temporary files --------------------------------------------------------


def test_a_read_only_output_is_not_replaced(tmp_path, capsys):
    source = heights_gpkg(tmp_path)
    out = tmp_path / "city.city.json"
    out.write_text("kept")
    out.chmod(0o444)
    code, _, err = run(["convert", str(source), "-o", str(out), "--overwrite"], capsys)
    assert code == 2 and "output is read-only" in err
    assert out.read_text() == "kept" and stat.S_IMODE(out.stat().st_mode) == 0o444


def test_overwrite_keeps_the_files_permissions(tmp_path, capsys):
    source = heights_gpkg(tmp_path)
    out = tmp_path / "city.gml"
    out.write_text("old")
    out.chmod(0o640)
    code, _, err = run(["convert", str(source), "-o", str(out), "--overwrite"], capsys)
    assert code == 0, err
    assert stat.S_IMODE(out.stat().st_mode) == 0o640 and validate_file(out).valid


def _dead_pid() -> int:
    child = subprocess.Popen([sys.executable, "-c", "pass"])
    child.wait()
    return child.pid


def test_a_later_run_removes_the_temporary_files_of_killed_runs(tmp_path, capsys):
    source = heights_gpkg(tmp_path)
    out = tmp_path / "city.city.json"
    with pytest.raises(RuntimeError), atomic_path(out) as tmp:  # a run that dies half-way
        tmp.write_text("half")
        raise RuntimeError
    assert not list(tmp_path.glob(".*part*"))  # a failed run cleans up after itself
    host = _HOST
    killed = tmp_path / f".city.city.json.part-{host}-{_dead_pid()}-0a1b2c3d.json"
    alive = tmp_path / f".city.city.json.part-{host}-{os.getpid()}-0a1b2c3d.json"
    elsewhere = tmp_path / ".city.city.json.part-otherhost-1-0a1b2c3d.json"
    for part in (killed, alive, elsewhere):
        part.write_text("{")
    assert stale_parts(out) == [killed]
    code, _, err = run(["convert", str(source), "-o", str(out)], capsys)
    assert code == 0, err
    assert not killed.exists()
    assert alive.exists() and elsewhere.exists()  # a running writer's, another machine's


def test_two_runs_without_overwrite_never_both_win(tmp_path):
    """Two `convert` runs to the same new file at once: exactly one writes it; the other says
    the output exists. (The check holds at the rename, not only when writing starts.)"""
    source = heights_gpkg(tmp_path)
    out = tmp_path / "city.gml"
    command = [sys.executable, "-m", "gnss_citygml", "convert", str(source), "-o", str(out), "-q"]
    runs = [
        subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        for _ in range(2)
    ]
    results = [(p.wait(timeout=120), p.stderr.read()) for p in runs]
    codes = sorted(code for code, _ in results)
    assert codes == [0, 2], results
    assert "output exists" in next(err for code, err in results if code == 2)
    assert validate_file(out).valid
    assert not list(tmp_path.glob(".*part*"))


# --- heights that no building has; tables that are not what they claim ----------------------


def test_implausible_heights_are_skipped_with_the_reason(tmp_path, capsys):
    source = heights_gpkg(tmp_path, height=[1e9, 30.0, 10.0], ground=[20.0, 5e4, 22.0])
    out = tmp_path / "city.city.json"
    code, stdout, err = run(["convert", str(source), "-o", str(out), "-q"], capsys)
    assert code == 2 and "none of the 3 buildings has a usable height" in err
    assert "roof more than 400 m above the ground" in err
    assert "ground outside -10..1400 m ODN" in err and "roof not above the ground" in err
    assert not out.exists()
    source = heights_gpkg(tmp_path, height=[1e9, 30.0, 41.0])
    code, stdout, err = run(["convert", str(source), "-o", str(out), "--overwrite"], capsys)
    assert code == 0 and stdout.startswith("2 buildings, 1 skipped"), err
    assert "skipped a: roof more than 400 m above the ground" in err
    code, _, err = run(["convert", str(source), "-o", str(out), "--overwrite", "--strict"], capsys)
    assert code == 2 and "roof more than 400 m" in err


def test_footprints_outside_the_grid_are_skipped(tmp_path, capsys):
    frame = buildings()
    frame.loc[1, "geometry"] = shapely.box(1e300, 0, 2e300, 1)
    frame.to_file(tmp_path / "far.gpkg", layer="heights", driver="GPKG")
    out = tmp_path / "city.gml"
    code, stdout, err = run(["convert", str(tmp_path / "far.gpkg"), "-o", str(out)], capsys)
    assert code == 0 and "skipped b: footprint outside the British National Grid" in err
    assert validate_file(out).valid


@pytest.mark.parametrize(
    "table, message",
    [
        (pd.DataFrame({"building": ["a"], "height": [30.0]}), "missing column(s) 'id'"),
        (
            pd.DataFrame({"id": ["a", "b"], "height": [30.0, 31.0], "converged": ["yes", "maybe"]}),
            "column 'converged' is not true/false: 'maybe' (buildings b)",
        ),
        (
            pd.DataFrame({"id": ["a", "a"], "height": [30.0, 31.0]}),
            "1 building id(s) with more than one height: a",
        ),
    ],
)
def test_export_of_a_bad_heights_table_is_one_line(table, message, tmp_path, capsys):
    buildings().drop(columns=["height"]).to_file(tmp_path / "fp.gpkg", driver="GPKG")
    table.to_csv(tmp_path / "h.csv", index=False)
    args = ["export", str(tmp_path / "h.csv"), "--footprints", str(tmp_path / "fp.gpkg")]
    code, _, err = run([*args, "-o", str(tmp_path / "city.gml")], capsys)
    assert code == 2 and message in err, err
    assert len(err.strip().splitlines()) == 1
    assert not (tmp_path / "city.gml").exists()


def test_converged_as_yes_no_text_is_understood(tmp_path, capsys):
    buildings().drop(columns=["height"]).to_file(tmp_path / "fp.gpkg", driver="GPKG")
    table = pd.DataFrame(
        {"id": ["a", "b", "c"], "height": [30.0, 31.0, 40.0], "converged": ["yes", "no", "Yes"]}
    )
    table.to_csv(tmp_path / "h.csv", index=False)
    args = ["export", str(tmp_path / "h.csv"), "--footprints", str(tmp_path / "fp.gpkg")]
    code, out, err = run([*args, "-o", str(tmp_path / "city.gml")], capsys)
    assert code == 0 and out.startswith("2 buildings, 1 skipped"), err
    assert "skipped b: height estimate did not converge" in err


def test_quiet_export_with_nothing_usable_says_why_in_its_one_line(tmp_path, capsys):
    source = heights_gpkg(tmp_path, converged=[False, False, False])
    code, _, err = run(["convert", str(source), "-o", str(tmp_path / "c.gml"), "-q"], capsys)
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert "height estimate did not converge: 3 (a, b, c)" in err
    assert "see the skipped" not in err


def test_control_characters_in_ids_are_not_replaced_silently(tmp_path, capsys):
    frame = buildings(id=["a\x01", "b", "c"])
    frame.to_file(tmp_path / "ctl.gpkg", layer="heights", driver="GPKG")
    code, _, err = run(
        ["convert", str(tmp_path / "ctl.gpkg"), "-o", str(tmp_path / "c.gml")], capsys
    )
    assert code == 0
    assert "warning: 1 building(s) have text that XML cannot hold" in err and "'a\\x01'" in err
    code, _, err = run(
        ["convert", str(tmp_path / "ctl.gpkg"), "-o", str(tmp_path / "c.city.json")], capsys
    )
    assert code == 0 and "warning" not in err
    assert '"a\\u0001"' in (tmp_path / "c.city.json").read_text()


def test_library_writers_warn_too(tmp_path):
    from gnss_citygml.export import write_citygml

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        write_citygml(buildings(id=["a\x01", "b", "c"]), tmp_path / "c.gml")
    assert any("XML cannot hold" in str(w.message) for w in caught)


def test_simulate_into_a_file_or_over_a_site(tmp_path, capsys):
    (tmp_path / "site").write_text("mine")
    code, _, err = run(["simulate", "ucl", "-o", str(tmp_path / "site")], capsys)
    assert code == 2 and err.startswith("error: the site folder is a file")  # one line, ours
    with pytest.raises(InputError, match="the site folder is a file"):
        check_site(tmp_path / "site", overwrite=True)
    (tmp_path / "old").mkdir()
    (tmp_path / "old" / "intersections.csv").write_text("mine")
    code, _, err = run(["simulate", "ucl", "-o", str(tmp_path / "old")], capsys)
    assert code == 2 and "output exists" in err and "intersections.csv" in err
    assert [p.name for p in (tmp_path / "old").iterdir()] == ["intersections.csv"]


def test_a_folder_output_appears_whole_or_not_at_all(tmp_path):
    """atomic_folder: filled beside under another name, renamed into place when complete;
    a failure leaves nothing; an old folder goes only with overwrite, once the new one is
    there."""
    out = tmp_path / "tiles"
    with pytest.raises(RuntimeError, match="worker died"):
        with atomic_folder(out, mark="a.parquet") as work:
            (work / "a.parquet").write_text("half")
            raise RuntimeError("worker died")
    assert list(tmp_path.iterdir()) == []
    with atomic_folder(out, mark="a.parquet") as work:
        assert work.parent == tmp_path and work.name.startswith(".tiles.part-")
        (work / "a.parquet").write_text("old")
    assert [p.name for p in tmp_path.iterdir()] == ["tiles"]
    with pytest.raises(InputError, match="output exists"):
        with atomic_folder(out, mark="a.parquet"):
            pytest.fail("the block must not run")
    with atomic_folder(out, overwrite=True, mark="a.parquet") as work:
        (work / "b.parquet").write_text("new")
    assert [p.name for p in tmp_path.iterdir()] == ["tiles"]
    assert sorted(p.name for p in out.iterdir()) == [MANIFEST, "b.parquet"]
    (tmp_path / "file").write_text("x")
    with pytest.raises(InputError, match="is a file"):
        with atomic_folder(tmp_path / "file", overwrite=True, mark="a.parquet"):
            pass
    with pytest.raises(InputError, match="output folder does not exist"):
        with atomic_folder(tmp_path / "missing" / "tiles", mark="a.parquet"):
            pass


def test_overwrite_replaces_only_a_folder_the_output_wrote(tmp_path, monkeypatch):
    """A folder without the output's mark (its index) is someone's: --overwrite does not take
    it, nor its files; an empty folder, or one the output wrote, is replaced."""
    mine = tmp_path / "Documents"
    mine.mkdir()
    (mine / "thesis.txt").write_text("years of work")
    with pytest.raises(InputError, match="has no tiles.gpkg") as caught:
        with atomic_folder(mine, overwrite=True, mark="tiles.gpkg"):
            pytest.fail("the block must not run")
    assert caught.value.fix == "give a new folder, or empty this one"
    assert [p.name for p in mine.iterdir()] == ["thesis.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["Documents"]
    empty = tmp_path / "empty"
    empty.mkdir()
    for folder in (empty, empty):  # empty, then one it wrote
        with atomic_folder(folder, overwrite=True, mark="tiles.gpkg") as work:
            (work / "tiles.gpkg").write_text("index")
        assert sorted(p.name for p in folder.iterdir()) == [MANIFEST, "tiles.gpkg"]
    monkeypatch.chdir(mine)  # "-o ." names the folder one is in
    with pytest.raises(InputError, match="has no tiles.gpkg"):
        with atomic_folder(".", overwrite=True, mark="tiles.gpkg"):
            pytest.fail("the block must not run")
    assert [p.name for p in mine.iterdir()] == ["thesis.txt"]
