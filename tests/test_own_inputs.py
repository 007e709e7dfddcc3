"""No command writes over one of its own inputs, by whatever name the output reaches it: the
same path, ``./x``, a relative path, a symbolic or a hard link, a folder output that holds
an input, an output inside an input folder (issue 26). A new layer beside the footprints in
their own GeoPackage is still written; the layer read never is."""

import hashlib
import os
import shutil
from pathlib import Path

import pandas as pd
import pyogrio
import pytest
from test_cli import run

CITY = Path(__file__).resolve().parents[1] / "examples" / "city"


def digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture
def inputs(tmp_path, monkeypatch):
    """The city's inputs, copied into the working folder."""
    for name in ("observations.parquet", "footprints.gpkg", "dem.tif", "truth.csv"):
        shutil.copy(CITY / name, tmp_path / name)
    monkeypatch.chdir(tmp_path)
    return tmp_path


def refused(capsys, args, message="the output would replace the input") -> None:
    code, _, err = run(args, capsys)
    assert code == 2 and message in err, err
    assert len(err.strip().splitlines()) == 1


def estimate(observations, footprints, output, *extra) -> list:
    return [
        "estimate", str(observations), str(footprints), "--dem", "dem.tif", "-o", str(output),
        "-q", *extra,
    ]  # fmt: skip


@pytest.mark.parametrize("spelling", ["same", "dot", "relative", "absolute", "symlink", "hardlink"])
def test_estimate_never_writes_over_its_observations(spelling, inputs, grid_args, capsys):
    obs = inputs / "observations.parquet"
    before = digest(obs)
    output = {
        "same": "observations.parquet",
        "dot": "./observations.parquet",
        "relative": f"../{inputs.name}/observations.parquet",
        "absolute": str(obs),
        "symlink": "link.parquet",
        "hardlink": "hard.parquet",
    }[spelling]
    os.symlink(obs, inputs / "link.parquet")
    os.link(obs, inputs / "hard.parquet")
    refused(capsys, [*estimate("observations.parquet", "footprints.gpkg", output), *grid_args,
                     "--overwrite"])  # fmt: skip
    assert digest(obs) == before and (inputs / "link.parquet").is_symlink()


def test_the_dem_and_the_truth_are_inputs_too(inputs, grid_args, capsys):
    os.symlink(inputs / "dem.tif", inputs / "dem.fgb")
    args = estimate("observations.parquet", "footprints.gpkg", "dem.fgb", *grid_args)
    refused(capsys, [*args, "--overwrite"])
    shutil.copy(inputs / "truth.csv", inputs / "report.html")
    args = estimate("observations.parquet", "footprints.gpkg", "h.fgb", *grid_args)
    refused(capsys, [*args, "--report", ".", "--truth", "report.html", "--overwrite"])
    assert not (inputs / "h.fgb").exists()


def test_a_new_layer_beside_the_footprints_but_never_over_them(inputs, grid_args, capsys):
    """The footprints' own GeoPackage takes the layer 'heights' (as before), replaced again
    with --overwrite when the footprints' layer is named; a file whose only layer is
    'heights' is the layer read: refused, in any case of its name."""
    fp = inputs / "footprints.gpkg"
    footprints = pyogrio.read_dataframe(fp)
    code, _, err = run([*estimate("observations.parquet", fp, fp), *grid_args], capsys)
    assert code == 0, err
    args = [*estimate("observations.parquet", fp, fp), *grid_args, "--overwrite"]
    refused(capsys, args, "the output's layer 'heights' would replace the layer read")
    for layer in ("Heights", "heights"):
        refused(capsys, [*args, "--layer", layer], "would replace the layer read")
    code, _, err = run([*args, "--layer", "footprints"], capsys)
    assert code == 0, err
    assert pyogrio.read_dataframe(fp, layer="footprints").equals(footprints)
    assert len(pyogrio.read_dataframe(fp, layer="heights")) == len(footprints)
    only = inputs / "only.gpkg"
    pyogrio.write_dataframe(footprints, only, layer="HEIGHTS")
    before = digest(only)
    refused(capsys, [*estimate("observations.parquet", only, only), *grid_args, "--overwrite"],
            "would replace the layer read")  # fmt: skip
    assert digest(only) == before


def test_convert_export_and_heights_never_write_over_their_inputs(inputs, grid_args, capsys):
    heights = inputs / "heights.gpkg"
    code, _, err = run([*estimate("observations.parquet", "footprints.gpkg", heights),
                        *grid_args], capsys)  # fmt: skip
    assert code == 0, err
    os.link(heights, inputs / "heights.city.json")  # a hard link: the same file
    before = digest(heights)
    refused(capsys, ["convert", "heights.gpkg", "-o", "heights.city.json", "--overwrite", "-q"])
    table = inputs / "heights.csv"
    pd.DataFrame(pyogrio.read_dataframe(heights, layer="heights").drop(columns="geometry")).to_csv(
        table
    )
    os.symlink(inputs / "footprints.gpkg", inputs / "fp.gml")
    refused(capsys, ["export", "heights.csv", "--footprints", "footprints.gpkg", "-o", "fp.gml",
                     "--overwrite", "-q"])  # fmt: skip
    refused(capsys, ["heights", "./heights.csv", "-o", "heights.csv", "--overwrite"])
    assert digest(heights) == before and (inputs / "fp.gml").is_symlink()


def test_observe_refuses_before_reading(inputs, capsys):
    (inputs / "log.txt").write_text("# Header\n")
    (inputs / "points.csv").write_text("receiver,start_utc,end_utc,lat,lon,h\n")
    refused(capsys, ["observe", "log.txt", "--orbits", "log.txt", "--positions", "points.csv",
                     "-o", "points.csv", "--overwrite"])  # fmt: skip


def test_a_folder_output_holding_an_input_or_inside_one(inputs, grid_args, capsys):
    args = ["partition", "observations.parquet", "--dem", "dem.tif", *grid_args, "-q"]
    code, _, err = run([*args, "-o", "part"], capsys)
    assert code == 0, err
    parts = sorted((inputs / "part").rglob("*.parquet"))
    before = [digest(p) for p in parts]
    refused(capsys, ["partition", str(parts[0]), "--dem", "dem.tif", "-o", "part", "-q",
                     "--overwrite"], "the output is a folder that holds the input")  # fmt: skip
    refused(capsys, ["partition", "observations.parquet", "--dem", "dem.tif", "-o", ".", "-q",
                     "--overwrite"], "holds the input")  # fmt: skip
    assert [digest(p) for p in parts] == before


def test_the_backup_of_an_update_is_no_input(inputs, grid_args, capsys):
    """MAP.bak.gpkg given as the DEM (a link to it): the backup would replace it."""
    os.symlink(inputs / "dem.tif", inputs / "footprints.bak.gpkg")
    before = digest(inputs / "footprints.gpkg")
    refused(capsys, ["update", "footprints.gpkg", "--observations", "observations.parquet",
                     "--dem", "footprints.bak.gpkg", *grid_args, "-q"],
            "the backup would replace the input footprints.bak.gpkg")  # fmt: skip
    assert digest(inputs / "footprints.gpkg") == before
    assert (inputs / "footprints.bak.gpkg").is_symlink()
