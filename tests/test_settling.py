"""Fits that settle (issue 46): no height depends on where an iteration cap stopped a fit, or
4PL-B's loop."""

import numpy as np
import pandas as pd
import pytest

from gnss_citygml.cli.demo import CITY
from gnss_citygml.footprints import read_footprints
from gnss_citygml.model.fourpl import X_TOL, fit_4pl, logistic4
from gnss_citygml.model.settling import MAX_PERIOD, SETTLE_TOL, Settling
from gnss_citygml.observations import read_observations
from gnss_citygml.pipeline import run
from gnss_citygml.settings import BLAMES, Estimator

HIGH_CAPS = {"max_iter": 100, "fit_max_iter": 2000}


def _after(trajectory):
    """The settling of one building whose roof lines were ``trajectory``."""
    state = Settling.start(1)
    for c in trajectory:
        state = state.after(np.array([c]))
    return state


def test_a_roof_line_that_stops_moving_has_settled():
    state = _after([30.0, 31.0, 31.2, 31.2 + SETTLE_TOL / 2])
    assert state.settled[0] and not state.held[0]
    assert not _after([30.0, 31.0, 31.2]).settled[0]
    # a steady creep, however slow, is neither settled nor held: it is going somewhere
    creep = _after(30.0 + 0.01 * np.arange(3 * MAX_PERIOD))
    assert not creep.settled[0] and not creep.held[0]


@pytest.mark.parametrize("cycle", [[30.0, 34.0], [30.0, 34.0, 31.0], [30.0, 40.0, 35.0, 33.0]])
def test_a_roof_line_that_comes_back_is_held_with_its_cycle_in_its_span(cycle):
    state = Settling.start(1)
    seen = []
    for c in [25.0] + cycle * 3:
        state = state.after(np.array([c]))
        seen.append(c)
        if state.held[0]:
            break
    assert state.held[0] and state.settled[0]
    assert len(seen) == 2 + len(cycle)  # held as soon as the cycle closes
    assert (state.span_lower[0], state.span_upper[0]) == (min(cycle), max(cycle))
    # held, it stays held, and settled
    assert state.after(np.array([seen[-1]])).held[0]


def test_a_roof_line_that_swings_without_repeating_is_held_with_its_last_turn():
    state = _after([40.0, 50.0, 33.0, 47.0, 36.0])  # its third turn
    assert state.held[0]
    assert state.span_lower[0] == 33.0 and state.span_upper[0] == 47.0
    assert _after([40.0, 50.0, 33.0, 47.0, 36.0, 44.0]).span_upper[0] == 47.0  # held there
    # one excursion early on is not the swing: the roof line's last turn is (a MasterMap
    # house of tests/test_pipeline.py's Bloomsbury, seen over its neighbours' party walls)
    path = [30.597, 35.02, 94.321, 34.963, 35.066, 35.066, 35.151, 35.121]
    state = _after(path)
    assert state.held[0] and (state.span_lower[0], state.span_upper[0]) == (35.066, 35.151)


def test_a_building_without_a_fit_is_settled_and_counts_as_such():
    state = _after([np.nan, np.nan])
    assert state.settled[0] and state.moving(np.array([False])) == 0
    assert _after([30.0, 31.0]).moving(np.array([True])) == 1


def _gap_data(rng, lo=20.0, hi=44.0, n=600):
    """Closed crossings up to ``lo`` and open ones from ``hi``: the roof is anywhere in
    between."""
    h = np.r_[rng.uniform(lo - 10.0, lo, n), rng.uniform(hi, hi + 10.0, n)]
    open_ = np.r_[rng.random(n) < 0.1, rng.random(n) < 0.9]
    return h, open_.astype(float)


def test_a_roof_line_in_a_gap_is_its_middle_whatever_the_cap_or_the_start(rng):
    h, y = _gap_data(rng)
    lower, upper = h[h < 30].max(), h[h > 30].min()
    fits = [
        fit_4pl(h, y, max_iter=200),
        fit_4pl(h, y, max_iter=2000),
        fit_4pl(h, y, init=[[0.9, 0.5, 25.0, 0.1]]),
        fit_4pl(h, y, init=[[0.9, 50.0, 41.0, 0.1]]),
    ]
    for fit in fits:
        assert fit.converged[0]
        assert fit.c[0] == pytest.approx(0.5 * (lower + upper))
        assert (fit.gap_lower[0], fit.gap_upper[0]) == (lower, upper)


def test_a_converged_roof_line_does_not_depend_on_where_the_fit_started(rng):
    h = rng.uniform(0.0, 60.0, 4000)
    y = (rng.random(h.size) < logistic4(h, 0.85, 0.6, 31.0, 0.15)).astype(float)
    starts = [None, [[0.6, 0.1, 20.0, 0.3]], [[0.99, 20.0, 40.0, 0.01]], [[0.7, 1.0, 31.5, 0.2]]]
    fits = [fit_4pl(h, y, init=start) for start in starts]
    c = np.array([fit.c[0] for fit in fits])
    assert all(fit.converged[0] and np.isnan(fit.gap_lower[0]) for fit in fits)
    assert np.ptp(c) <= X_TOL  # all within the tolerance on c of one another
    assert all(fit.n_iter[0] < 30 for fit in fits)  # data that pin c: no tail


def _city_run(**caps):
    obs = read_observations(CITY / "observations.parquet")
    return run(obs, read_footprints(CITY / "footprints.gpkg"), str(CITY / "dem.tif"), **caps)


@pytest.mark.parametrize("blame", BLAMES)
def test_the_sample_citys_heights_do_not_depend_on_the_caps(blame):
    default = _city_run(estimator=Estimator(blame=blame))
    high = _city_run(estimator=Estimator(blame=blame, **HIGH_CAPS))
    columns = ["id", "status", "height", "height_lower", "height_upper"]
    a, b = default.heights[columns], high.heights[columns]
    pd.testing.assert_series_equal(a["status"], b["status"])
    both = a["status"] == "ok"
    assert both.sum() >= 20  # the sample city's buildings mostly converge
    assert np.abs(a["height"] - b["height"])[both].max() <= 0.01
    # the loop ended because it settled, not at its cap
    assert default.heights["iterations"].max() < Estimator().max_iter


def test_a_building_whose_rows_and_labels_stay_keeps_its_fit(rng):
    from gnss_citygml.model.classifier import SignalClassifier
    from gnss_citygml.model.parts import Part

    n = 3000
    g = np.repeat([0, 1], n)
    h = rng.uniform(0.0, 60.0, 2 * n)
    roof = np.where(g == 0, 25.0, 40.0)
    cn0 = np.where(h > roof + rng.normal(0.0, 1.0, h.size), 42.0, 22.0) + rng.normal(0, 2, h.size)
    part = Part.of(g, h, cn0, 2).fitted(SignalClassifier.initial(30.0))
    first = part.last.fit
    # the same classifier labels the rows alike: nothing to fit again, every fit is its last
    again = part.fitted(SignalClassifier.initial(30.0)).last
    assert np.array_equal(again.fit.params, first.params)
    assert again.settling.settled.all() and (again.change == 0).all()
    # a classifier that relabels rows refits the buildings whose labels changed
    moved = part.fitted(SignalClassifier.initial(35.0)).last
    assert not np.array_equal(moved.fit.params, first.params)
