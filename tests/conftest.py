"""Shared fixtures: small datasets drawn from known curves and simulated scenes."""

import numpy as np
import pandas as pd
import pytest

from gnss_citygml.model.fourpl import logistic4


def draw_4pl(rng, n, a, b, c, d, lo=0.0, hi=60.0):
    """Heights uniform in [lo, hi] and labels drawn from a known 4PL."""
    x = rng.uniform(lo, hi, n)
    y = rng.random(n) < logistic4(x, a, b, c, d)
    return x, y


def synthetic_intersections(rng, truth=45.0, n=4000, building="b1", blocked=0.4, noise=1.0):
    """A building crossed at heights 20-80 m: open signals strong, closed weak or blocked."""
    h = rng.uniform(20.0, 80.0, n)
    is_open = h + rng.normal(0.0, noise, n) > truth
    cn0 = np.where(is_open, rng.normal(40.0, 4.0, n), rng.normal(25.0, 5.0, n))
    cn0[~is_open & (rng.random(n) < blocked)] = np.nan
    cn0[cn0 < 12.0] = np.nan
    return pd.DataFrame({"building": building, "height": h, "cn0": cn0})


@pytest.fixture
def rng():
    return np.random.default_rng(12345)
