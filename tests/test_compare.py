"""Estimates judged by the roof span (issue 27, decision 1): the distance of each estimate to
[lowest, highest roof point] (0 inside), whether its range meets the span, the error to the
span's middle beside them; a truth table without the span judged as before."""

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from test_cli import run as run_cli

from gnss_citygml.compare import check_truth, compare, summary
from gnss_citygml.errors import InputError

CITY = Path(__file__).resolve().parents[1] / "examples" / "city"


def _heights(height, lower, upper, converged):
    """A heights layer as `estimate` writes it (the columns compare reads), ground 20 m."""
    n = len(height)
    return pd.DataFrame(
        {
            "id": [f"b{k}" for k in range(n)],
            "height": height,
            "height_lower": lower,
            "height_upper": upper,
            "converged": converged,
            "status": ["ok" if c else "height range wider than 10 m" for c in converged],
            "ground": [20.0] * n,
        }
    )


#: b0 inside its span, b1 under it, b2 over it, b3 not converged; b1's range meets its span,
#: b2's does not.
HEIGHTS = _heights(
    [35.0, 27.0, 44.0, np.nan],
    [33.0, 25.0, 42.5, np.nan],
    [37.0, 30.5, 45.5, np.nan],
    [True, True, True, False],
)
TRUTH = pd.DataFrame(
    {
        "id": ["b0", "b1", "b2", "b3"],
        "height": [36.0, 32.0, 40.0, 30.0],
        "ground": [20.0] * 4,
        "roof_low": [34.5, 30.0, 38.5, 28.0],
        "roof_high": [37.5, 34.0, 41.5, 32.0],
    }
)


def test_the_distance_to_the_span_and_the_ranges_that_meet_it():
    table = compare(HEIGHTS, check_truth(TRUTH, "truth.csv"))
    np.testing.assert_allclose(table["span_error"], [0.0, 3.0, 2.5, np.nan])
    np.testing.assert_allclose(table["error"], [-1.0, -5.0, 4.0, np.nan])  # to the middle
    assert list(table["meets"]) == [True, True, False, False]
    assert list(table["inside"]) == [True, False, False, False]
    np.testing.assert_allclose(table["roof_low"], [14.5, 10.0, 18.5, 8.0])  # above the ground
    np.testing.assert_allclose(table["roof_high"], [17.5, 14.0, 21.5, 12.0])
    rmse_span, rmse_mid = np.sqrt((0 + 9 + 6.25) / 3), np.sqrt((1 + 25 + 16) / 3)
    assert summary(table) == (
        f"3 of 4 buildings converged, RMSE {rmse_span:.2f} m to the roof span, "
        f"{rmse_mid:.2f} m to its middle, range meeting the span for 2 of 3"
    )


@pytest.mark.parametrize(
    "old",
    [
        TRUTH.drop(columns=["roof_low", "roof_high"]),  # a truth table from before issue 27
        TRUTH.assign(roof_low=np.nan, roof_high=np.nan),  # the span columns left empty
        TRUTH.assign(roof_low=TRUTH["height"], roof_high=TRUTH["height"]),  # flat roofs only
    ],
)
def test_a_truth_without_a_span_is_judged_as_before(old):
    """The span is then [height, height]: the distance to it is the error's size, meeting it
    is holding the height, and the summary line is today's."""
    table = compare(HEIGHTS, check_truth(old, "truth.csv"))
    np.testing.assert_allclose(table["span_error"], table["error"].abs())
    assert (table["meets"] == table["inside"]).all()
    rmse = np.sqrt((1 + 25 + 16) / 3)
    assert summary(table) == (
        f"3 of 4 buildings converged, RMSE {rmse:.2f} m, truth inside the range for 1 of 3"
    )


def test_a_row_without_its_span_takes_its_height():
    """Old rows and new in one table: each row judged by what it has."""
    mixed = TRUTH.assign(roof_low=[34.5, np.nan, 38.5, np.nan], roof_high=[37.5, np.nan, 41.5, 32])
    table = compare(HEIGHTS, check_truth(mixed, "truth.csv"))
    np.testing.assert_allclose(table["span_error"], [0.0, 5.0, 2.5, np.nan])


def test_nothing_converged_is_a_line_too():
    table = compare(HEIGHTS.assign(converged=False), TRUTH)
    assert summary(table) == (
        "0 of 4 buildings converged, RMSE - to the roof span, - to its middle, range meeting "
        "the span for 0 of 0"
    )


@pytest.mark.parametrize(
    ("bad", "message"),
    [
        (TRUTH.drop(columns="roof_high"), "roof_high"),
        (TRUTH.drop(columns="roof_low"), "roof_low"),
        (TRUTH.assign(roof_low=["low"] * 4), "'roof_low' is not numbers"),
        (TRUTH.assign(roof_high=TRUTH["roof_low"] - 1), "roof_low above roof_high: b0, b1"),
    ],
)
def test_a_span_that_is_not_one_is_refused(bad, message):
    with pytest.raises(InputError, match=message):
        check_truth(bad, "truth.csv")


def test_a_bad_span_is_one_line_before_the_work(grid_args, tmp_path, capsys):
    """From the command line: the report's truth with its span upside down."""
    bad = tmp_path / "truth.csv"
    swapped = {"roof_low": "roof_high", "roof_high": "roof_low"}
    pd.read_csv(CITY / "truth.csv").rename(columns=swapped).to_csv(bad, index=False)
    files = [str(CITY / "observations.parquet"), str(CITY / "footprints.gpkg")]
    args = ["report", *files, "--dem", str(CITY / "dem.tif"), *grid_args, "-q"]
    code, out, err = run_cli([*args, "-o", str(tmp_path / "r"), "--truth", str(bad)], capsys)
    assert (code, out) == (2, "") and err.count("\n") == 1
    assert err.startswith("error: the roof span of 13 building(s) has roof_low above roof_high")
    assert not (tmp_path / "r").exists()
