"""The settings objects: their defaults, and bad values refused in one line when they are made."""

import pytest

from gnss_citygml.errors import InputError, ModelError
from gnss_citygml.settings import (
    Acceptance,
    Calibration,
    Estimator,
    PositionError,
    Rays,
    ReceiverHeights,
)


def test_defaults_are_the_papers():
    assert Rays() == Rays(min_elevation=10.0, max_elevation=85.0, max_range=500.0)
    assert not Rays().earth_curvature
    assert ReceiverHeights() == ReceiverHeights(source="dem", antenna_height=1.0)
    assert Estimator() == Estimator(
        method="4PL-B", init_threshold=30.0, weighting="none", visibility=True, max_iter=10
    )
    assert Estimator().acceptance == Acceptance(0.01, 10, 0.3, 10.0)
    # position errors from the data by default; sd=0 takes positions as exact, as the paper
    assert PositionError() == PositionError(sd=None, window=None)
    assert not PositionError().exact and PositionError(sd=0).exact
    assert not Calibration().on
    assert Calibration(prior_sd=5.0).rounds == 3


def test_settings_are_frozen():
    with pytest.raises(AttributeError):
        Estimator().method = "hinge"


@pytest.mark.parametrize(
    "settings, message",
    [
        (lambda: Rays(min_elevation=40.0, max_elevation=30.0), "elevation mask 40.0..30.0"),
        (lambda: Rays(max_elevation=95.0), "elevation mask"),
        (lambda: Rays(max_range=0.0), "max_range"),
        (lambda: ReceiverHeights(source="gps"), "unknown receiver height source 'gps'"),
        (lambda: ReceiverHeights(antenna_height=float("inf")), "antenna_height"),
        (lambda: PositionError(sd=-1.0), "position error must be a number of metres, 0 or"),
        (lambda: PositionError(sd=float("inf")), "position error must be a number of metres"),
        (lambda: PositionError(sd=1.0, window=0.0), "position window must be a positive"),
        (lambda: Calibration(prior_sd=float("nan")), "calibration prior must be a positive"),
        (lambda: Calibration(window=30.0), "a calibration window without self-calibration"),
        (lambda: Calibration(prior_sd=5.0, rounds=0), "calibration rounds"),
        (lambda: Estimator(init_threshold=float("nan")), "init_threshold"),
        (lambda: Estimator(max_iter=0), "max_iter"),
        (lambda: Acceptance(min_signals=2.5), "min_signals"),
        (lambda: Acceptance(label_tol=-0.1), "label_tol"),
        (lambda: Acceptance(min_separation=2.0), "min_separation"),
        (lambda: Acceptance(max_uncertainty=0.0), "max_uncertainty"),
    ],
)
def test_bad_values_are_refused_in_one_line(settings, message):
    with pytest.raises((InputError, ModelError), match=message) as caught:
        settings()
    assert "\n" not in str(caught.value) and ": " in str(caught.value)  # what: how to fix


def test_calibration_only_with_4plb():
    for method in ("4PL", "hinge", "bayes"):
        with pytest.raises(InputError, match=f"self-calibration needs method 4PL-B, not {method}"):
            Calibration(prior_sd=5.0).check_method(Estimator(method=method))
    Calibration(prior_sd=5.0).check_method(Estimator())
    Calibration().check_method(Estimator(method="hinge"))  # no calibration asked for
