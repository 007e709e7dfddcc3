"""GPS time and UTC: the leap seconds around the 2017 step, time-zone aware times, and the
errors for times that are no GNSS times."""

import numpy as np
import pandas as pd
import pytest

from gnss_citygml.errors import InputError
from gnss_citygml.gnss.gpstime import gps_minus_utc, gps_to_utc, to_datetime64, utc_to_gps


def test_leap_seconds_around_the_2017_step():
    assert gps_minus_utc(["1980-01-06", "2016-06-30", "2016-12-31T23:59:59"]).tolist() == [
        0,
        17,
        17,
    ]
    assert gps_minus_utc(["2017-01-01", "2020-02-11", "2025-11-16"]).tolist() == [18, 18, 18]
    utc = to_datetime64(["2016-12-31T23:59:59", "2017-01-01T00:00:01", "2021-04-29T22:35:26"])
    gps = utc_to_gps(utc)
    assert (gps - utc).astype("timedelta64[s]").astype(int).tolist() == [17, 18, 18]
    assert (gps_to_utc(gps) == utc).all()


def test_times_before_gps_and_numbers_are_errors():
    with pytest.raises(InputError, match="before the start of GPS time"):
        gps_minus_utc("1979-12-31")
    with pytest.raises(InputError, match="numbers, not dates"):
        to_datetime64(np.array([1.5e9]))


def test_aware_times_are_converted_to_utc():
    local = pd.Series(pd.to_datetime(["2021-04-29 15:35:26"]).tz_localize("America/Los_Angeles"))
    assert to_datetime64(local)[0] == np.datetime64("2021-04-29T22:35:26")
