"""Self-calibration of receiver offsets on a simulated street canyon."""

import warnings

import numpy as np
import pytest

from gnss_citygml.calibrate import calibrate_receivers, check_map_heights
from gnss_citygml.errors import InputError, MissingColumnError
from gnss_citygml.recordings import recording_windows
from gnss_citygml.settings import Calibration, Estimator
from gnss_citygml.simulate import simulate


@pytest.fixture(scope="module")
def canyon():
    sim = simulate("goodchild", locations="manual", seed=1, interval=5.0)
    return sim.rays, sim.buildings


def _cross_street_error(rx):
    # the canyon runs east-west: the northing error is what scales the intersection heights
    return (rx["n"] - rx["n_true"]).groupby(rx["receiver"]).mean()


@pytest.mark.parametrize("signal_model", ["paper", "mixture"])
def test_offsets_move_receivers_towards_the_truth(canyon, signal_model):
    rx, buildings = canyon
    estimator = Estimator(signal_model=signal_model)
    out = calibrate_receivers(rx, buildings, Calibration(prior_sd=1.0), estimator=estimator)
    before, after = _cross_street_error(rx), _cross_street_error(out)
    assert np.sqrt(np.mean(after**2)) < 0.6 * np.sqrt(np.mean(before**2))
    # one offset per recording, applied to e and n
    per_session = out.groupby("receiver")[["offset_e", "offset_n"]].nunique()
    assert (per_session == 1).all().all()
    np.testing.assert_allclose(out["e"] - out["offset_e"], rx["e"])


def test_windows_give_one_offset_per_window(canyon):
    rx, buildings = canyon
    out = calibrate_receivers(rx, buildings, Calibration(prior_sd=1.0, window=600.0, rounds=1))
    assert out.groupby("receiver")["offset_n"].nunique().max() > 1
    # the windows are those of the modelled position errors: one offset in each
    windows = recording_windows(rx, 600.0)
    assert (out.groupby(windows)[["offset_e", "offset_n"]].nunique() == 1).all().all()


def test_shadows_take_back_an_offset_every_recording_shares(canyon):
    """Every recording 3 m north (a bias all phones in a street share): the roof lines move
    with it, the shadows do not. (Towards the near wall, 0.5 m from it, the heights fitted from
    the shifted positions hold the receivers there: docs/issue-28-positions.md.)"""
    rx, buildings = canyon
    moved = rx.assign(n=rx["n"] + 3.0, position_sd=3.0)
    shadows = Calibration(prior_sd=3.0, matching="shadows", rounds=1)
    out = calibrate_receivers(moved, buildings, shadows)
    before, after = _cross_street_error(moved), _cross_street_error(out)
    assert after.abs().mean() < 0.6 * before.abs().mean()
    assert (out.groupby("receiver")[["offset_e", "offset_n"]].nunique() == 1).all().all()


def test_shadows_take_the_prior_where_a_position_claims_no_error(canyon):
    """A ``position_sd`` of 0 (or none) is no prior of 0 m: the calibration's is taken."""
    rx, buildings = canyon
    moved = rx.assign(n=rx["n"] + 3.0)
    shadows = Calibration(prior_sd=3.0, matching="shadows", rounds=1, window=1800.0)
    claimed_none = calibrate_receivers(moved.assign(position_sd=0.0), buildings, shadows)
    unsaid = calibrate_receivers(moved.drop(columns="position_sd"), buildings, shadows)
    np.testing.assert_array_equal(claimed_none["offset_n"], unsaid["offset_n"])
    assert np.isfinite(unsaid["offset_n"]).all() and unsaid["offset_n"].abs().max() > 0.5


@pytest.mark.parametrize("push", [3.0, -3.0])
@pytest.mark.parametrize("sd", [0.5, 2.0])
def test_roofs_given_with_the_map_take_back_a_bias_every_recording_shares(canyon, push, sd):
    """Every recording 3 m across the street, towards the near wall too (where the roofs fitted
    from the shifted positions hold the receivers there): against the map's heights, with
    their error (drawn with the standard deviation they claim), the bias is taken back."""
    rx, buildings = canyon
    truth, ground = _truth(buildings)
    error = np.random.default_rng(1).normal(0.0, sd, ground.size)
    buildings = buildings.assign(ground=ground, relh=truth - ground + error, other=truth - ground)
    moved = rx.assign(n=rx["n"] + push, position_sd=3.0)
    shadows = Calibration(prior_sd=3.0, matching="shadows", rounds=1, heights="relh", heights_sd=sd)
    out = calibrate_receivers(moved, buildings, shadows)
    before, after = _cross_street_error(moved), _cross_street_error(out)
    assert after.abs().mean() < 0.2 * before.abs().mean()


def test_a_map_height_of_zero_or_none_is_no_roof(canyon):
    """Where the map's field is empty, 0 or not a number, the building's roof is the one being
    estimated, as without the field."""
    rx, buildings = canyon
    moved = rx.assign(n=rx["n"] + 3.0, position_sd=3.0)
    _, ground = _truth(buildings)
    empty = buildings.assign(ground=ground, relh=[0.0, None, "n/a", -2.0])
    with_field = Calibration(prior_sd=3.0, matching="shadows", rounds=1, heights="relh")
    without = Calibration(prior_sd=3.0, matching="shadows", rounds=1)
    with pytest.warns(UserWarning, match="no building has a positive height"):
        matched = calibrate_receivers(moved, empty, with_field)
    np.testing.assert_array_equal(
        matched["n"],
        calibrate_receivers(moved, buildings, without)["n"],
    )


def test_a_map_heights_field_with_no_height_is_refused(canyon):
    """A field of names, or one all empty, would leave the matching without the map's heights,
    silently: refused, naming the field and what it holds; one of numbers none of which is a
    height (all 0 or less) is said."""
    rx, buildings = canyon
    _, ground = _truth(buildings)
    shadows = Calibration(prior_sd=3.0, matching="shadows", rounds=1, heights="relh")
    for values, said in (([f"block {k}" for k in range(4)], "block 0"), ([None] * 4, "empty")):
        named = buildings.assign(ground=ground, relh=values)
        with pytest.raises(InputError, match=f"'relh' holds no height.*{said}"):
            check_map_heights(named, shadows)
        with pytest.raises(InputError, match="holds no height"):
            calibrate_receivers(rx.assign(position_sd=3.0), named, shadows)
    with pytest.warns(UserWarning, match="no building has a positive height in .* 'relh'"):
        check_map_heights(buildings.assign(relh=[0.0, None, -2.0, "n/a"]), shadows)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_map_heights(buildings.assign(relh=[0.0, None, 12.0, "n/a"]), shadows)


def _truth(buildings):
    truth = simulate("goodchild", locations="manual", seed=1, interval=5.0).truth
    truth = truth.set_index("id").reindex(buildings["id"])
    return truth["height"].to_numpy(), truth["ground"].to_numpy()


def test_bad_input(canyon):
    rx, buildings = canyon
    one_metre = Calibration(prior_sd=1.0)
    with pytest.raises(MissingColumnError):
        calibrate_receivers(rx.drop(columns="bearing"), buildings, one_metre)
    with pytest.raises(MissingColumnError, match="time_utc"):
        calibrate_receivers(
            rx.drop(columns="time_utc"), buildings, Calibration(prior_sd=1.0, window=60.0)
        )
    with pytest.raises(MissingColumnError, match="svid"):
        shadows = Calibration(prior_sd=1.0, matching="shadows")
        calibrate_receivers(rx.drop(columns="svid"), buildings, shadows)
    heights = Calibration(prior_sd=1.0, matching="shadows", heights="relh2")
    with pytest.raises(MissingColumnError, match="'relh2'.*footprints.*id, geometry"):
        calibrate_receivers(rx, buildings, heights)
    with pytest.raises(InputError, match="map heights .* without shadow matching"):
        Calibration(prior_sd=1.0, heights="relh2")
    with pytest.raises(InputError, match="must name a footprint field"):
        Calibration(prior_sd=1.0, matching="shadows", heights="")
    with pytest.raises(InputError, match="standard deviation must be a positive"):
        Calibration(prior_sd=1.0, matching="shadows", heights="relh2", heights_sd=0.0)
    with pytest.raises(InputError, match="calibration matching must be one of"):
        Calibration(prior_sd=1.0, matching="shadow")
    with pytest.raises(InputError, match="'shadows' without self-calibration"):
        Calibration(matching="shadows")
    with pytest.raises(InputError, match="positive"):
        Calibration(prior_sd=0.0)
    with pytest.raises(InputError, match="calibration window without self-calibration"):
        Calibration(window=60.0)
    with pytest.raises(InputError, match="without a prior"):
        calibrate_receivers(rx, buildings, Calibration())
    with pytest.raises(InputError, match="needs method 4PL-B, not 4PL"):
        calibrate_receivers(rx, buildings, one_metre, estimator=Estimator(method="4PL"))
