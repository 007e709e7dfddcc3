"""Which rows share one position error: stays, stretches of a way, time windows of recordings."""

import geopandas as gpd
import numpy as np
import pandas as pd
import pytest
import shapely

from gnss_citygml.errors import InputError
from gnss_citygml.pipeline import intersections
from gnss_citygml.recordings import position_groups, recording_windows
from gnss_citygml.settings import DEFAULT_POSITION_DISTANCE, PositionError

START = pd.Timestamp("2020-02-11T10:00:00Z")


def rows(receivers, seconds):
    return pd.DataFrame(
        {"receiver": receivers, "time_utc": START + pd.to_timedelta(seconds, unit="s")}
    )


def groups(codes):
    """The partition of row positions that ``codes`` makes, independent of the code values."""
    return sorted(sorted(i for i, c in enumerate(codes) if c == code) for code in set(codes))


def test_a_window_starts_at_its_recordings_first_epoch():
    # b starts 25 s after a: its windows are 25..55 and 55..85, not the run's 0..30, 30..60...
    table = rows(["a", "a", "a", "b", "b", "b"], [0, 10, 40, 25, 50, 60])
    codes = recording_windows(table, 30.0)
    assert groups(codes) == [[0, 1], [2], [3, 4], [5]]
    # ... so b is cut the same way whichever other recordings are in the run
    alone = recording_windows(table[table["receiver"] == "b"], 30.0)
    assert groups(alone) == [[0, 1], [2]]


def test_without_a_window_a_recording_is_one_group():
    table = rows(["a", "b", "a"], [0, 1000, 5000])
    assert list(recording_windows(table)) == [0, 1, 0]


def test_time_zones_and_order_do_not_matter():
    table = rows(["a", "a", "a"], [70, 0, 35])
    local = table.assign(time_utc=table["time_utc"].dt.tz_convert("Europe/Berlin"))
    assert groups(recording_windows(table, 30.0)) == [[0], [1], [2]]
    assert list(recording_windows(local, 30.0)) == list(recording_windows(table, 30.0))


def test_windows_need_times():
    with pytest.raises(InputError, match="time_utc"):
        recording_windows(pd.DataFrame({"receiver": ["a"]}), 30.0)


def test_the_pipelines_position_errors_share_the_windows():
    wall = gpd.GeoDataFrame({"id": ["w"]}, geometry=[shapely.box(10, -50, 20, 50)])
    walkers = rows(["a", "a", "a", "b", "b", "b"], [0, 10, 40, 25, 50, 60]).assign(
        e=[0.0, 1.0, 2.0, 0.0, 1.0, 2.0], n=0.0, z=1.0, bearing=90.0, elevation=30.0, cn0=40.0
    )
    out = intersections(walkers, wall, position_error=PositionError(sd=1.0, window=30.0))
    assert groups(out["recording"].tolist()) == [[0, 1], [2], [3, 4], [5]]
    # named by receiver and first epoch, so another run over more rows names them alike
    assert out["recording"][3] == "b 2020-02-11T10:00:25.000000Z"


def test_a_receiver_standing_still_shares_one_error_over_its_stay():
    # a: placed by hand at one point for 60 s, then at another for 40 s, then 20 s at a third
    # (shorter than STILL: a pause of a walk); b: a phone's fixes, a little off every epoch
    seconds = [0, 30, 60, 80, 120, 130, 150, 0, 10, 40, 70]
    table = rows(["a"] * 7 + ["b"] * 4, seconds).assign(
        e=[5.0, 5.0, 5.0, 9.0, 9.0, 7.0, 7.0, 0.0, 0.3, 0.1, 0.2], n=0.0
    )
    # each stay its own error; the moving rows share one per recording ...
    assert groups(position_groups(table)) == [[0, 1, 2], [3, 4], [5, 6], [7, 8, 9, 10]]
    # ... or one per window of the recording
    by_30 = [[0, 1, 2], [3, 4], [5], [6], [7, 8], [9], [10]]
    assert groups(position_groups(table, 30.0)) == by_30
    # the order of the rows does not matter (row i is now row 10 - i)
    backwards = groups(position_groups(table.iloc[::-1].reset_index(drop=True), 30.0))
    assert backwards == sorted(sorted(10 - i for i in g) for g in by_30)


def test_a_moving_receiver_shares_one_error_per_stretch_of_its_way():
    """With a distance, a walker's error lasts until its reported position is that far from
    where the error began (the next stretch of street); a phone lying still, whose fixes
    wander a few metres, keeps one; an unknown position is never far; a window wins."""
    walk = np.arange(0.0, 201.0, 10.0)  # 0, 10, ... 200 m along a street, one fix a second
    walker = rows(["w"] * walk.size, np.arange(walk.size)).assign(e=walk, n=0.0)
    still = rows(["s"] * 40, np.arange(40)).assign(
        e=np.random.default_rng(0).normal(0.0, 3.0, 40), n=0.0
    )
    table = pd.concat([walker, still], ignore_index=True)
    codes = position_groups(table, distance=50.0)
    # the walker: 0-50 m, 60-110 m, 120-170 m, 180-200 m; the phone lying still: one
    assert groups(codes) == [
        list(range(0, 6)),
        list(range(6, 12)),
        list(range(12, 18)),
        list(range(18, 21)),
        list(range(21, 61)),
    ]
    assert len(set(position_groups(table))) == 2  # without: one per recording
    assert len(set(position_groups(table, 30.0, 50.0))) == 3  # 21 s and 40 s of 30 s windows
    lost = walker.assign(e=np.where(walker.index == 3, np.nan, walker["e"]))
    assert groups(position_groups(lost, distance=50.0))[0] == list(range(0, 6))


def test_the_pipelines_errors_follow_the_stretches_by_default():
    wall = gpd.GeoDataFrame({"id": ["w"]}, geometry=[shapely.box(-50, 20, 300, 30)])
    walk = np.arange(0.0, 201.0, 10.0)
    walker = rows(["w"] * walk.size, np.arange(walk.size)).assign(
        e=walk, n=0.0, z=1.0, bearing=0.0, elevation=30.0, cn0=40.0
    )
    out = intersections(walker, wall, position_error=PositionError(sd=1.0))
    assert PositionError().distance == DEFAULT_POSITION_DISTANCE
    assert out["recording"].nunique() == 4
    whole = intersections(walker, wall, position_error=PositionError(sd=1.0, distance=None))
    assert whole["recording"].nunique() == 1
