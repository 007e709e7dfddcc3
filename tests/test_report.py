"""The report of a run (issue 13): the figures' data as tables, the page self-contained, the
files where they are promised and never half-written, and the commands that write it."""

import base64
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from test_cli import run as run_cli

import gnss_citygml as gc
from gnss_citygml.cli.demo import OUTPUTS
from gnss_citygml.compare import compare, summary
from gnss_citygml.model.mixture import Cn0Mixture
from gnss_citygml.pipeline import run
from gnss_citygml.report import (
    REPORT,
    binned_open,
    blocked_by_others,
    fit_sample,
    signal_states,
    write_report,
)

CITY = Path(__file__).resolve().parents[1] / "examples" / "city"
FIGURES = ["cn0.png", "fits.png", "map.png", "ranges.png", "skyplots.png"]


@pytest.fixture(scope="module")
def city_run(grid_dir):
    obs = gc.read_observations(CITY / "observations.parquet")
    footprints = gc.read_footprints(CITY / "footprints.gpkg")
    return run(obs, footprints, CITY / "dem.tif", grid_dir=grid_dir)


@pytest.fixture(scope="module")
def truth():
    return pd.read_csv(CITY / "truth.csv")


def test_signal_states(city_run):
    states = signal_states(city_run)
    assert len(states) == len(city_run.receivers)
    blocked = np.isnan(city_run.receivers["cn0"].to_numpy())
    assert ((states["state"] == "blocked") == blocked).all()
    threshold = city_run.classifier.threshold
    received = states[~blocked]
    assert (received.loc[received["cn0"] > threshold + 0.5, "state"] == "open").all()
    assert (received.loc[received["cn0"] < threshold - 0.5, "state"] == "closed").all()
    # a ray below a fitted roof line is closed on the map, whatever its C/N0
    inter = city_run.intersections
    roofs = city_run.heights.set_index("id")["c"]
    below = inter["height"].to_numpy() <= roofs.reindex(inter["building"]).to_numpy()
    assert below.any()
    assert not states["map_open"].to_numpy()[inter["signal"].to_numpy()[below]].any()


def test_blocked_by_others():
    inter = pd.DataFrame(
        {"signal": [0, 0, 1, 2], "building": ["a", "b", "a", "b"], "height": [5.0, 30, 5, 5]}
    )
    roofs = pd.Series({"a": 10.0, "b": 20.0})
    # signal 0 passes below a's roof: it says nothing about b; its row for a is a's own data
    assert blocked_by_others(inter, roofs).tolist() == [False, True, False, False]


def test_fit_sample_takes_the_worst_the_best_and_a_sample():
    table = pd.DataFrame(
        {
            "id": [f"b{i}" for i in range(20)],
            "c": [10.0] * 19 + [np.nan],
            "height_lower": [10.0] * 20,
            "height_upper": [10.0 + i for i in range(20)],
            "converged": [True] * 15 + [False] * 5,
        }
    )
    chosen = fit_sample(table, each=3)
    by = chosen.groupby("why")["id"].apply(list)
    assert by["worst"] == ["b14", "b13", "b12"]  # the widest ranges among the converged
    assert by["best"] == ["b0", "b1", "b2"]
    assert len(by["sample"]) == 3 and not set(by["sample"]) & {"b0", "b1", "b2", "b12", "b13"}
    assert "b19" not in chosen["id"].tolist()  # no fit, nothing to draw
    with_errors = table.assign(error=[0.1 * i for i in range(20)][::-1])
    assert fit_sample(with_errors, each=1).set_index("why")["id"]["worst"] == "b0"


def test_binned_open_of_nothing():
    assert binned_open(np.array([]), np.array([], dtype=bool)).empty


def test_the_page_is_self_contained_and_the_figures_are_beside_it(city_run, truth, tmp_path):
    page = write_report(city_run, tmp_path / "r", truth=truth, title="sample <city>")
    assert page == tmp_path / "r" / REPORT
    assert sorted(p.name for p in (tmp_path / "r").iterdir()) == ["figures", REPORT]
    assert sorted(p.name for p in (tmp_path / "r" / "figures").iterdir()) == FIGURES
    text = page.read_text()
    assert "<title>sample &lt;city&gt;</title>" in text  # escaped
    sources = re.findall(r'src="([^"]+)"', text)
    assert len(sources) == len(FIGURES)
    assert all(s.startswith("data:image/png;base64,") for s in sources)  # nothing outside
    embedded = {base64.b64decode(s.split(",", 1)[1]) for s in sources}
    on_disk = {(tmp_path / "r" / "figures" / name).read_bytes() for name in FIGURES}
    assert embedded == on_disk and all(png.startswith(b"\x89PNG") for png in on_disk)
    assert not re.search(r"(href|src)=\"https?:", text)
    assert summary(compare(city_run.heights, truth)) in text
    for building in city_run.heights["id"]:
        assert f"<td>{building}</td>" in text
    for status, n in city_run.heights["status"].value_counts().items():
        assert f"<td>{status}</td>\n      <td>{n}</td>" in text


def test_an_existing_report_needs_overwrite(city_run, tmp_path):
    write_report(city_run, tmp_path)
    before = (tmp_path / REPORT).read_bytes()
    with pytest.raises(gc.InputError, match="exists"):
        write_report(city_run, tmp_path, overwrite=False)
    assert (tmp_path / REPORT).read_bytes() == before


def test_estimate_report_and_demo_write_it(grid_args, tmp_path, capsys):
    files = [str(CITY / "observations.parquet"), str(CITY / "footprints.gpkg")]
    common = [*files, "--dem", str(CITY / "dem.tif"), *grid_args, "-q"]
    out = tmp_path / "h.gpkg"
    code, stdout, err = run_cli(
        ["estimate", *common, "-o", str(out), "--report", str(tmp_path / "a")], capsys
    )
    assert code == 0, err
    assert out.is_file() and (tmp_path / "a" / REPORT).is_file()
    assert stdout.splitlines()[-1] == f"report -> {tmp_path / 'a' / REPORT}"
    code, stdout, err = run_cli(
        ["report", *common, "-o", str(tmp_path / "b"), "--truth", str(CITY / "truth.csv")], capsys
    )
    assert code == 0, err
    assert "range meeting the span" in (tmp_path / "b" / REPORT).read_text()
    # an existing report: refused before the work, nothing else written
    code, _, err = run_cli(
        ["estimate", *common, "-o", str(tmp_path / "h2.gpkg"), "--report", str(tmp_path / "a")],
        capsys,
    )
    assert code == 2 and "exists" in err and "report.html" in err
    assert not (tmp_path / "h2.gpkg").exists()


def test_without_matplotlib_one_line_says_what_to_install(grid_args, tmp_path):
    """matplotlib is an extra: made unimportable (as Python does for a missing module), the
    report is one line naming it, before any work; the demo writes all else and says why
    there is no report."""
    files = [CITY / "observations.parquet", CITY / "footprints.gpkg", "--dem", CITY / "dem.tif"]
    block = "import sys; sys.modules['matplotlib'] = None; from gnss_citygml.cli import main; "
    args = ["report", *map(str, files), *grid_args, "-o", str(tmp_path / "r")]
    done = subprocess.run(
        [sys.executable, "-c", block + f"main({args!r})"], capture_output=True, text=True
    )
    assert done.returncode == 2 and not (tmp_path / "r").exists()
    assert done.stderr.startswith("error: the report needs matplotlib, which is not installed")
    assert "pip install 'gnss-citygml[plot]'" in done.stderr
    args = ["demo", "-o", str(tmp_path / "d"), "-q"]
    done = subprocess.run(
        [sys.executable, "-c", block + f"main({args!r})"], capture_output=True, text=True
    )
    assert done.returncode == 0, done.stderr
    assert "note: no report.html: the report needs matplotlib" in done.stderr
    assert sorted(p.name for p in (tmp_path / "d").iterdir()) == sorted(OUTPUTS)


@pytest.mark.parametrize("method", ["hinge", "bayes"])
def test_a_baseline_without_ranges_has_a_report(method, grid_dir, tmp_path):
    """The baselines give heights without a range: the range figure says so, no crash."""
    obs = gc.read_observations(CITY / "observations.parquet")
    footprints = gc.read_footprints(CITY / "footprints.gpkg")
    baseline = run(obs, footprints, CITY / "dem.tif", grid_dir=grid_dir,
                   estimator=gc.Estimator(method=method))  # fmt: skip
    page = write_report(baseline, tmp_path)
    assert page.is_file() and len(list((tmp_path / "figures").iterdir())) == len(FIGURES)


def test_a_bad_truth_table_is_refused_before_the_work(grid_args, tmp_path, capsys):
    bad = tmp_path / "truth.csv"
    pd.read_csv(CITY / "truth.csv").drop(columns="ground").to_csv(bad, index=False)
    files = [str(CITY / "observations.parquet"), str(CITY / "footprints.gpkg")]
    args = ["report", *files, "--dem", str(CITY / "dem.tif"), *grid_args, "-q"]
    code, _, err = run_cli([*args, "-o", str(tmp_path / "r"), "--truth", str(bad)], capsys)
    assert code == 2 and "'ground'" in err and not (tmp_path / "r").exists()
    twice = tmp_path / "twice.csv"
    table = pd.read_csv(CITY / "truth.csv")
    pd.concat([table, table.iloc[:2]]).to_csv(twice, index=False)
    code, _, err = run_cli([*args, "-o", str(tmp_path / "r"), "--truth", str(twice)], capsys)
    assert code == 2 and "2 building id(s) more than once" in err


def test_a_truth_table_without_a_report_is_refused(grid_args, tmp_path, capsys):
    """The truth is only shown in the report: given alone, it would be read and then ignored."""
    files = [str(CITY / "observations.parquet"), str(CITY / "footprints.gpkg")]
    args = ["estimate", *files, "--dem", str(CITY / "dem.tif"), *grid_args, "-q"]
    code, _, err = run_cli(
        [*args, "-o", str(tmp_path / "h.gpkg"), "--truth", str(CITY / "truth.csv")], capsys
    )
    assert code == 2 and "no report was asked for" in err and not (tmp_path / "h.gpkg").exists()


#: Names matplotlib would read as math text or TeX (and fail on, or draw otherwise), with a
#: line end, a control character and one far too long for a title.
TAMPERED_NAMES = ["$\\frac{$", "$x^2$", "a_b^c", "50% {x}", "back\\slash", "$a$\n$b$", "z" * 300]


def test_names_are_drawn_literally(city_run, tmp_path):
    """Ids and receiver names (log file names) are the user's text: none is math text."""
    import dataclasses

    ids = city_run.heights["id"].astype(str).unique()
    new_ids = {old: f"{TAMPERED_NAMES[i % len(TAMPERED_NAMES)]}{i}" for i, old in enumerate(ids)}
    receivers = city_run.receivers["receiver"].astype(str).unique()
    new_receivers = {old: f"{TAMPERED_NAMES[i % 7]}{i}" for i, old in enumerate(receivers)}
    tampered = dataclasses.replace(
        city_run,
        heights=city_run.heights.assign(id=city_run.heights["id"].map(new_ids)),
        buildings=city_run.buildings.assign(id=city_run.buildings["id"].map(new_ids)),
        intersections=city_run.intersections.assign(
            building=city_run.intersections["building"].map(new_ids)
        ),
        receivers=city_run.receivers.assign(
            receiver=city_run.receivers["receiver"].map(new_receivers)
        ),
    )
    page = write_report(tampered, tmp_path / "r", title="$\\bad{$ report")
    text = page.read_text()
    assert "<h1>$\\bad{$ report</h1>" in text
    assert sorted(p.name for p in (tmp_path / "r" / "figures").iterdir()) == FIGURES


def test_estimate_report_with_a_math_receiver_name(grid_args, tmp_path, capsys):
    """A receiver is named after its log file: `$...$` in it must not stop the report after the
    heights were written."""
    obs = pd.read_parquet(CITY / "observations.parquet")
    obs["receiver"] = "$\\undefined{$_" + obs["receiver"].astype(str)
    obs.to_parquet(tmp_path / "obs.parquet")
    args = [str(tmp_path / "obs.parquet"), str(CITY / "footprints.gpkg")]
    args += ["--dem", str(CITY / "dem.tif"), *grid_args, "-q", "-o", str(tmp_path / "h.gpkg")]
    code, _, err = run_cli(["estimate", *args, "--report", str(tmp_path / "r")], capsys)
    assert code == 0, err
    assert (tmp_path / "r" / REPORT).is_file()


def test_the_mixture_signal_model_has_a_report(grid_dir, tmp_path):
    """The mixture is drawn at 45 degrees of elevation: its 50 % point, and each received
    signal labelled by it at its own elevation."""
    obs = gc.read_observations(CITY / "observations.parquet")
    footprints = gc.read_footprints(CITY / "footprints.gpkg")
    mixture = run(obs, footprints, CITY / "dem.tif", grid_dir=grid_dir,
                  estimator=gc.Estimator(signal_model="mixture"))  # fmt: skip
    assert isinstance(mixture.classifier, Cn0Mixture)
    threshold = mixture.classifier.threshold
    assert 20.0 < threshold < 45.0
    states = signal_states(mixture)
    at_45 = states[(states["elevation"] - 45.0).abs() < 2.0]
    assert (at_45.loc[at_45["cn0"] > threshold + 1.0, "state"] == "open").all()
    assert (at_45.loc[at_45["cn0"] < threshold - 1.0, "state"] == "closed").all()
    page = write_report(mixture, tmp_path)
    assert page.is_file() and len(list((tmp_path / "figures").iterdir())) == len(FIGURES)
