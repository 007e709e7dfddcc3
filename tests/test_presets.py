"""4PL-B on the simulated versions of the paper's sites, for initial thresholds 20, 30, 40."""

import numpy as np
import pytest

from gnss_citygml import Estimator, estimate_heights
from gnss_citygml.pipeline import intersections
from gnss_citygml.simulate import simulate

THRESHOLDS = (20.0, 30.0, 40.0)


@pytest.fixture(scope="module")
def sims():
    cache = {}

    def get(preset, locations):
        if (preset, locations) not in cache:
            cache[(preset, locations)] = simulate(preset, locations=locations, seed=0, interval=5.0)
        return cache[(preset, locations)]

    return get


def _cast(sim):
    """The intersections as the pipeline casts them by default: each position 1 m off (placed
    by hand) or as far as the phone says its fix may be."""
    return intersections(sim.rays, sim.buildings)


def _target(sim, threshold, method="4PL-B"):
    """The estimate of the site's target building and its true height."""
    truth = sim.truth.set_index("id")
    estimator = Estimator(method=method, init_threshold=threshold)
    out = estimate_heights(_cast(sim), estimator).set_index("id")
    bid = truth.index[truth["target"]][0]
    return out.loc[bid], truth.loc[bid, "height"]


@pytest.mark.parametrize("locations", ["manual", "gnss"])
@pytest.mark.parametrize("preset", ["ucl", "hermitage"])
@pytest.mark.parametrize("threshold", THRESHOLDS)
def test_open_sites_are_recovered_within_their_range(sims, preset, locations, threshold):
    row, truth = _target(sims(preset, locations), threshold)
    assert row["converged"], row["status"]
    # GNSS fixes err by metres: the transition widens. UCL's truth is one part of a roof of
    # several levels and a dome (the entrance hall, as the paper adopted it): the roof line the
    # signals see, c, is 2 m under it; the paper's c + 1.5/b is nearer there.
    tolerance = 3.0 if locations == "gnss" else {"ucl": 2.5, "hermitage": 1.5}[preset]
    assert row["height"] == pytest.approx(truth, abs=tolerance)
    assert row["height_lower"] - 1.0 <= truth <= row["height_upper"] + 1.0


@pytest.mark.parametrize("threshold", THRESHOLDS)
def test_canyon_roof_line_is_found_with_manual_positions(sims, threshold):
    # In the canyon, position errors blur the transition (3/b of several metres) and the paper's
    # point estimate c + 1.5/b sits above the roof; the inflection point c (the height) finds it.
    row, truth = _target(sims("goodchild", "manual"), threshold)
    assert row["converged"], row["status"]
    assert row["c"] == pytest.approx(truth, abs=3.5)
    assert row["height_upper"] - row["height_lower"] < 10.0


@pytest.mark.parametrize("threshold", THRESHOLDS)
def test_canyon_with_gnss_fixes_is_reported_not_guessed(sims, threshold):
    # The paper's own result: with the phone's fixes in a canyon 4PL-B failed (0/20).
    row, _ = _target(sims("goodchild", "gnss"), threshold)
    assert not row["converged"]
    assert np.isnan(row["height"]) and row["status"] != "ok"


@pytest.mark.parametrize("threshold", THRESHOLDS)
def test_city_with_walkers(sims, threshold):
    sim = sims("city", "manual")
    truth = sim.truth.set_index("id")["height"]
    out = estimate_heights(_cast(sim), Estimator(init_threshold=threshold)).set_index("id")
    ok = out["converged"]
    true = truth.reindex(out.index)
    err = (out["height"] - true)[ok]
    inside = ((out["height_lower"] <= true) & (true <= out["height_upper"]))[ok]
    # half of the buildings or more; the rest with a status: their data leave a range over 10 m
    assert ok.mean() >= 0.5
    assert np.median(np.abs(err)) < 1.0
    assert np.abs(err).max() < 6.0
    assert inside.mean() >= 0.85


def test_baselines_depend_on_the_threshold_where_4plb_does_not(sims):
    sim = sims("hermitage", "manual")

    def spread(method):
        return np.ptp([_target(sim, t, method=method)[0]["height"] for t in THRESHOLDS])

    assert spread("4PL-B") < 1.0 < spread("hinge")
