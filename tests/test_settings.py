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
    RunSettings,
    Tiling,
)


def test_defaults_are_the_papers():
    assert Rays() == Rays(min_elevation=10.0, max_elevation=85.0, max_range=500.0)
    assert not Rays().earth_curvature
    assert ReceiverHeights() == ReceiverHeights(source="dem", antenna_height=1.0)
    assert Estimator() == Estimator(
        method="4PL-B", init_threshold=30.0, weighting="none", visibility=True, max_iter=30
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
        (lambda: PositionError(sd=-1.0), "position error must be a number of metres, 0 to"),
        (lambda: PositionError(sd=float("inf")), "position error must be a number of metres"),
        (lambda: PositionError(sd=1.0, window=0.0), "position window must be a positive"),
        (lambda: Calibration(prior_sd=float("nan")), "calibration prior must be a positive"),
        (lambda: Calibration(window=30.0), "a calibration window without self-calibration"),
        (lambda: Calibration(prior_sd=5.0, rounds=0), "calibration rounds"),
        (lambda: Estimator(init_threshold=float("nan")), "init_threshold"),
        (lambda: Estimator(max_iter=0), "max_iter"),
        (lambda: Estimator(fit_max_iter=0), "fit_max_iter"),
        (lambda: Estimator(fit_max_iter=-200), "fit_max_iter"),
        (lambda: Estimator(method="hinge", fit_max_iter=50), "fit_max_iter not used by method"),
        (lambda: Estimator(method="bayes", max_iter=5), "max_iter not used by method bayes"),
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


NAN, INF = float("nan"), float("inf")


@pytest.mark.parametrize(
    "settings, message",
    [
        # each option with a unit has a range from its physics; NaN and inf are refused
        (lambda: ReceiverHeights(antenna_height=-50.0), "antenna_height .* above the ground"),
        (lambda: ReceiverHeights(antenna_height=1e9), "antenna_height"),
        (lambda: ReceiverHeights(antenna_height=NAN), "antenna_height"),
        (lambda: Rays(max_range=1e9), "max_range must be a positive number of metres up to"),
        (lambda: Rays(max_range=NAN), "max_range"),
        (lambda: Rays(min_elevation=NAN), "elevation mask"),
        (lambda: Rays(max_elevation=INF), "elevation mask"),
        (lambda: Estimator(init_threshold=-5.0), "init_threshold must be a C/N0"),
        (lambda: Estimator(init_threshold=1e6), "init_threshold"),
        (lambda: Estimator(init_threshold=INF), "init_threshold"),
        (lambda: Estimator(max_iter=10**9), "max_iter must be a whole number, 1 to 1000"),
        (lambda: Estimator(max_iter=2.5), "max_iter"),
        (lambda: Estimator(fit_max_iter=10**6), "fit_max_iter must be a whole number, 1 to 10000"),
        (lambda: Estimator(fit_max_iter=200.0), "fit_max_iter"),
        (lambda: Estimator(fit_max_iter=NAN), "fit_max_iter"),
        (lambda: Estimator(fit_max_iter=True), "fit_max_iter"),
        (lambda: Estimator(max_iter=True), "max_iter"),
        (lambda: Acceptance(min_signals=True), "min_signals"),
        (lambda: Acceptance(max_uncertainty=1e9), "max_uncertainty"),
        (lambda: Acceptance(max_uncertainty=NAN), "max_uncertainty"),
        (lambda: Acceptance(label_tol=NAN), "label_tol"),
        (lambda: Acceptance(min_separation=INF), "min_separation"),
        (lambda: PositionError(sd=1e6), "position error must be a number of metres, 0 to 1000"),
        (lambda: PositionError(sd=NAN), "position error"),
        (lambda: PositionError(window=-30.0), "position window"),
        (lambda: PositionError(window=1e12), "position window .* up to 86400"),
        (lambda: PositionError(window=NAN), "position window"),
        (lambda: PositionError(distance=0.0), "position error.s distance"),
        (lambda: PositionError(distance=1e9), "distance .* up to 100000"),
        (lambda: PositionError(distance=NAN), "position error.s distance"),
        (lambda: Calibration(prior_sd=0.0), "calibration prior"),
        (lambda: Calibration(prior_sd=1e9), "calibration prior .* up to 1000"),
        (lambda: Calibration(prior_sd=5.0, window=INF), "calibration window"),
        (lambda: Calibration(prior_sd=5.0, window=1e12), "calibration window"),
        (lambda: Calibration(prior_sd=5.0, rounds=10**6), "calibration rounds .* 1 to 100"),
        (lambda: Tiling("local", workers=100_000), "at most 4 worker processes per core"),
    ],
)
def test_options_outside_their_physical_range_are_refused(settings, message):
    with pytest.raises((InputError, ModelError), match=message) as caught:
        settings()
    assert "\n" not in str(caught.value) and ": " in str(caught.value)


def test_options_at_the_ends_of_their_ranges_are_taken():
    ReceiverHeights(antenna_height=0.0)
    ReceiverHeights(antenna_height=500.0)
    Rays(max_range=10_000.0, min_elevation=-90.0, max_elevation=90.0)
    Estimator(init_threshold=0.0, max_iter=1000, fit_max_iter=10_000)
    Estimator(max_iter=1, fit_max_iter=1)
    PositionError(sd=1000.0, window=86_400.0)
    Calibration(prior_sd=1000.0, window=86_400.0, rounds=100)


def test_calibration_only_with_4plb():
    for method in ("4PL", "hinge", "bayes"):
        with pytest.raises(InputError, match=f"self-calibration needs method 4PL-B, not {method}"):
            Calibration(prior_sd=5.0).check_method(Estimator(method=method))
    Calibration(prior_sd=5.0).check_method(Estimator())
    Calibration().check_method(Estimator(method="hinge"))  # no calibration asked for


def test_run_settings_are_checked_together_when_made():
    """The rules between the parts (:meth:`RunSettings.check`) hold for every way a run's
    settings are made: at once, or by replacing a part of checked ones."""
    assert RunSettings() == RunSettings.of() == RunSettings.of(None)
    assert RunSettings.of(estimator=Estimator(method="4PL")).estimator.method == "4PL"
    local = Tiling("local")
    with pytest.raises(InputError, match="self-calibration needs method 4PL-B, not 4PL"):
        RunSettings(calibration=Calibration(prior_sd=5.0), estimator=Estimator(method="4PL"))
    with pytest.raises(InputError, match="runs 4PL-B or 4PL, not hinge"):
        RunSettings.of(RunSettings(tiling=local), estimator=Estimator(method="hinge"))
    with pytest.raises(InputError, match="self-calibration is not available in a run on a Dask"):
        RunSettings.of(RunSettings(calibration=Calibration(prior_sd=5.0)), tiling=local)
    RunSettings(tiling=local, estimator=Estimator(method="4PL"))
    RunSettings(estimator=Estimator(method="hinge"))  # no tiles, no calibration: any method


def test_a_run_settings_part_of_another_kind_is_named():
    """``RunSettings(estimator="4PL")`` is a caller's slip, named, not an AttributeError."""
    with pytest.raises(
        TypeError, match="the run settings' estimator must be of type Estimator, not"
    ):
        RunSettings(estimator="4PL")
    with pytest.raises(TypeError, match="the run settings' tiling must be of type Tiling"):
        RunSettings.of(tiling="local")


def test_an_unknown_part_of_the_run_settings_is_named():
    with pytest.raises(TypeError, match="unknown run settings: estimater, grid"):
        RunSettings.of(estimater=Estimator(), grid="x", rays=Rays())
