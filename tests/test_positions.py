"""Receiver positions: from a log's fixes (nearest, interpolated, across 180 degrees) and from
a file of surveyed positions, and the errors of both."""

import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from gnss_citygml.errors import InputError, MissingColumnError
from gnss_citygml.gnss.gnsslogger import GnssLog, read_gnsslogger
from gnss_citygml.gnss.positions import (
    ACCURACY_PER_SD,
    positions,
    read_surveyed_positions,
    surveyed_positions,
)

LONDON = "london_ucl_2020-02-11_SM-G973F_gnss_log.txt"
STANFORD = "stanford_2023-11-07_Pixel7_gnss_log.txt"


@pytest.fixture(scope="module")
def gnss_dir(repo_data):
    return repo_data / "gnss"


@pytest.fixture(scope="module")
def london(shared_data) -> GnssLog:
    """The London log (2.7 MB: only in the shared data); the warning about its cut-off last
    line is test_gnsslogger's."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return read_gnsslogger(shared_data / "gnss" / LONDON)


def test_london_positions_from_gps_fixes(london):
    log = london
    pos = positions(log)
    assert len(pos) == 279  # the last of the 280 epochs lost a row: dropped
    assert pos["time_utc"].is_monotonic_increasing
    # the README's range 51.52467-51.52472 N, 0.13440-0.13414 W, to its 5 decimals
    assert pos["lat"].between(51.524665, 51.524725).all()
    assert pos["lon"].between(-0.134405, -0.134135).all()
    # each epoch is 0.6 ms after its fix: nearest and interpolated are the fix itself
    fixes = log.fixes.sort_values("time_utc")[:279]
    np.testing.assert_array_equal(pos["lat"], fixes["lat"])
    np.testing.assert_array_equal(pos["h"], fixes["altitude"])
    # the phone's accuracy is a 68 % radius: over 1.51, the error per axis
    assert fixes["accuracy"].notna().all()
    np.testing.assert_allclose(pos["position_sd"], fixes["accuracy"] / 1.5096, rtol=1e-4)
    inter = positions(log, method="interpolate")
    np.testing.assert_allclose(inter[["lat", "lon"]], pos[["lat", "lon"]], atol=1e-8)
    np.testing.assert_allclose(inter["h"], pos["h"], atol=1e-3)


def _log_with_fixes(epochs, fix_times, lat, lon, h, accuracy=np.nan):
    utc = pd.to_datetime(epochs, utc=True).as_unit("ns")
    fixes = pd.DataFrame(
        {
            "time_utc": pd.to_datetime(fix_times, utc=True).as_unit("ns"),
            "provider": "gps",
            "lat": lat,
            "lon": lon,
            "altitude": h,
            "accuracy": accuracy,
        }
    )
    raw = pd.DataFrame({"time_utc": utc})
    return GnssLog(Path("synthetic.txt"), "3.0", raw, fixes, pd.DataFrame(), pd.DataFrame())


def test_interpolation_between_fixes_and_across_180_degrees():
    log = _log_with_fixes(
        ["2024-01-01 00:00:00.5", "2024-01-01 00:00:01.5", "2024-01-01 00:00:02.9"],
        ["2024-01-01 00:00:00", "2024-01-01 00:00:02", "2024-01-01 00:00:03"],
        lat=[10.0, 12.0, 13.0],
        lon=[179.9, -179.9, -179.8],
        h=[100.0, 104.0, np.nan],
        accuracy=[3.0, 6.0, np.nan],
    )
    inter = positions(log, method="interpolate")
    np.testing.assert_allclose(inter["position_sd"] * ACCURACY_PER_SD, [3.75, 5.25, np.nan])
    np.testing.assert_allclose(inter["lat"], [10.5, 11.5, 12.9])
    np.testing.assert_allclose(inter["lon"], [179.95, -179.95, -179.81])
    np.testing.assert_allclose(inter["h"], [101.0, 103.0, np.nan])
    near = positions(log, method="nearest")
    np.testing.assert_allclose(near["lat"], [10.0, 12.0, 13.0])
    np.testing.assert_allclose(near["h"], [100.0, 104.0, np.nan])
    np.testing.assert_allclose(near["position_sd"] * ACCURACY_PER_SD, [3.0, 6.0, np.nan])
    with pytest.raises(InputError, match="2 of 3 epochs have no 'gps' fix within 0.4 s"):
        positions(log, max_gap=0.4)


def test_positions_errors(gnss_dir):
    log = read_gnsslogger(gnss_dir / STANFORD)
    with pytest.raises(InputError, match=r"provider 'glonass'.*\['flp', 'gps', 'nlp'\]"):
        positions(log, provider="glonass")
    with pytest.raises(InputError, match="29 of 31 epochs have no 'NLP' fix within 0.5 s"):
        positions(log, provider="NLP", max_gap=0.5)
    with pytest.raises(InputError, match="unknown position method"):
        positions(log, method="kriging")


SURVEYED = """\
# manually surveyed positions of the receivers
receiver,start_utc,end_utc,lat,lon,h
{receiver},2020-02-11T08:49:00Z,2020-02-11T08:51:00Z,51.5247,-0.1341,
{receiver},2020-02-11T09:51:00+01:00,2020-02-11 08:55:00,51.5248,-0.1342,115.2

other,2020-02-11T08:00:00Z,2020-02-11T09:00:00Z,51.0,0.0,10
"""


def test_surveyed_positions_per_receiver_and_span(london, tmp_path):
    log = london
    path = tmp_path / "manual.csv"
    path.write_text(SURVEYED.format(receiver=log.receiver))
    surveyed = read_surveyed_positions(path)
    assert len(surveyed) == 3
    assert str(surveyed["start_utc"].dtype) == "datetime64[ns, UTC]"
    # 09:51+01:00 is 08:51 UTC: where the spans touch the later one wins
    pos = surveyed_positions(surveyed, log.receiver, log.epochs)
    assert len(pos) == 279
    first = pos["time_utc"] <= pd.Timestamp("2020-02-11 08:51", tz="UTC")
    assert first.sum() == 93  # 08:49:28 .. 08:51:00
    assert (pos.loc[first, "lat"] == 51.5247).all() and pos.loc[first, "h"].isna().all()
    assert (pos.loc[~first, "lat"] == 51.5248).all() and (pos.loc[~first, "h"] == 115.2).all()
    assert pos["position_sd"].isna().all()  # no sd column: the estimator's default
    touching = surveyed_positions(surveyed, log.receiver, ["2020-02-11T08:51:00Z"])
    assert touching["lat"].tolist() == [51.5248]
    with pytest.raises(InputError, match="receiver 'phone' has no surveyed position.*other"):
        surveyed_positions(surveyed, "phone", log.epochs)
    with pytest.raises(InputError, match="279 of 279 epochs of receiver 'other'") as err:
        surveyed_positions(surveyed, "other", log.epochs + pd.Timedelta("1h"))
    assert str(path) in err.value.where


@pytest.mark.parametrize(
    ("row", "message", "line"),
    [
        ("a,2020-02-11T08:00Z,2020-02-11T08:30Z,51,0,,", "overlaps the span on line 2", 4),
        ("b,2020-02-11T08:00Z,2020-02-11T07:00Z,51,0,,", "ends before it starts", 4),
        ("b,2020-02-11T08:00Z,2020-02-11T09:00Z,91,0,,", "lat '91' is not a number within", 4),
        ("b,2020-02-11T08:00Z,2020-02-11T09:00Z,51,0,x,", "h 'x' is not a number", 4),
        ("b,yesterday,2020-02-11T09:00Z,51,0,,", "start_utc 'yesterday' is not a time", 4),
        ("b,2020-02-11T08:00Z,51,0,", "5 fields, the header has 7", 4),
        ("b,2020-02-11T08:00Z,2020-02-11T09:00Z,51,0,,-1", "sd -1 is negative", 4),
        ("b,2020-02-11T08:00Z,2020-02-11T09:00Z,51,0,,1m", "sd '1m' is not a number", 4),
    ],
)
def test_surveyed_positions_bad_rows(tmp_path, row, message, line):
    path = tmp_path / "manual.csv"
    head = "receiver,start_utc,end_utc,lat,lon,h,sd\na,2020-02-11T07:00Z,2020-02-11T08:10Z,51,0,,\n"
    path.write_text(head + "\n" + row + "\n")
    with pytest.raises(InputError, match=message) as err:
        read_surveyed_positions(path)
    assert err.value.where == f"{path}, line {line}"


def test_surveyed_positions_missing_column(tmp_path):
    path = tmp_path / "manual.csv"
    path.write_text("receiver,start,end_utc,lat,lon,h\n")
    with pytest.raises(MissingColumnError, match="'start_utc'"):
        read_surveyed_positions(path)


def test_surveyed_positions_say_how_far_off_they_may_be(tmp_path):
    path = tmp_path / "manual.csv"
    path.write_text(
        "receiver,start_utc,end_utc,lat,lon,h,sd\n"
        "a,2020-02-11T08:00Z,2020-02-11T08:10Z,51,0,,0.5\n"
        "a,2020-02-11T08:20Z,2020-02-11T08:30Z,51,0,,\n"  # empty: the estimator's default
    )
    surveyed = read_surveyed_positions(path)
    times = ["2020-02-11T08:05Z", "2020-02-11T08:25Z"]
    sd = surveyed_positions(surveyed, "a", times)["position_sd"]
    np.testing.assert_array_equal(sd, [0.5, np.nan])
