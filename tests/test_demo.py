"""`gnss-citygml demo` from the user's side: the sample city through `estimate` and `convert`,
the files left behind, and the table that compares every estimate with the simulator's truth."""

import json
import os
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pyogrio
import pytest

from gnss_citygml.cli import main
from gnss_citygml.cli.demo import CITY, OUTPUTS, REPORT_OUTPUTS
from gnss_citygml.geodesy.grids import GRID_DIR_ENV


def run(args, capsys):
    with pytest.raises(SystemExit) as exc:
        main([str(a) for a in args])
    out = capsys.readouterr()
    return exc.value.code, out.out, out.err


def test_demo_writes_the_models_and_compares_with_the_truth(tmp_path, capsys, monkeypatch):
    monkeypatch.delenv(GRID_DIR_ENV, raising=False)  # the grids found as for a user
    folder = tmp_path / "new" / "out"  # made by the demo
    code, out, err = run(["demo", "-o", folder, "--quiet"], capsys)
    assert code == 0, err
    assert sorted(p.name for p in folder.iterdir()) == sorted(
        OUTPUTS + REPORT_OUTPUTS
    )  # no temporary file left
    assert json.loads((folder / "city.city.json").read_text())["type"] == "CityJSON"
    assert "valid (json, structure, geometry)" in out and "valid (xml, xsd, geometry)" in out
    assert (folder / "city.gml").read_bytes().startswith(b"<?xml")

    heights = pyogrio.read_dataframe(folder / "heights.gpkg", layer="heights").set_index("id")
    truth = pd.read_csv(CITY / "truth.csv").set_index("id")
    lines = out.splitlines()
    start = lines.index(next(line for line in lines if line.split()[:2] == ["id", "estimate"]))
    table = [line.split(maxsplit=7) for line in lines[start + 1 : start + 31]]
    assert sorted(row[0] for row in table) == sorted(truth.index)
    for bid, estimate, span, true, roof, error, to_span, status in table:
        h, t = heights.loc[bid], truth.loc[bid]
        assert true == f"{t['height'] - t['ground']:.2f}"
        assert roof == f"{t['roof_low'] - t['ground']:.2f}-{t['roof_high'] - t['ground']:.2f}"
        assert status == h["status"]
        if h["converged"]:
            assert estimate == f"{h['relative_height']:.2f}"
            assert error == f"{h['height'] - t['height']:+.2f}"
            off = max(t["roof_low"] - h["height"], h["height"] - t["roof_high"], 0.0)
            assert to_span == f"{off:.2f}"
            assert (
                span
                == f"{h['height_lower'] - h['ground']:.2f}-{h['height_upper'] - h['ground']:.2f}"
            )
        else:
            assert estimate == span == error == to_span == "-"
    ok = heights["converged"].astype(bool)
    height = heights["height"]
    low, high = (truth[c].reindex(heights.index) for c in ("roof_low", "roof_high"))
    errors = (height - truth["height"].reindex(heights.index))[ok]
    off_span = ((low - height).clip(lower=0) + (height - high).clip(lower=0))[ok]
    meets = heights["height_lower"].le(high) & heights["height_upper"].ge(low)
    assert (low < high).any() and (off_span < errors.abs() - 1e-9).any()  # the span counts
    assert lines[start + 31] == (
        f"{ok.sum()} of 30 buildings converged, RMSE {np.sqrt(np.mean(off_span**2)):.2f} m to "
        f"the roof span, {np.sqrt(np.mean(errors**2)):.2f} m to its middle, range meeting the "
        f"span for {(meets & ok).sum()} of {ok.sum()}"
    )
    assert ok.sum() == 24  # as `estimate` on the sample city (README)
    readme = (Path(__file__).parents[1] / "README.md").read_text(encoding="utf-8")
    assert f"\n{lines[start + 31]}\n" in readme, (
        "the README's demo line is stale: " + lines[start + 31]
    )

    # Again without --overwrite: refused before any work, the files untouched.
    before = {p.name: p.stat().st_mtime_ns for p in folder.iterdir()}
    code, out, err = run(["demo", "-o", folder], capsys)
    assert code == 2 and out == ""
    assert (
        err
        == f"error: output exists ({folder / 'heights.gpkg'}): choose another name or --overwrite\n"
    )
    assert {p.name: p.stat().st_mtime_ns for p in folder.iterdir()} == before
    code, out, _ = run(["demo", "-o", folder, "--overwrite", "-q"], capsys)
    assert code == 0 and out.splitlines()[-1] == lines[start + 31]
    assert sorted(p.name for p in folder.iterdir()) == sorted(OUTPUTS + REPORT_OUTPUTS)


def test_demo_refuses_a_file_as_its_folder_and_an_existing_model(tmp_path, capsys):
    afile = tmp_path / "file"
    afile.write_text("mine")
    code, out, err = run(["demo", "-o", afile], capsys)
    assert (code, out) == (2, "")
    assert err == f"error: the output folder is a file ({afile}): give a folder\n"
    assert afile.read_text() == "mine"
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "city.gml").write_text(
        "mine"
    )  # the last output: checked first all the same
    code, out, err = run(["demo", "-o", tmp_path / "out"], capsys)
    assert code == 2 and out == "" and "output exists" in err and "city.gml" in err
    assert [p.name for p in (tmp_path / "out").iterdir()] == ["city.gml"]
    assert (tmp_path / "out" / "city.gml").read_text() == "mine"


@pytest.mark.parametrize("command", [["demo"], ["simulate", "ucl"]])
def test_a_folder_that_cannot_be_made_is_one_error_line(command, tmp_path, capsys):
    """A folder under a file cannot be created: one line naming it, not an internal error."""
    (tmp_path / "file").write_text("mine")
    inside = tmp_path / "file" / "out"
    code, out, err = run([*command, "-o", inside], capsys)
    assert (code, out) == (2, "")
    assert err.startswith(f"error: cannot create the output folder ({inside}): check the path")
    assert err.count("\n") == 1 and (tmp_path / "file").read_text() == "mine"


def test_demo_over_a_geopackage_with_other_layers(tmp_path, capsys):
    """estimate keeps the GeoPackage's other layers: the demo converts its own `heights`
    layer, not "several layers, choose one" halfway through."""
    folder = tmp_path / "out"
    folder.mkdir()
    fp = pyogrio.read_dataframe(CITY / "footprints.gpkg")
    pyogrio.write_dataframe(fp, folder / "heights.gpkg", layer="mine")
    code, out, err = run(["demo", "-o", folder, "--overwrite", "-q"], capsys)
    assert code == 0, err
    assert sorted(pyogrio.list_layers(folder / "heights.gpkg")[:, 0]) == [
        "heights",
        "layer_styles",
        "mine",
    ]
    assert sorted(p.name for p in folder.iterdir()) == sorted(OUTPUTS + REPORT_OUTPUTS)


def test_a_reader_that_stops_early_does_not_cut_the_job_short(tmp_path):
    """`demo -o DIR | head -1`: every file is written before the first line is printed."""
    folder = tmp_path / "out"
    run_ = subprocess.run(
        f"{shlex.quote(sys.executable)} -m gnss_citygml demo -o {shlex.quote(str(folder))} -q"
        " | head -1",
        shell=True,
        capture_output=True,
        text=True,
        env={k: v for k, v in os.environ.items() if k != GRID_DIR_ENV},
    )
    assert run_.stdout.count("\n") == 1
    assert sorted(p.name for p in folder.iterdir()) == sorted(OUTPUTS + REPORT_OUTPUTS)


def test_simulate_refuses_a_zero_interval(tmp_path, capsys):
    code, out, err = run(["simulate", "ucl", "-o", tmp_path / "s", "--interval", "0"], capsys)
    assert code == 2 and "--interval" in err and "internal error" not in err
    assert not (tmp_path / "s").exists()
