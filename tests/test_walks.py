"""A walk's windows hold each other's shifts (:mod:`gnss_citygml.calibrate.walks`): the prior's
scale and correlation time come from the shadows themselves, and a window that cannot tell where
it was takes its neighbours' shift."""

import numpy as np
import pandas as pd
import pytest

from gnss_citygml.calibrate import walks
from gnss_citygml.calibrate.walks import walk_offsets
from gnss_citygml.recordings import recording_windows, window_walks

AXIS = np.linspace(-1.0, 1.0, 11)
EAST, NORTH = (a.ravel() for a in np.meshgrid(AXIS, AXIS))  # north-major, as the shadows'


def _score(shift, half, sd):
    """Each window's log-likelihood on its grid: Gaussian about its ``shift`` (m), ``sd`` m
    per axis (inf: that axis says nothing)."""
    de = half[:, None] * EAST - shift[:, :1]
    dn = half[:, None] * NORTH - shift[:, 1:]
    return -0.5 * ((de / sd[0]) ** 2 + (dn / sd[1]) ** 2)


def _alone(score, half, sd):
    """Each window's posterior mean with its own prior only."""
    log = score - 0.5 * (EAST**2 + NORTH**2) * (half / sd)[:, None] ** 2
    p = np.exp(log - log.max(axis=1, keepdims=True))
    p /= p.sum(axis=1, keepdims=True)
    return np.column_stack([half * (p @ EAST), half * (p @ NORTH)])


def test_with_no_correlation_each_window_stands_alone(monkeypatch):
    monkeypatch.setattr(walks, "TAUS", (0.0,))
    monkeypatch.setattr(walks, "SCALES", (1.0,))
    rng = np.random.default_rng(1)
    n = 40
    half, sd = np.full(n, 10.0), rng.uniform(2.0, 5.0, n)
    score = _score(rng.normal(0.0, 4.0, (n, 2)), half, (3.0, 3.0))
    walk, time = np.repeat([0, 1], n // 2), np.tile(np.arange(n // 2) * 10.0, 2)
    found, chosen = walk_offsets(score, AXIS, half, sd, walk, time)
    np.testing.assert_allclose(found, _alone(score, half, sd), atol=1e-9)
    assert chosen["tau"] == 0.0 and chosen["scale"] == 1.0


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_walks_scale_and_memory_are_told_by_the_shadows(seed):
    """Shifts that drift (correlated over 30 s) and are twice what the phones claim: the
    evidence picks a wider prior and a memory, and the walk places the windows better than
    each alone."""
    rng = np.random.default_rng(seed)
    n_walks, n = 20, 30
    claimed = 3.0
    rho = np.exp(-10.0 / 30.0)
    shift = np.zeros((n_walks, n, 2))
    shift[:, 0] = rng.normal(0.0, 2 * claimed, (n_walks, 2))
    for k in range(1, n):
        step = rng.normal(0.0, 2 * claimed * np.sqrt(1 - rho**2), (n_walks, 2))
        shift[:, k] = rho * shift[:, k - 1] + step
    shift = shift.reshape(-1, 2)
    half, sd = np.full(len(shift), 2.5 * claimed), np.full(len(shift), claimed)
    seen = shift + rng.normal(0.0, 4.0, shift.shape)  # what the shadows say, 4 m off
    score = _score(seen, half, (4.0, 4.0))
    walk, time = np.repeat(np.arange(n_walks), n), np.tile(np.arange(n) * 10.0, n_walks)
    found, chosen = walk_offsets(score, AXIS, half, sd, walk, time)
    assert chosen["scale"] > 1.0 and chosen["tau"] > 0.0
    alone = _alone(score, half, sd)
    inside = np.all(np.abs(shift) < half[:, None], axis=1)  # the grid's reach
    error = np.sqrt(np.mean((found - shift)[inside] ** 2))
    assert error < 0.95 * np.sqrt(np.mean((alone - shift)[inside] ** 2))


def test_a_window_that_cannot_tell_takes_its_neighbours_shift(monkeypatch):
    """Along a street the shadows say nothing of the shift along it; the corner the walk turns
    at says it. The same walker's windows before the corner take it, fading with time; another
    walker at the same time does not."""
    monkeypatch.setattr(walks, "TAUS", (100.0,))
    n = 8
    half, sd = np.full(2 * n, 10.0), np.full(2 * n, 4.0)
    shift = np.tile([6.0, 0.0], (2 * n, 1))
    street = _score(shift, half, (np.inf, 1.0))
    corner = _score(shift, half, (1.0, 1.0))
    score = np.where(np.arange(2 * n)[:, None] == n - 1, corner, street)
    walk, time = np.repeat([0, 1], n), np.tile(np.arange(n) * 10.0, 2)
    found = walk_offsets(score, AXIS, half, sd, walk, time)[0]
    assert found[n - 1, 0] == pytest.approx(6.0, abs=1.0)
    assert np.all(found[: n - 1, 0] > 2.0)  # carried back along the street
    assert np.all(np.diff(found[:n, 0]) > 0.0)  # the further from the corner, the less
    np.testing.assert_allclose(found[n:, 0], 0.0, atol=1e-9)  # the other walker's own
    np.testing.assert_allclose(found[:, 1], 0.0, atol=0.2)


def test_windows_given_in_any_order_are_walked_in_time():
    rng = np.random.default_rng(3)
    n = 24
    half, sd = np.full(n, 10.0), np.full(n, 4.0)
    score = _score(rng.normal(0.0, 5.0, (n, 2)), half, (2.0, 2.0))
    walk, time = np.repeat([0, 1, 2], n // 3), np.tile(np.arange(n // 3) * 10.0, 3)
    order = rng.permutation(n)
    found = walk_offsets(score, AXIS, half, sd, walk, time)[0]
    shuffled = walk_offsets(score[order], AXIS, half[order], sd[order], walk[order], time[order])
    np.testing.assert_allclose(shuffled[0], found[order], atol=1e-12)


def test_each_window_is_placed_on_its_walk_in_time_whatever_the_time_zone():
    times = ["2020-06-01T10:00:00Z", "2020-06-01T10:00:04Z", "2020-06-01T10:00:12Z"]
    rows = pd.DataFrame({"receiver": ["a", "a", "a", "b"], "time_utc": times + [times[0]]})
    unit = recording_windows(rows, 10.0)
    walk, time = window_walks(rows, unit)
    assert walk.tolist() == [0, 0, 1] and time.tolist() == [2.0, 12.0, 0.0]
    local = rows.assign(time_utc=pd.to_datetime(rows["time_utc"]).dt.tz_convert("Europe/London"))
    np.testing.assert_array_equal(window_walks(local, unit)[1], time)
