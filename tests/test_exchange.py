"""The paper's exchange, signal by signal (gnss_citygml.model.exchange): an update of the last
exchange is the exchange over every row, bit for bit."""

import numpy as np
import pytest

from gnss_citygml.cli.demo import CITY
from gnss_citygml.footprints import read_footprints
from gnss_citygml.model import exchange
from gnss_citygml.model.classifier import Cn0Counts, SignalClassifier
from gnss_citygml.model.estimate import intersections_part
from gnss_citygml.observations import read_observations
from gnss_citygml.pipeline import run
from gnss_citygml.settings import BLAMES, Estimator, PositionError


def test_group_rows_are_the_rows_of_the_groups(rng):
    g = np.sort(rng.integers(0, 50, 2000))
    for groups in (np.array([], dtype=int), np.array([0]), np.array([3, 7, 49, 60]), np.arange(50)):
        assert np.array_equal(exchange.group_rows(g, groups), np.flatnonzero(np.isin(g, groups)))


def test_counts_in_and_out_are_the_counts_of_the_signals_left(rng):
    cn0 = rng.choice(np.r_[np.arange(15.0, 50.0, 0.1), np.nan], 3000)
    labels = rng.random(3000) < 0.6
    first, second = slice(0, 1800), slice(1800, None)
    whole = Cn0Counts.of(cn0, labels)
    part = Cn0Counts.of(cn0[first], labels[first])
    rest = Cn0Counts.of(cn0[second], labels[second])
    empty = Cn0Counts.of([], [])
    for got, want in ((whole.plus(empty, rest), part), (part.plus(rest, empty), whole)):
        for name in ("key", "n", "k"):
            assert np.array_equal(getattr(got, name), getattr(want, name))
    # a C/N0 left without a signal is gone, as Cn0Counts.of has it
    alone = Cn0Counts.of([33.3], [True])
    assert whole.plus(alone, empty).plus(empty, alone).key.size == whole.key.size


@pytest.fixture(scope="module", params=[False, True], ids=["entered", "crossing chance"])
def city_cast(request):
    """The sample city's run; with each row's chance of crossing, near misses too."""
    obs = read_observations(CITY / "observations.parquet")
    error = PositionError(crossing=request.param)
    return run(
        obs, read_footprints(CITY / "footprints.gpkg"), str(CITY / "dem.tif"), position_error=error
    )


def _state(part, tally):
    state = part.exchange
    return (
        part.seen,
        tally.evidence.key,
        tally.evidence.n,
        tally.evidence.k,
        state.used,
        state.lead,
        state.clear,
        state.moved,
    )


@pytest.mark.parametrize("blame", BLAMES)
def test_an_update_is_the_exchange_over_every_row(city_cast, blame, monkeypatch):
    """4PL-B's loop on the sample city, each exchange done both ways from the same part."""
    part = intersections_part(city_cast.intersections, Estimator(blame=blame))[1]
    model, updates = SignalClassifier.initial(30.0), 0
    redone = []  # the rows of each update that found signals again
    update = exchange._update
    monkeypatch.setattr(
        exchange, "_update", lambda *args: redone.append(args[-1].size) or update(*args)
    )
    for _ in range(12):
        part = part.fitted(model)
        shared = part.shared()
        monkeypatch.setattr(exchange, "FULL_SHARE", -1.0)  # every row, always
        every, every_tally = part.exchanged(shared)
        monkeypatch.setattr(exchange, "FULL_SHARE", 2.0)  # an update wherever it can
        updated, tally = part.exchanged(shared)
        for a, b in zip(_state(every, every_tally), _state(updated, tally), strict=True):
            assert np.array_equal(a, b)
        updates += part.exchange is not None
        part, model = updated, tally.refit(model)
    assert updates == 11  # all but the first were updates
    assert len(redone) >= 5 and 0 < min(redone)
    # late on, a few signals; with whole-ray blame, or rows weighed by their chance of crossing,
    # the loop (run on past the 9th iteration, where the sample city's ends) still refits some
    # of its 30 buildings by micrometres
    if blame == "drop" and "crossing" not in city_cast.intersections:
        assert min(redone) < part.h.size / 4


def test_the_citys_heights_are_the_same_whichever_way(monkeypatch):
    obs = read_observations(CITY / "observations.parquet")
    footprints = read_footprints(CITY / "footprints.gpkg")
    heights = []
    for share in (-1.0, 2.0):
        monkeypatch.setattr(exchange, "FULL_SHARE", share)
        heights.append(run(obs, footprints, str(CITY / "dem.tif")).heights)
    assert heights[0].equals(heights[1])
