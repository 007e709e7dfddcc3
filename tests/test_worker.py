"""The worker that runs the QGIS plugin's jobs in a child Python (issue 12), driven as the
plugin drives it: JSON in, JSON lines out, SIGINT to cancel. The plugin itself is tested in a
real QGIS (qgis_plugin/tests)."""

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import geopandas as gpd
import pandas as pd
import pytest
from test_cli import run

CITY = Path(__file__).resolve().parents[1] / "examples" / "city"


def child(request: dict, ignoring_sigint: bool = False) -> subprocess.Popen:
    """The worker running ``request``; started as by a host that ignores SIGINT (a process run
    in the background by a shell) with ``ignoring_sigint``."""
    ignore = (lambda: signal.signal(signal.SIGINT, signal.SIG_IGN)) if ignoring_sigint else None
    process = subprocess.Popen(
        [sys.executable, "-m", "gnss_citygml.worker"],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=ignore,
    )
    assert process.stdin is not None
    process.stdin.write(json.dumps(request))
    process.stdin.close()
    return process


def answers(process: subprocess.Popen) -> list[dict]:
    assert process.stdout is not None
    lines = [json.loads(line) for line in process.stdout]  # every line is one JSON object
    process.wait()
    return lines


def estimate(output: Path, **extra) -> dict:
    args = {
        "observations": str(CITY / "observations.parquet"),
        "footprints": str(CITY / "footprints.gpkg"),
        "dem": str(CITY / "dem.tif"),
        "output": str(output),
        **extra,
    }
    return {"job": "estimate", "args": args}


def test_estimate_reports_its_stages_and_writes_the_clis_heights(
    grid_dir, grid_args, tmp_path, capsys
):
    grids = None if grid_dir is None else str(grid_dir)
    request = estimate(tmp_path / "w.gpkg", rays={"min_elevation": 15}, grid_dir=grids)
    process = child(request)
    said = answers(process)
    assert process.returncode == 0, process.stderr.read()
    stages = [m["progress"][0] for m in said if "progress" in m]
    assert stages == [
        "observations",
        "receivers",
        "buildings",
        "ray casting",
        "height model",
        "output",
        "done",
    ]
    (result,) = [m["result"] for m in said if "result" in m]
    ours = gpd.read_file(tmp_path / "w.gpkg", layer="heights")
    assert result == {"buildings": len(ours), "converged": int(ours["converged"].sum())}
    code, _, err = run(
        [
            "estimate",
            str(CITY / "observations.parquet"),
            str(CITY / "footprints.gpkg"),
            "--dem",
            str(CITY / "dem.tif"),
            "--min-elevation",
            "15",
            "-o",
            str(tmp_path / "cli.gpkg"),
            *grid_args,
            "-q",
        ],
        capsys,
    )
    assert code == 0, err
    theirs = gpd.read_file(tmp_path / "cli.gpkg", layer="heights")
    assert ours.drop(columns="geometry").equals(theirs.drop(columns="geometry"))


def test_an_error_is_the_clis_one_line_message(tmp_path, capsys):
    request = estimate(tmp_path / "w.gpkg")
    request["args"]["observations"] = str(tmp_path / "none.parquet")
    process = child(request)
    said = answers(process)
    assert process.returncode == 2
    args = request["args"]
    cli = [args["observations"], args["footprints"], "--dem", args["dem"], "-o", args["output"]]
    code, _, err = run(["estimate", *cli], capsys)
    assert code == 2 and said == [{"error": err.strip().removeprefix("error: ")}]
    assert not (tmp_path / "w.gpkg").exists()


def test_settings_are_checked_as_the_settings_objects_check_them(tmp_path):
    said = answers(child(estimate(tmp_path / "w.gpkg", estimator={"method": "magic"})))
    (error,) = [m["error"] for m in said]
    assert "magic" in error and "4PL-B" in error


@pytest.mark.parametrize("ignoring_sigint", [False, True])
def test_sigint_cancels_and_leaves_nothing(tmp_path, ignoring_sigint):
    process = child(estimate(tmp_path / "w.gpkg"), ignoring_sigint)
    assert process.stdout is not None
    first = json.loads(process.stdout.readline())
    assert first == {"progress": ["observations", 0.0]}
    process.send_signal(signal.SIGINT)
    said = [first, *answers(process)]
    assert said[-1] == {"error": "cancelled"} and process.returncode == 130
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("suffix", [".city.json", ".gml"])
def test_convert_and_validate(suffix, grid_dir, tmp_path):
    heights = tmp_path / "h.gpkg"
    grids = None if grid_dir is None else str(grid_dir)
    assert answers(child(estimate(heights, grid_dir=grids)))[-1].keys() == {"result"}
    model = tmp_path / f"m{suffix}"
    request = {"job": "convert", "args": {"source": str(heights), "output": str(model)}}
    said = answers(child(request))
    result = said[-1]["result"]
    assert result["validated"] and result["written"] > 0 and model.is_file()
    assert said[-2] == {"progress": ["done", 1.0]}
    said = answers(child({"job": "validate", "args": {"path": str(model)}}))
    report = said[-1]["result"]
    assert report["valid"] and report["errors"] == [] and report["exit_code"] == 0


def test_update(grid_dir, tmp_path):
    import shutil

    shutil.copy(CITY / "footprints.gpkg", tmp_path / "map.gpkg")
    args = {
        "path": str(tmp_path / "map.gpkg"),
        "observations": [str(CITY / "observations.parquet")],
        "dem": str(CITY / "dem.tif"),
        "grid_dir": None if grid_dir is None else str(grid_dir),
        "estimator": {"init_threshold": 30.0},
    }
    said = answers(child({"job": "update", "args": args}))
    result = said[-1]["result"]
    assert result["written"] and result["updated"] == 30 and result["new_signals"] > 0
    assert result["lines"][0].startswith(f"{result['new_signals']} new signals cast")
    assert [m["progress"][0] for m in said if "progress" in m][-1] == "done"
    again = answers(child({"job": "update", "args": args}))[-1]["result"]
    assert not again["written"] and again["new_signals"] == 0


def test_a_library_that_cannot_be_imported_is_the_installation_not_a_bug(tmp_path):
    """A dependency half installed (its import fails while a job runs) is said as the user's
    installation with the fix, by the command line and by the plugin's worker alike: never
    "internal error ... please report it"."""
    broken = tmp_path / "site" / "pyarrow"
    broken.mkdir(parents=True)
    (broken / "__init__.py").write_text(
        "raise ImportError('libarrow.so.1800: cannot open shared object file', name='pyarrow')\n"
    )
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(broken.parent), *sys.path])}
    inputs = [CITY / "observations.parquet", CITY / "footprints.gpkg", "--dem", CITY / "dem.tif"]
    command = [sys.executable, "-m", "gnss_citygml", "estimate", *inputs, "-o", tmp_path / "h.gpkg"]
    done = subprocess.run(command, capture_output=True, text=True, env=env)
    assert done.returncode == 2 and done.stderr.count("\n") == 1, done.stderr
    assert done.stderr.startswith("error: the installation is broken: importing ")
    assert "--force-reinstall" in done.stderr and "internal error" not in done.stderr
    process = subprocess.run(
        [sys.executable, "-m", "gnss_citygml.worker"],
        input=json.dumps(estimate(tmp_path / "w.gpkg")),
        capture_output=True,
        text=True,
        env=env,
    )
    said = [json.loads(line) for line in process.stdout.splitlines()]
    assert process.returncode == 2 and said[-1]["error"].startswith("the installation is broken")
    assert not (tmp_path / "h.gpkg").exists() and not (tmp_path / "w.gpkg").exists()


DEMO_2016 = "google_demo_pseudoranges_log_2016_08_22_14_45_50.txt"
DEMO_JUNE = "google_demo_pseudoranges_log_2016_06_30_21_26_07.txt"


def test_observe_writes_the_clis_observations(repo_data, tmp_path, capsys):
    """Two logs with the orbit files of each: the command line's table, its summary, the
    logs' warnings passed on, progress log by log."""
    logs = [str(repo_data / "gnss" / name) for name in (DEMO_2016, DEMO_JUNE)]
    orbits = [str(repo_data / "orbits" / name) for name in ("hour2350.16n", "hour1820.16n")]
    args = {"logs": logs, "orbit_files": orbits, "output": str(tmp_path / "w.parquet")}
    said = answers(child({"job": "observe", "args": {**args, "min_elevation": 15.0}}))
    result = said[-1]["result"]
    flags = [flag for orbit in orbits for flag in ("--orbits", orbit)]
    cli = [*logs, *flags, "--min-elevation", "15", "-o", str(tmp_path / "cli.parquet"), "-q"]
    code, out, err = run(["observe", *cli], capsys)
    assert code == 0, err
    assert out.strip() == f"{result['summary']} -> {tmp_path / 'cli.parquet'}"
    ours, theirs = (
        pd.read_parquet(tmp_path / "w.parquet"),
        pd.read_parquet(tmp_path / "cli.parquet"),
    )
    pd.testing.assert_frame_equal(ours, theirs)
    assert result["signals"] == len(ours) > 0 and ours["elevation"].min() >= 15.0
    assert [m["progress"] for m in said if "progress" in m] == [
        [Path(logs[0]).stem, 0.5],
        [Path(logs[1]).stem, 1.0],
        ["done", 1.0],
    ]
    assert any("without orbit data" in m.get("warning", "") for m in said)
    # an error is the command line's one line, before any log is read
    wrong = str(tmp_path / "o.xlsx")
    said = answers(child({"job": "observe", "args": {**args, "output": wrong}}))
    code, _, err = run(["observe", *logs, *flags, "-o", wrong], capsys)
    assert code == 2 and said == [{"error": err.strip().removeprefix("error: ")}]
    assert "unknown table format" in err


def _buildings_table(page: Path) -> str:
    """The report page's tables of the buildings (what does not depend on the time nor on how
    the PNGs were compressed)."""
    return page.read_text(encoding="utf-8").split("<h2>Buildings by status</h2>")[1]


def test_report_writes_the_clis_report(grid_dir, grid_args, tmp_path, capsys):
    grids = None if grid_dir is None else str(grid_dir)
    request = estimate(tmp_path / "unused.gpkg", grid_dir=grids, report=str(tmp_path / "w"))
    request["job"] = "report"
    said = answers(child(request))
    result = said[-1]["result"]
    assert result["page"] == str(tmp_path / "w" / "report.html")
    assert [m["progress"][0] for m in said if "progress" in m][-2:] == ["report", "done"]
    inputs = [CITY / "observations.parquet", CITY / "footprints.gpkg", "--dem", CITY / "dem.tif"]
    code, _, err = run(["report", *map(str, inputs), "-o", str(tmp_path / "cli"), *grid_args, "-q"],
                       capsys)  # fmt: skip
    assert code == 0, err
    assert _buildings_table(tmp_path / "w" / "report.html") == _buildings_table(
        tmp_path / "cli" / "report.html"
    )
    figures = sorted(p.name for p in (tmp_path / "cli" / "figures").iterdir())
    assert sorted(p.name for p in (tmp_path / "w" / "figures").iterdir()) == figures
    assert result["buildings"] == 30 and result["converged"] > 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cli", "w"]  # no heights layer
