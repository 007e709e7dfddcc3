import numpy as np
import pytest

from gnss_citygml.model.baselines import BAYES_FLOOR, bayes_heights, hinge_heights

# Four signals of one building, labelled by a classifier with threshold 30 dB-Hz:
# closed at 5 m and 8 m (C/N0 20 and NaN), open at 10 m and 12 m (C/N0 40).
HEIGHTS = np.array([12.0, 5.0, 10.0, 8.0])
CN0 = np.array([40.0, 20.0, 40.0, np.nan])
GROUPS = np.zeros(4, dtype=int)


def test_hinge_separable_example_is_the_middle_of_the_gap():
    # cost(H) = sum over open of max(0, H - h) + sum over closed of max(0, h - H): zero on [8, 10]
    assert hinge_heights(GROUPS, HEIGHTS, CN0, 1)[0] == pytest.approx(9.0)


def test_hinge_hand_computed_with_misclassified_signals():
    # open at 2 and 10, closed at 6 and 8: cost(6) = 4 + 2 = 6, cost(8) = 6 + 0 = 6,
    # cost(2) = 0 + 4 + 6 = 10, cost(10) = 8: a flat minimum on [6, 8].
    h = np.array([2.0, 6.0, 8.0, 10.0])
    cn0 = np.array([40.0, 20.0, 20.0, 40.0])
    assert hinge_heights(np.zeros(4, int), h, cn0, 1)[0] == pytest.approx(7.0)
    # A third closed signal at 9 m: cost(8) = 6 + 1 = 7 = cost(9) = 7, cost(10) = 8, cost(6) = 9,
    # so the minimum is flat on [8, 9].
    h2 = np.append(h, 9.0)
    cn2 = np.append(cn0, 20.0)
    assert hinge_heights(np.zeros(5, int), h2, cn2, 1)[0] == pytest.approx(8.5)


def test_bayes_hand_computed():
    # p(open) = 0.9 for C/N0 40, 0.1 for 20 and the floor for the blocked one; the likelihood is
    # highest with H between 8 and 10.
    assert bayes_heights(GROUPS, HEIGHTS, CN0, 1)[0] == pytest.approx(9.0)
    # Brute force over candidate heights agrees on a noisier example.
    rng = np.random.default_rng(3)
    h = rng.uniform(0, 30, 40)
    cn0 = np.where(h > 15, rng.normal(38, 5, 40), rng.normal(26, 5, 40))
    p = np.clip(0.1 + 0.8 / (1 + np.exp(-0.2 * (cn0 - 30.0))), BAYES_FLOOR, 1 - BAYES_FLOOR)
    cands = np.sort(h)
    ll = [np.sum(np.where(h <= H, np.log1p(-p), np.log(p))) for H in cands]
    k = int(np.argmax(ll))
    expected = 0.5 * (cands[k] + cands[k + 1])
    assert bayes_heights(np.zeros(40, int), h, cn0, 1)[0] == pytest.approx(expected)


def test_many_buildings_match_one_at_a_time(rng):
    groups = rng.integers(0, 5, 600)
    h = rng.uniform(0, 50, 600)
    cn0 = np.where(h > 10 + 5 * groups, 40.0, 20.0) + rng.normal(0, 6, 600)
    for func in (hinge_heights, bayes_heights):
        together = func(groups, h, cn0, 6)
        assert np.isnan(together[5])
        for k in range(5):
            m = groups == k
            alone = func(np.zeros(m.sum(), int), h[m], cn0[m], 1)[0]
            assert together[k] == pytest.approx(alone)


def test_results_depend_on_the_threshold(rng):
    h = rng.uniform(20, 80, 3000)
    cn0 = np.where(h > 45, rng.normal(40, 4, 3000), rng.normal(25, 5, 3000))
    low = hinge_heights(np.zeros(3000, int), h, cn0, 1, init_threshold=20)[0]
    high = hinge_heights(np.zeros(3000, int), h, cn0, 1, init_threshold=40)[0]
    assert low < 45 < high
