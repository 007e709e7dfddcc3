import subprocess
import sys
from pathlib import Path

import click
import geopandas as gpd
import numpy as np
import pandas as pd
import pytest
from conftest import synthetic_intersections

from gnss_citygml.cli import cli, main
from gnss_citygml.model.estimate import estimate_heights
from gnss_citygml.settings import Estimator


def run(args, capsys):
    with pytest.raises(SystemExit) as exc:
        main(args)
    out = capsys.readouterr()
    return exc.value.code, out.out, out.err


def test_an_option_means_the_same_in_every_command():
    """An option that several commands take is declared once (cli/options.py): same type,
    default and help everywhere. Only what a file is for may be said per command, whether the
    DEM or the footprints must be given, and whether the output may be '-' (standard output)."""
    per_command = {
        "dem": ("help", "required"),
        "footprints": ("help", "required"),
        "output": ("help", "type"),
        "output_dir": ("help",),
    }
    ctx = click.Context(cli)
    declared = {}
    for name in cli.list_commands(ctx):
        for param in cli.get_command(ctx, name).params:
            if isinstance(param, click.Option):
                info = param.to_info_dict()
                for key in per_command.get(param.name, ()):
                    info.pop(key)
                declared.setdefault(param.opts[0], {})[name] = info
    shared = {opt: by_command for opt, by_command in declared.items() if len(by_command) > 1}
    assert {"--grid-dir", "--layer", "--id-field", "--dem-crs", "--method"} <= set(shared)
    for opt, by_command in shared.items():
        first, *others = by_command.values()
        assert all(info == first for info in others), opt


def test_simulate_then_heights(grid_args, tmp_path, capsys):
    args = ["simulate", "hermitage", "-o", str(tmp_path), "--interval", "30", *grid_args]
    code, out, _ = run(args, capsys)
    assert code == 0 and "intersections" in out
    for name in ("observations.csv", "intersections.csv", "truth.csv", "footprints.gpkg"):
        assert (tmp_path / name).is_file()
    heights = tmp_path / "heights.csv"
    code, out, _ = run(["heights", str(tmp_path / "intersections.csv"), "-o", str(heights)], capsys)
    assert code == 0 and "converged" in out
    table = pd.read_csv(heights)
    assert "hermitage_terrace" in set(table["id"])
    assert not list(tmp_path.glob("*.part*"))


def test_user_errors_are_one_line_with_exit_code_2(tmp_path, capsys):
    code, _, err = run(
        ["heights", str(tmp_path / "nope.csv"), "-o", str(tmp_path / "h.csv")], capsys
    )
    assert code == 2
    assert err.strip() == f"error: file not found ({tmp_path / 'nope.csv'}): check the path"
    bad = tmp_path / "bad.csv"
    pd.DataFrame({"building": ["a"], "height": [3.0]}).to_csv(bad, index=False)
    code, _, err = run(["heights", str(bad), "-o", str(tmp_path / "h.csv")], capsys)
    assert code == 2 and err.startswith("error: missing column(s) 'cn0'")
    assert len(err.strip().splitlines()) == 1
    assert not (tmp_path / "h.csv").exists()


def test_the_signal_model_reaches_the_estimator(tmp_path, capsys):
    """``heights --signal-model mixture`` gives the library's mixture heights, which are not
    the paper's: the option is not dropped on its way to the estimator."""
    table = pd.concat(
        [
            synthetic_intersections(np.random.default_rng(1), n=1500),
            synthetic_intersections(np.random.default_rng(2), n=1500, truth=30.0, building="b2"),
        ],
        ignore_index=True,
    )
    table.to_parquet(tmp_path / "intersections.parquet")
    written = {}
    for model in ("paper", "mixture"):
        out = tmp_path / f"{model}.parquet"
        args = ["heights", str(tmp_path / "intersections.parquet"), "-o", str(out)]
        code, _, err = run([*args, "--signal-model", model], capsys)
        assert code == 0, err
        written[model] = pd.read_parquet(out)
        expected = estimate_heights(table, Estimator(signal_model=model))
        pd.testing.assert_frame_equal(written[model], expected, check_dtype=False)
    change = (written["mixture"]["height"] - written["paper"]["height"]).abs()
    assert change.max() > 1e-3


@pytest.mark.parametrize("method", ["hinge", "bayes", "4PL"])
@pytest.mark.parametrize(
    "args",
    [
        ["heights", "{d}/i.csv", "-o", "{d}/h.csv"],
        ["estimate", "{d}/o.csv", "{d}/f.gpkg", "--dem", "{d}/dem.tif", "-o", "{d}/h.gpkg"],
        ["report", "{d}/o.csv", "{d}/f.gpkg", "--dem", "{d}/dem.tif", "-o", "{d}/report"],
        ["update", "{d}/map.gpkg", "--observations", "{d}/o.csv", "--dem", "{d}/dem.tif"],
    ],
)
def test_a_signal_model_the_method_has_not_is_one_line(args, method, tmp_path, capsys):
    """The mixture signal model is 4PL-B's: with another method every command that builds an
    estimator says so in one line, exit 2, before reading any input."""
    args = [a.format(d=tmp_path) for a in args]
    code, out, err = run([*args, "--method", method, "--signal-model", "mixture"], capsys)
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert err.startswith(f"error: signal model mixture needs method 4PL-B, not {method}")
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("model", ["bogus", "Mixture", "", "4PL-B"])
def test_an_unknown_signal_model_is_refused_by_its_option(model, tmp_path, capsys):
    args = ["heights", str(tmp_path / "i.csv"), "-o", str(tmp_path / "h.csv")]
    code, _, err = run([*args, "--signal-model", model], capsys)
    assert code == 2
    assert f"Invalid value for '--signal-model': '{model}' is not one of 'paper', 'mixture'" in err


def test_unknown_output_format_writes_nothing(grid_args, tmp_path, capsys):
    run(["simulate", "ucl", "-o", str(tmp_path), "--interval", "120", *grid_args], capsys)
    code, _, err = run(
        ["heights", str(tmp_path / "intersections.csv"), "-o", str(tmp_path / "h.xlsx")], capsys
    )
    assert code == 2 and "unknown table format '.xlsx'" in err
    assert not (tmp_path / "h.xlsx").exists()


@pytest.mark.parametrize("command", [["-m", "gnss_citygml"], ["console-script"]])
def test_entry_points_report_the_version(command):
    if command == ["console-script"]:
        argv = [str(Path(sys.executable).parent / "gnss-citygml")]
    else:
        argv = [sys.executable, *command]
    out = subprocess.run([*argv, "--version"], capture_output=True, text=True, check=True)
    assert out.stdout.startswith("gnss-citygml, version")


DEMO_2016 = "google_demo_pseudoranges_log_2016_08_22_14_45_50.txt"


def test_observe_a_real_log(repo_data, tmp_path, capsys):
    out_path = tmp_path / "obs.parquet"
    log, nav = repo_data / "gnss" / DEMO_2016, repo_data / "orbits" / "hour2350.16n"
    code, out, err = run(["observe", str(log), "--orbits", str(nav), "-o", str(out_path)], capsys)
    assert code == 0, err
    assert "1863 signals (1850 received, 13 blocked)" in out
    assert err.startswith("warning: ") and "without orbit data" in err  # Galileo, BeiDou
    assert len(pd.read_parquet(out_path)) == 1863


def test_observe_with_orbits_of_another_day_writes_nothing(repo_data, tmp_path, capsys):
    out_path = tmp_path / "obs.parquet"
    log, nav = repo_data / "gnss" / DEMO_2016, repo_data / "orbits" / "hour1820.16n"
    code, _, err = run(["observe", str(log), "--orbits", str(nav), "-o", str(out_path)], capsys)
    assert code == 2
    assert "error: the orbits cover 2016-06-29" in err and "2016-08-22 21:45:56" in err
    assert not list(tmp_path.iterdir())


def simulated_site(folder, grid_args, capsys, interval="30"):
    """A simulated Hermitage Rd written as a user's files in ``folder``."""
    args = ["simulate", "hermitage", "-o", str(folder), "--interval", interval, *grid_args]
    code, _, err = run(args, capsys)
    assert code == 0, err


def estimate_args(folder, grid_args, observations="observations.csv", output="heights.gpkg"):
    return [
        "estimate",
        str(folder / observations),
        str(folder / "footprints.gpkg"),
        "--dem",
        str(folder / "dem.tif"),
        "-o",
        str(folder / output),
        *grid_args,
    ]


def test_estimate_from_simulated_files(grid_args, tmp_path, capsys):
    simulated_site(tmp_path, grid_args, capsys)
    out_path = tmp_path / "heights.gpkg"
    args = estimate_args(tmp_path, grid_args)
    code, out, err = run(args, capsys)
    assert code == 0, err
    assert "buildings have a height" in out
    heights = gpd.read_file(out_path, layer="heights").set_index("id")
    truth = pd.read_csv(tmp_path / "truth.csv").set_index("id")
    assert heights.crs.to_epsg() == 27700
    assert (
        abs(heights.loc["hermitage_terrace", "height"] - truth.loc["hermitage_terrace", "height"])
        < 1.5
    )
    before = out_path.read_bytes()
    code, _, err = run(args, capsys)  # the output exists now
    assert code == 2 and "output exists" in err
    code, _, err = run([*args[:4], str(tmp_path / "nope.tif"), *args[5:], "--overwrite"], capsys)
    assert code == 2 and err.startswith("error: ") and "nope.tif" in err
    assert out_path.read_bytes() == before  # a failed run leaves the old output alone
    assert not list(tmp_path.glob(".*part*"))


def test_simulate_options_are_checked_in_one_line(tmp_path, capsys):
    """Every numeric option of simulate: a bad value is one error line naming the option,
    before any work or memory is spent (1e-9 s once ran out of memory), and nothing written."""
    folder = tmp_path / "site"
    for option, value in [
        ("--interval", "1e-9"),
        ("--interval", "nan"),
        ("--interval", "inf"),
        ("--interval", "-1"),
        ("--interval", "0.001"),
        ("--seed", "-1"),
    ]:
        code, _, err = run(["simulate", "hermitage", "-o", str(folder), option, value], capsys)
        assert code == 2 and err.startswith("error: ") and err.count("\n") == 1, err
        assert option in err and "internal error" not in err
    code, _, err = run(["simulate", "hermitage", "-o", str(folder), "--interval", "0.02"], capsys)
    assert code == 2 and "epochs" in err and "give --interval 0.05 or more" in err
    assert not folder.exists() or not any(folder.iterdir())


def test_options_outside_their_physical_range_are_refused(grid_args, tmp_path, capsys):
    """A physical option out of its range (a roof below the ground from --antenna-height -50,
    rays of 1e9 m, NaN) is refused in one line before any work, by the settings every
    interface builds; nothing is written."""
    simulated_site(tmp_path, grid_args, capsys, interval="120")
    for option, value in [
        ("--antenna-height", "-50"),
        ("--antenna-height", "1e9"),
        ("--antenna-height", "nan"),
        ("--max-range", "1e9"),
        ("--max-range", "-1"),
        ("--min-elevation", "nan"),
        ("--max-elevation", "inf"),
        ("--init-threshold", "-5"),
        ("--init-threshold", "1e6"),
        ("--position-sd", "nan"),
        ("--position-sd", "1e6"),
        ("--position-window", "inf"),
        ("--calibration-sd", "-5"),
        ("--calibration-sd", "1e9"),
    ]:
        code, _, err = run([*estimate_args(tmp_path, grid_args), option, value], capsys)
        assert code == 2 and err.startswith("error: ") and err.count("\n") == 1, (option, err)
        assert option in err, err
    args = ["partition", str(tmp_path / "observations.csv"), "-o", str(tmp_path / "part")]
    code, _, err = run([*args, "--antenna-height", "-50", *grid_args], capsys)
    assert code == 2 and "--antenna-height" in err and err.count("\n") == 1
    assert not (tmp_path / "heights.gpkg").exists() and not (tmp_path / "part").exists()


def test_estimate_refuses_a_signal_both_received_and_blocked(grid_args, tmp_path, capsys):
    """The observations plus a copy with C/N0 flipped once gave no heights and exit 0; now one
    line naming both lines. An exact copy counts once, with a warning; azimuths in radians
    draw a warning."""
    simulated_site(tmp_path, grid_args, capsys, interval="120")
    table = pd.read_csv(tmp_path / "observations.csv")
    flipped = table.assign(cn0=table["cn0"].isna() * 40.0).replace(0.0, float("nan"))
    pd.concat([table, flipped]).to_csv(tmp_path / "flipped.csv", index=False)
    code, _, err = run(estimate_args(tmp_path, grid_args, "flipped.csv"), capsys)
    assert code == 2 and err.count("\n") == 1
    assert err.startswith("error: the same signal twice with different values")
    assert f"flipped.csv, line 2 and {tmp_path / 'flipped.csv'}, line {len(table) + 2}" in err
    assert not (tmp_path / "heights.gpkg").exists()
    pd.concat([table, table]).to_csv(tmp_path / "twice.csv", index=False)
    code, _, err = run(estimate_args(tmp_path, grid_args, "twice.csv"), capsys)
    assert code == 0 and f"warning: {len(table)} repeated observation(s)" in err
    table.assign(azimuth=table["azimuth"] / 57.3).to_csv(tmp_path / "rad.csv", index=False)
    code, _, err = run([*estimate_args(tmp_path, grid_args, "rad.csv"), "--overwrite"], capsys)
    assert "warning: every azimuth is within 0..6.28: radians?" in err


def test_estimate_with_position_errors(grid_args, tmp_path, capsys):
    simulated_site(tmp_path, grid_args, capsys, interval="60")
    code, _, err = run([*estimate_args(tmp_path, grid_args), "--position-sd", "-1"], capsys)
    assert code == 2 and "--position-sd" in err
    code, _, err = run([*estimate_args(tmp_path, grid_args), "--calibration-window", "30"], capsys)
    assert code == 2 and "--calibration-sd" in err
    code, _, err = run([*estimate_args(tmp_path, grid_args), "--position-window", "0"], capsys)
    assert code == 2 and "--position-window" in err
    # self-calibration fits 4PL-B's roof lines: with another method it is refused, not ignored
    calibrated_hinge = ["--calibration-sd", "5", "--method", "hinge"]
    code, _, err = run([*estimate_args(tmp_path, grid_args), *calibrated_hinge], capsys)
    assert code == 2 and err.count("\n") == 1
    assert err.startswith("error: self-calibration needs method 4PL-B, not hinge: ")
    assert "--calibration-sd" in err
    assert not (tmp_path / "heights.gpkg").exists()
    ranges = {}
    for sd in ("0", "1", "3"):  # 0: exact positions, as in the paper
        args = [*estimate_args(tmp_path, grid_args), "--position-sd", sd, "--overwrite"]
        code, _, err = run(args, capsys)
        assert code == 0, err
        row = gpd.read_file(tmp_path / "heights.gpkg", layer="heights").set_index("id")
        row = row.loc["hermitage_terrace"]
        assert row["converged"]
        ranges[sd] = (row["height_lower"], row["height_upper"])
    # the range carries the roof line's position uncertainty: 1 m costs about what the
    # errors-in-variables fit gains (its roof line is sharper: 3/b shrinks), 3 m widen it
    width = {sd: upper - lower for sd, (lower, upper) in ranges.items()}
    assert max(width["0"], width["1"]) < width["3"]


def test_estimate_with_shadow_matching(grid_args, tmp_path, capsys):
    simulated_site(tmp_path, grid_args, capsys, interval="60")
    shadows = ["--calibration-sd", "3", "--calibration-window", "600"]
    code, _, err = run(
        [*estimate_args(tmp_path, grid_args), *shadows, "--calibration-matching", "shadow"], capsys
    )
    assert code == 2 and "--calibration-matching" in err and "shadows" in err
    code, _, err = run(
        [*estimate_args(tmp_path, grid_args), "--calibration-matching", "shadows"], capsys
    )
    assert code == 2 and "--calibration-sd" in err and err.count("\n") == 1
    code, out, err = run(
        [*estimate_args(tmp_path, grid_args), *shadows, "--calibration-matching", "shadows"], capsys
    )
    assert code == 0, err
    heights = gpd.read_file(tmp_path / "heights.gpkg", layer="heights").set_index("id")
    truth = pd.read_csv(tmp_path / "truth.csv").set_index("id")
    terrace = "hermitage_terrace"
    assert abs(heights.loc[terrace, "height"] - truth.loc[terrace, "height"]) < 1.5, out
    # the map's own roof heights (a field above the ground, 0 where it has none) place them
    footprints = gpd.read_file(tmp_path / "footprints.gpkg")
    above = footprints["id"].map(truth["height"] - truth["ground"])
    footprints.assign(relh=above.where(footprints["id"] != terrace, 0.0)).to_file(
        tmp_path / "mapped.gpkg"
    )
    mapped = estimate_args(tmp_path, grid_args, output="mapped_h.gpkg")
    mapped[2] = str(tmp_path / "mapped.gpkg")
    matching = [*shadows, "--calibration-matching", "shadows"]
    code, _, err = run([*mapped, *matching, "--calibration-heights", "relh2"], capsys)
    assert code == 2 and "'relh2'" in err and "relh" in err and err.count("\n") == 1
    assert "missing column" in err  # the field, not the matching (that is given)
    code, _, err = run([*mapped, *matching, "--calibration-heights", "id"], capsys)
    assert code == 2 and "'id' holds no height" in err and err.count("\n") == 1
    given = ["--calibration-matching", "shadows", "--calibration-heights", "relh"]
    code, out, err = run([*mapped, *shadows, *given, "--calibration-heights-sd", "1"], capsys)
    assert code == 0, err
    heights = gpd.read_file(tmp_path / "mapped_h.gpkg", layer="heights").set_index("id")
    assert abs(heights.loc[terrace, "height"] - truth.loc[terrace, "height"]) < 1.5, out


def test_estimate_bad_observation_names_its_line(grid_args, tmp_path, capsys):
    simulated_site(tmp_path, grid_args, capsys, interval="60")
    obs = pd.read_csv(tmp_path / "observations.csv")
    obs.loc[4, "azimuth"] = 400.0
    obs.to_csv(tmp_path / "bad.csv", index=False)
    code, _, err = run(estimate_args(tmp_path, grid_args, "bad.csv", "h.gpkg"), capsys)
    assert code == 2
    assert err.strip() == (
        f"error: azimuth 400 outside 0..360 ({tmp_path / 'bad.csv'}, line 6): give azimuths in "
        "degrees clockwise from true north, 0 <= azimuth < 360"
    )
    assert not (tmp_path / "h.gpkg").exists()


def test_convert_and_validate(grid_args, repo_data, tmp_path, capsys):
    simulated_site(tmp_path, grid_args, capsys)
    heights = tmp_path / "heights.gpkg"
    code, _, err = run(estimate_args(tmp_path, grid_args), capsys)
    assert code == 0, err
    for name in ("city.city.json", "city.city.jsonl", "city.gml"):
        code, out, err = run(["convert", str(heights), "-o", str(tmp_path / name)], capsys)
        assert code == 0, err
        assert "valid" in out
        code, out, _ = run(["validate", str(tmp_path / name)], capsys)
        assert code == 0 and "valid" in out
    broken = repo_data / "citymodels" / "cityjson" / "invalid"
    code, out, _ = run(["validate", str(sorted(broken.glob("*.json"))[0])], capsys)
    assert code == 1 and "invalid" in out
    code, _, err = run(["validate", str(tmp_path / "nope.gml")], capsys)
    assert code == 2 and err.startswith("error: ")


def test_export_a_heights_table(grid_args, tmp_path, capsys):
    simulated_site(tmp_path, grid_args, capsys)
    table = tmp_path / "h.csv"
    code, _, err = run(["heights", str(tmp_path / "intersections.csv"), "-o", str(table)], capsys)
    assert code == 0, err
    args = ["export", str(table), "--footprints", str(tmp_path / "footprints.gpkg")]
    args += ["--dem", str(tmp_path / "dem.tif"), "-o", str(tmp_path / "city.city.json")]
    code, out, err = run(args, capsys)
    assert code == 0, err
    written = int(out.split(" buildings")[0])
    assert written == int(pd.read_csv(table)["converged"].sum()) >= 1
    pd.concat([pd.read_csv(table), pd.DataFrame({"id": ["ghost"], "height": [40.0]})]).to_csv(
        table, index=False
    )
    code, _, err = run([*args, "--overwrite"], capsys)
    assert code == 2 and "1 height(s) for buildings not among the footprints: ghost" in err


def test_a_crash_is_one_line_and_exit_2_never_a_verdict(tmp_path, capsys, monkeypatch):
    """A bug that escapes a command (here: a reader that recurses too deep) is reported as one
    line with exit code 2, not a traceback, and never as validate's 'invalid' (exit 1)."""
    import gnss_citygml.validate as validate

    def crash(*args, **kwargs):
        raise RecursionError("maximum recursion depth exceeded")

    monkeypatch.setattr(validate, "validate_file", crash)
    code, out, err = run(["validate", str(tmp_path / "x.city.json")], capsys)
    assert code == 2 and out == ""
    assert err.startswith("error: internal error, RecursionError: maximum recursion depth")
    assert len(err.strip().splitlines()) == 1
    monkeypatch.setenv("GNSS_CITYGML_DEBUG", "1")
    with pytest.raises(RecursionError):
        main(["validate", str(tmp_path / "x.city.json")])


@pytest.mark.parametrize(
    "args",
    [
        ["validate", "{d}"],
        ["heights", "{d}", "-o", "{d}/h.csv"],
        ["observe", "{d}/log.txt", "--orbits", "{d}", "-o", "{d}/o.csv"],
    ],
)
def test_a_folder_given_for_a_file_is_named_as_such(args, tmp_path, capsys):
    (tmp_path / "log.txt").write_text("# Header\n")
    code, _, err = run([a.format(d=tmp_path) for a in args], capsys)
    assert code == 2 and "is a folder, not a file" in err, err
    assert len(err.strip().splitlines()) == 1
