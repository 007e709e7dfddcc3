"""Fits in threads, a run of whole groups each: the bits of one thread."""

import numpy as np
import pytest
from conftest import draw_4pl

from gnss_citygml import threads
from gnss_citygml.model import fourpl, group_threads
from gnss_citygml.model.fourpl import fit_4pl
from gnss_citygml.model.interval import c_interval


def _groups(rng, n_groups=40):
    xs, ys, gs = [], [], []
    for k in range(n_groups):
        if k % 7 == 3:
            continue  # an empty group now and then, at a cut too
        x, y = draw_4pl(rng, int(rng.integers(2, 900)), 0.9, rng.uniform(0.2, 4), 30.0, 0.1)
        xs.append(x)
        ys.append(y)
        gs.append(np.full(x.size, k))
    return np.concatenate(xs), np.concatenate(ys), np.concatenate(gs)


@pytest.mark.parametrize("n_threads", ["2", "3", "8"])
def test_a_fit_in_threads_is_one_threads_bit_for_bit(rng, monkeypatch, n_threads):
    x, y, g = _groups(rng)
    order = rng.permutation(x.size)  # fit_4pl sorts by group itself
    x, y, g = x[order], y[order], g[order]
    sd, init = rng.uniform(0, 2, x.size), np.tile([0.8, 1.0, 29.0, 0.1], (40, 1))

    def fit():
        result = fit_4pl(x, y, groups=g, n_groups=40, sd=sd, init=init)
        return result, c_interval(result, x, y, g, sd=sd)

    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    one, one_range = fit()
    monkeypatch.setenv("OMP_NUM_THREADS", n_threads)
    monkeypatch.setattr(group_threads, "MIN_ROWS", 100)  # threads even for these few samples
    runs = []  # the runs fit_4pl and c_interval cut the groups into

    def counted(g, n, work):
        return group_threads.by_groups(g, n, lambda *run: runs.append(run) or work(*run))

    monkeypatch.setattr(fourpl, "by_groups", counted)
    many, many_range = fit()
    assert len(runs) > 2
    for name in ("a", "b", "c", "d", "loglik", "converged", "n_iter", "separable"):
        assert np.array_equal(getattr(many, name), getattr(one, name), equal_nan=True), name
    assert all(
        np.array_equal(m, o, equal_nan=True) for m, o in zip(many_range, one_range, strict=True)
    )
    assert np.isnan(many.c[3]) and not many.converged[3]


@pytest.mark.parametrize(("value", "expected"), [("3", 3), (" 2 ", 2), ("0", None), ("x", None)])
def test_threads_follow_omp_num_threads(monkeypatch, value, expected):
    monkeypatch.setenv("OMP_NUM_THREADS", value)
    n = threads.threads()
    assert n == expected if expected is not None else n >= 1
