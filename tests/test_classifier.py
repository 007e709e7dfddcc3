import numpy as np
import pytest

from gnss_citygml.model.classifier import SignalClassifier


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
