import numpy as np
import pytest

from gnss_citygml.model.classifier import Cn0Counts, SignalClassifier


def test_initial_classifier_is_the_papers():
    clf = SignalClassifier.initial(27.0)
    assert (clf.a, clf.b, clf.c, clf.d) == (0.9, 0.2, 27.0, 0.1)
    assert clf.threshold == pytest.approx(27.0)


def test_blocked_signals_are_closed():
    clf = SignalClassifier.initial(10.0)
    assert clf.prob(np.array([np.nan]))[0] == 0.0
    assert not clf.label(np.array([np.nan]))[0]


def test_refit_learns_the_threshold(rng):
    cn0 = rng.uniform(10, 50, 20000)
    labels = rng.random(cn0.size) < np.where(cn0 > 36.0, 0.95, 0.05)
    clf = SignalClassifier.initial(25.0).refit(cn0, labels)
    assert clf.threshold == pytest.approx(36.0, abs=0.5)


def test_refit_ignores_blocked_and_keeps_itself_on_one_class(rng):
    clf = SignalClassifier.initial(30.0)
    assert clf.refit(np.array([np.nan, 40.0, 41.0]), np.array([False, True, True])) is clf
    assert clf.refit(np.array([]), np.array([], dtype=bool)) is clf


def test_counts_of_parts_add_up_to_the_whole_and_refit_it_exactly(rng):
    # the tiles of a distributed run each count their signals; one sum refits the classifier
    n = 5000
    is_open = rng.random(n) < 0.6
    cn0 = np.where(is_open, rng.normal(40, 4, n), rng.normal(25, 5, n)).round(1)
    cn0[rng.random(n) < 0.1] = np.nan  # blocked: no C/N0
    labels = is_open ^ (rng.random(n) < 0.05)
    part = rng.integers(0, 4, n)
    counts = [Cn0Counts.of(cn0[part == p], labels[part == p]) for p in range(4)]
    total = counts[0] + counts[1] + counts[2] + counts[3]
    whole = Cn0Counts.of(cn0, labels)
    for name in ("key", "n", "k"):
        np.testing.assert_array_equal(getattr(total, name), getattr(whole, name))
    assert total.n.sum() == np.isfinite(cn0).sum()
    start = SignalClassifier.initial(30.0)
    assert start.refit_counts(total) == start.refit(cn0, labels)
    assert 30.0 < start.refit(cn0, labels).threshold < 36.0
