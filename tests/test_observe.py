"""Logs + orbits -> observations, checked against Google's satellite positions and the phone."""

import numpy as np
import pandas as pd
import pytest

from gnss_citygml.errors import InputError
from gnss_citygml.gnss.gnsslogger import read_gnsslogger
from gnss_citygml.gnss.gpstime import gps_to_utc
from gnss_citygml.gnss.observe import observe
from gnss_citygml.gnss.orbits import OrbitSpanError, load_orbits
from gnss_citygml.gnss.sky import azimuth_elevation
from gnss_citygml.observations import OBSERVATION_COLUMNS, check_observations

DEMO_2016 = "google_demo_pseudoranges_log_2016_08_22_14_45_50.txt"


def separation(az1, el1, az2, el2):
    """Angle (deg) between two sky directions: the metric that does not blow up near zenith."""
    az1, el1, az2, el2 = map(np.radians, (az1, el1, az2, el2))
    cos = np.sin(el1) * np.sin(el2) + np.cos(el1) * np.cos(el2) * np.cos(az1 - az2)
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def test_orbit_sky_matches_googles_derived_positions(shared_data):
    """Azimuth and elevation from the broadcast orbits vs from Google's own satellite positions
    for the same GPS satellites at the same (transmission) times, seen from the ground truth:
    within 0.01 deg. (The file's ``millisSinceGpsEpoch`` labels are ~1 s off its positions.)"""
    gnss = shared_data / "gnss"
    derived = pd.read_csv(gnss / "gsdc2021_mtv_2020-05-14_Pixel4_derived_excerpt.csv")
    derived = derived[derived["signalType"] == "GPS_L1"]
    truth = pd.read_csv(gnss / "gsdc2021_mtv_2020-05-14_Pixel4_ground_truth_excerpt.csv").iloc[0]
    sent = derived["receivedSvTimeInGpsNanos"] - derived["satClkBiasM"] / 299792458.0 * 1e9
    times = gps_to_utc(np.round(sent.to_numpy()).astype(np.int64))
    orbits = load_orbits([shared_data / "orbits" / "brdc1350.20n"])
    ours = orbits.positions(times, "G", derived["svid"].to_numpy())
    place = (truth["latDeg"], truth["lngDeg"], truth["heightAboveWgs84EllipsoidM"])
    google = derived[["xSatPosM", "ySatPosM", "zSatPosM"]].to_numpy()
    assert len(derived) >= 50
    assert np.linalg.norm(ours - google, axis=1).max() < 0.1
    assert (
        separation(*azimuth_elevation(*place, ours), *azimuth_elevation(*place, google)).max()
        < 0.01
    )


def test_google_positions_match_the_phones_status_angles(shared_data):
    """The phone's own (whole-degree) Status directions of its Galileo satellites vs those from
    Google's positions: within 2 deg. (No Galileo orbits exist for that day here.)"""
    gnss = shared_data / "gnss"
    with pytest.warns(UserWarning, match="skipped 1 bad line"):  # its corrupted Fix altitude
        log = read_gnsslogger(
            gnss / "gsdc2021_mtv_2020-05-14_Pixel4_GnssLog_excerpt.txt", lenient=True
        )
    derived = pd.read_csv(gnss / "gsdc2021_mtv_2020-05-14_Pixel4_derived_excerpt.csv")
    first = derived[derived["millisSinceGpsEpoch"] == derived["millisSinceGpsEpoch"].min()]
    galileo = first[first["constellationType"] == 6].drop_duplicates("svid").set_index("svid")
    truth = pd.read_csv(gnss / "gsdc2021_mtv_2020-05-14_Pixel4_ground_truth_excerpt.csv").iloc[0]
    status = log.status[log.status["band"] == "L1"].set_index("svid")
    both = status.index.intersection(galileo.index)
    assert len(both) >= 5
    az, el = azimuth_elevation(
        truth["latDeg"],
        truth["lngDeg"],
        truth["heightAboveWgs84EllipsoidM"],
        galileo.loc[both, ["xSatPosM", "ySatPosM", "zSatPosM"]].to_numpy(),
    )
    phone = status.loc[both, "azimuth"].to_numpy(), status.loc[both, "elevation"].to_numpy()
    assert separation(az, el, *phone).max() < 2.0


@pytest.fixture(scope="module")
def demo_observations(shared_data):
    with pytest.warns(UserWarning, match="without orbit data"):
        return observe(
            [shared_data / "gnss" / DEMO_2016], [shared_data / "orbits" / "hour2350.16n"]
        )


def test_observations_of_a_real_log(shared_data, demo_observations):
    obs = demo_observations
    assert list(obs.columns) == OBSERVATION_COLUMNS
    check_observations(obs)  # the schema holds
    log = read_gnsslogger(shared_data / "gnss" / DEMO_2016)
    gps = log.raw[(log.raw["constellation"] == "G") & (log.raw["band"] == "L1")]
    assert obs["time_utc"].nunique() == log.epochs.size == 207
    assert set(obs["constellation"]) == {"G"}  # the nav file has GPS only
    assert obs["elevation"].between(10.0, 85.0).all()
    # every received GPS signal in view is a row with its C/N0; the rest are blocked rows
    received = obs.dropna(subset=["cn0"])
    merged = received.merge(gps, on=["time_utc", "constellation", "svid"], suffixes=("", "_raw"))
    assert len(merged) == len(received)
    np.testing.assert_array_equal(merged["cn0"], merged["cn0_raw"])
    assert obs["cn0"].isna().sum() > 0
    assert obs["receiver"].unique().tolist() == [DEMO_2016.removesuffix(".txt")]


def test_mask_changes_the_rows(shared_data, demo_observations):
    with pytest.warns(UserWarning):
        high = observe(
            [shared_data / "gnss" / DEMO_2016],
            [shared_data / "orbits" / "hour2350.16n"],
            min_elevation=30.0,
        )
    assert 0 < len(high) < len(demo_observations)
    assert high["elevation"].min() >= 30.0


def test_orbits_not_covering_the_log(shared_data):
    with pytest.raises(OrbitSpanError, match="2016-08-22"):
        observe([shared_data / "gnss" / DEMO_2016], [shared_data / "orbits" / "hour1820.16n"])


def test_empty_mask_is_an_error(shared_data):
    with pytest.raises(InputError, match="elevation mask"):
        observe(
            [shared_data / "gnss" / DEMO_2016],
            [shared_data / "orbits" / "hour2350.16n"],
            min_elevation=50.0,
            max_elevation=40.0,
        )
