import numpy as np
import pytest
from conftest import draw_4pl

from gnss_citygml.model.fourpl import (
    fit_4pl,
    group_range,
    log_likelihood,
    logistic4,
)
from gnss_citygml.model.interval import c_interval


def test_logistic4_shape():
    x = np.array([-1e3, 30.0, 1e3])
    p = logistic4(x, 0.9, 0.2, 30.0, 0.1)
    np.testing.assert_allclose(p, [0.1, 0.5, 0.9])


def test_gradient_matches_finite_differences(rng):
    x, y = draw_4pl(rng, 500, 0.8, 0.4, 30.0, 0.2)
    w = rng.uniform(0.5, 2.0, x.size)
    params = np.array([0.7, 0.3, 28.0, 0.15])
    _, grad = log_likelihood(params, x, y, w)
    for k in range(4):
        h = np.zeros(4)
        h[k] = 1e-6
        up, _ = log_likelihood(params + h, x, y, w)
        down, _ = log_likelihood(params - h, x, y, w)
        assert grad[k] == pytest.approx((up - down) / 2e-6, rel=1e-4, abs=1e-4)


@pytest.mark.parametrize("seed", range(12))
def test_recovers_known_parameters(seed):
    rng = np.random.default_rng(seed)
    a, b, c, d = (
        rng.uniform(0.75, 0.95),
        rng.uniform(0.3, 1.5),
        rng.uniform(20, 40),
        rng.uniform(0.02, 0.25),
    )
    x, y = draw_4pl(rng, 20000, a, b, c, d)
    fit = fit_4pl(x, y)
    assert fit.converged[0]
    assert fit.c[0] == pytest.approx(c, abs=0.6)
    assert fit.a[0] == pytest.approx(a, abs=0.03)
    assert fit.d[0] == pytest.approx(d, abs=0.03)
    assert fit.b[0] == pytest.approx(b, rel=0.35)


def test_fit_is_a_maximum(rng):
    x, y = draw_4pl(rng, 3000, 0.85, 0.5, 33.0, 0.15)
    fit = fit_4pl(x, y)
    best, grad = log_likelihood(fit.params[0], x, y)
    assert np.max(np.abs(grad)) < 0.05
    for shift in ([0.01, 0, 0, 0], [0, 0.05, 0, 0], [0, 0, 0.3, 0], [0, 0, 0, 0.01]):
        assert log_likelihood(fit.params[0] + np.array(shift), x, y)[0] <= best + 1e-6
        assert log_likelihood(fit.params[0] - np.array(shift), x, y)[0] <= best + 1e-6


def test_weights_equal_repeated_samples(rng):
    x, y = draw_4pl(rng, 800, 0.85, 0.5, 33.0, 0.15)
    reps = rng.integers(1, 4, x.size)
    weighted = fit_4pl(x, y, reps)
    repeated = fit_4pl(np.repeat(x, reps), np.repeat(y, reps))
    np.testing.assert_allclose(weighted.params, repeated.params, rtol=1e-4, atol=1e-4)


def test_groups_are_fitted_independently(rng):
    xs, ys, gs = [], [], []
    for k, c in enumerate([15.0, 30.0, 45.0]):
        x, y = draw_4pl(rng, 5000, 0.9, 0.8, c, 0.1)
        xs.append(x)
        ys.append(y)
        gs.append(np.full(x.size, k))
    fit = fit_4pl(np.concatenate(xs), np.concatenate(ys), groups=np.concatenate(gs))
    np.testing.assert_allclose(fit.c, [15.0, 30.0, 45.0], atol=0.8)
    single = fit_4pl(xs[1], ys[1])
    assert fit.c[1] == pytest.approx(single.c[0], abs=1e-3)


@pytest.mark.parametrize("before", [1, 777, 70_000])
@pytest.mark.parametrize("size", [40, 3000, 150_000])
def test_a_groups_fit_is_the_same_bit_for_bit_whatever_groups_surround_it(before, size):
    """A tile fits a building among other groups than the whole run does: its fit must not
    change in the last bit, or a flat likelihood (separable data, a gap in the heights) turns
    the rounding into metres. Groups of every size (packed with others in a block, alone,
    spanning blocks), after a group of any size, with weights and errors in x."""
    rng = np.random.default_rng(size + before)
    x, y = draw_4pl(rng, size, 0.9, 2.0, 30.0, 0.1)
    w, sd = rng.uniform(0.2, 1.0, size), rng.uniform(0.0, 2.0, size)
    x0, y0 = draw_4pl(rng, before, 0.8, 0.5, 20.0, 0.2)
    alone = fit_4pl(x, y, w, sd=sd, init=[[0.8, 1.0, 29.0, 0.1]])
    w0, sd0 = rng.uniform(0.2, 1.0, before), rng.uniform(0.0, 2.0, before)
    x_all, y_all, g_all = (
        np.r_[x0, x],
        np.r_[y0, y],
        np.r_[np.zeros(before, int), np.ones(size, int)],
    )
    after = fit_4pl(
        x_all,
        y_all,
        np.r_[w0, w],
        g_all,
        sd=np.r_[sd0, sd],
        init=[[0.7, 0.4, 21.0, 0.2], [0.8, 1.0, 29.0, 0.1]],
    )
    for name in ("a", "b", "c", "d", "loglik"):
        assert getattr(after, name)[1] == getattr(alone, name)[0], name
    one = c_interval(alone, x, y, np.zeros(size, int), weights=w, sd=sd)
    two = c_interval(after, x_all, y_all, g_all, weights=np.r_[w0, w], sd=np.r_[sd0, sd])
    assert (two[0][1], two[1][1]) == (one[0][0], one[1][0])


def test_separable_data_end_on_the_boundary():
    x = np.linspace(0.0, 10.0, 60)
    fit = fit_4pl(x, x > 5.0)
    assert fit.separable[0]
    assert 4.8 < fit.c[0] < 5.2
    assert fit.a[0] > 0.99 and fit.d[0] < 0.01
    assert np.isfinite(fit.loglik[0])


@pytest.mark.parametrize("labels", [np.ones(40), np.zeros(40)])
def test_one_class_data_stay_finite(labels):
    fit = fit_4pl(np.linspace(0.0, 40.0, 40), labels)
    assert np.all(np.isfinite(fit.params))
    assert 0 <= fit.d[0] < fit.a[0] <= 1


def test_tiny_and_empty_groups():
    fit = fit_4pl(
        np.array([1.0, 2.0, 3.0]), np.array([0, 1, 1]), groups=np.array([0, 0, 0]), n_groups=2
    )
    assert np.all(np.isfinite(fit.params[0]))
    assert np.all(np.isnan(fit.params[1])) and not fit.converged[1]


def test_constraints_hold(rng):
    x, y = draw_4pl(rng, 2000, 0.6, 2.0, 10.0, 0.5)
    fit = fit_4pl(x, y)
    assert 0 <= fit.d[0] < fit.a[0] <= 1 and fit.b[0] > 0


@pytest.mark.parametrize("seed", range(6))
def test_errors_in_x_are_modelled(seed):
    # A transition 3 m wide (b = 1 per m) seen through heights with known errors of 0-3 m: the
    # plain fit sees a blur; the fit told each sample's error recovers the slope.
    rng = np.random.default_rng(seed)
    n = 20_000
    x_true, y = draw_4pl(rng, n, 0.9, 1.0, 30.0, 0.1)
    sd = rng.uniform(0.0, 3.0, n)
    x = x_true + rng.normal(0.0, 1.0, n) * sd
    plain = fit_4pl(x, y)
    eiv = fit_4pl(x, y, sd=sd)
    assert eiv.converged[0]
    assert plain.b[0] < 0.8
    assert eiv.b[0] == pytest.approx(1.0, rel=0.2)
    assert eiv.c[0] == pytest.approx(30.0, abs=0.15)
    assert eiv.a[0] == pytest.approx(0.9, abs=0.03) and eiv.d[0] == pytest.approx(0.1, abs=0.03)


def test_zero_errors_are_the_plain_fit(rng):
    x, y = draw_4pl(rng, 3000, 0.85, 0.5, 25.0, 0.1)
    plain, eiv = fit_4pl(x, y), fit_4pl(x, y, sd=np.zeros(x.size))
    np.testing.assert_allclose(eiv.params, plain.params, rtol=1e-9)


def test_c_interval_spans_a_gap_in_the_data():
    # closed signals up to 30 m and open ones from 50 m: any roof line in between fits them
    x = np.r_[np.linspace(20.0, 30.0, 200), np.linspace(50.0, 60.0, 200)]
    y = (x > 40.0).astype(float)
    fit = fit_4pl(x, y)
    lower, upper = c_interval(fit, x, y, np.zeros(x.size, dtype=int), reach=30.0)
    assert 30.0 <= fit.c[0] <= 50.0
    assert lower[0] <= 30.5 and upper[0] >= 49.5  # the gap, to the grid's 0.5 m
    assert upper[0] - lower[0] < 21.0


def test_c_interval_narrows_with_the_data():
    rng = np.random.default_rng(7)
    widths = []
    for n in (200, 20000):
        x = rng.uniform(0.0, 40.0, n)
        y = (rng.random(n) < logistic4(x, 0.9, 1.0, 20.0, 0.1)).astype(float)
        fit = fit_4pl(x, y)
        lower, upper = c_interval(fit, x, y, np.zeros(n, dtype=int))
        assert lower[0] < 20.0 < upper[0]
        widths.append(upper[0] - lower[0])
    # about 1/sqrt(n): 100 times the data, a tenth of the width (to the grid's steps)
    assert widths[1] < 0.25 * widths[0]


def test_group_range_is_the_same_on_rows_sorted_by_group(rng):
    """Rows sorted by group are reduced run by run, others one by one: the same ranges, empty
    groups included."""
    g = rng.integers(0, 40, 2000)
    g[g == 7] = 8  # group 7 is empty
    x = rng.normal(size=g.size)
    by_group = np.argsort(g, kind="stable")
    shuffled = group_range(x, g, 42)
    in_runs = group_range(x[by_group], g[by_group], 42)
    np.testing.assert_array_equal(shuffled[0], in_runs[0])
    np.testing.assert_array_equal(shuffled[1], in_runs[1])
    assert shuffled[0][7] == shuffled[1][41] == 0.0


def test_a_fit_can_say_how_it_stopped_without_changing_a_bit(rng):
    """``stops=True`` records how each group's fit stopped (a diagnostic of fits that do not
    settle) and changes nothing of the fits themselves: an ordinary group converges with a
    small last gain and nothing on a bound, a separable one ends with b on its upper bound, and
    a fit cut by its cap says how far its parameters were still moving."""
    x0, y0 = draw_4pl(rng, 3000, 0.9, 0.8, 30.0, 0.1)
    x1 = np.linspace(0.0, 10.0, 60)
    x, y = np.r_[x0, x1], np.r_[y0, x1 > 5.0].astype(float)
    g = np.r_[np.zeros(x0.size, int), np.ones(x1.size, int)]
    for cap in (200, 3):
        plain = fit_4pl(x, y, groups=g, max_iter=cap)
        told = fit_4pl(x, y, groups=g, max_iter=cap, stops=True)
        assert plain.stops is None
        for name in ("a", "b", "c", "d", "loglik", "converged", "n_iter", "separable"):
            np.testing.assert_array_equal(getattr(told, name), getattr(plain, name), name)
    told = fit_4pl(x, y, groups=g, stops=True)
    stops = told.stops
    assert told.converged[0] and stops.accepted[0] and abs(stops.gain[0]) <= 1e-9
    assert not stops.at_lower[0].any() and not stops.at_upper[0].any()
    assert told.separable[1] and stops.at_upper[1, 1]  # log b on its bound
    cut = fit_4pl(x0, y0, max_iter=4, init=[[0.6, 0.05, 20.0, 0.4]], stops=True)
    assert not cut.converged[0] and cut.n_iter[0] == 4
    assert np.abs(cut.stops.drift[0]).max() > 0.0  # still moving in its last two iterations
