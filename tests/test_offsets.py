"""Each recording's C/N0 offset learnt from its open sky (issue 27: phones differ)."""

import numpy as np
import pandas as pd
import pytest

from gnss_citygml import Estimator, estimate_heights
from gnss_citygml.model.offsets import (
    CN0_BIN,
    PRIOR_SIGNALS,
    SkyCounts,
    _weighted_medians,
    cn0_offsets,
    levelled,
    sky_counts,
)
from gnss_citygml.pipeline import intersections, open_sky
from gnss_citygml.settings import PositionError
from gnss_citygml.simulate import simulate
from gnss_citygml.simulate.scenes import street_scene
from gnss_citygml.simulate.signals import SignalModel


def _sky(offsets: dict[str, float], n: int, seed: int = 0) -> pd.DataFrame:
    """Open signals of recordings with the given offsets, on an antenna-gain slope, with
    fading and a tail of signals the map misses (trees): 10 % 12 dB weaker."""
    rng = np.random.default_rng(seed)
    rows = []
    for name, offset in offsets.items():
        elevation = rng.uniform(10.0, 85.0, n)
        cn0 = 30.0 + 12.0 * elevation / 90.0 + offset + rng.normal(0.0, 3.0, n)
        cn0[rng.random(n) < 0.1] -= 12.0
        rows.append(pd.DataFrame({"receiver": name, "elevation": elevation, "cn0": cn0}))
    return pd.concat(rows, ignore_index=True)


def test_each_recording_offset_is_found_against_the_others():
    found = cn0_offsets(_sky({"a": 3.0, "b": -2.0, "c": 0.0, "d": -1.0}, 2000))
    assert found.to_dict() == pytest.approx({"a": 3.0, "b": -2.0, "c": 0.0, "d": -1.0}, abs=0.3)


def test_a_recording_with_few_open_signals_is_moved_little():
    """A handful of signals say little: the offset is shrunk towards the others' level."""
    sky = _sky({"a": 0.0, "b": 0.0}, 2000)
    few = _sky({"c": 6.0}, 5, seed=1)
    found = cn0_offsets(pd.concat([sky, few], ignore_index=True))
    assert 0.0 < found["c"] < 6.0 * 5 / (5 + PRIOR_SIGNALS) + 1.0


def test_signals_not_received_and_recordings_without_open_sky():
    """Unreceived signals (NaN) say nothing of the level; a recording with none received
    keeps 0; a single signal cannot fit the elevation line: every offset 0."""
    sky = _sky({"a": 2.0, "b": -2.0}, 1000)
    blind = pd.DataFrame({"receiver": ["c"] * 3, "elevation": [20.0, 40.0, 60.0]})
    blind["cn0"] = np.nan
    found = cn0_offsets(pd.concat([sky, blind], ignore_index=True))
    assert found["c"] == 0.0 and found["a"] - found["b"] == pytest.approx(4.0, abs=0.4)
    one = cn0_offsets(sky.iloc[:1])
    assert one.to_dict() == {"a": 0.0}


def test_phones_of_a_simulated_street_are_levelled():
    """Phones recorded on a street (the simulator's own physics: reflections, tracking, the
    map's open sky): one phone 8 dB weaker (a body) is found about 8 dB below the others."""
    scene = street_scene(np.random.default_rng(7), 24.0, 8.0, walkers=3)
    phones = [SignalModel(device_sd=0.0, session_sd=0.0)] * 2
    phones.append(SignalModel(device_sd=0.0, session_sd=0.0, body_loss=8.0))
    sim = simulate(scene, interval=10.0, seed=2, physics=phones)
    rays = sim.rays
    cast = intersections(rays, sim.buildings, position_error=PositionError())
    found = cn0_offsets(open_sky(rays, cast))
    weak = scene.sessions[2].receiver
    others = found.drop(weak)
    assert others.mean() - found[weak] == pytest.approx(8.0, abs=1.5)
    assert np.ptp(others.to_numpy()) < 1.0


def test_missing_columns_and_unknown_elevations():
    """A table without the columns is refused by name; a signal without an elevation says
    nothing of its phone's level (it is not taken as one at the horizon)."""
    from gnss_citygml.errors import MissingColumnError

    with pytest.raises(MissingColumnError, match="elevation"):
        cn0_offsets(pd.DataFrame({"receiver": ["a"], "cn0": [40.0]}))
    sky = _sky({"a": 0.0, "b": 0.0}, 1000)
    blind = pd.DataFrame({"receiver": ["b"] * 300, "elevation": np.nan, "cn0": 10.0})
    found = cn0_offsets(pd.concat([sky, blind], ignore_index=True))
    assert abs(found["a"] - found["b"]) < 0.4


def test_counts_of_parts_add_up_to_the_whole_and_give_its_offsets():
    """A run in tiles counts its signals by parts: the parts' counts add up to the whole's,
    all less some leaves the rest, and the offsets are the whole's, bit for bit."""
    sky = _sky({"a": 2.0, "b": -1.0, "c": 0.0}, 700)
    cut = np.random.default_rng(3).random(len(sky)) < 0.4
    whole, some, rest = (sky_counts(t) for t in (sky, sky[cut], sky[~cut]))
    pd.testing.assert_series_equal((some + rest).counts, whole.counts)
    pd.testing.assert_series_equal((whole - some).counts, rest.counts)
    pd.testing.assert_series_equal((some + rest).offsets(), whole.offsets())
    assert (SkyCounts.empty() + whole).offsets().equals(whole.offsets())


def test_binned_medians_are_the_medians_of_the_signals():
    """The offsets come from counts in bins of CN0_BIN: each phone's median residual is the
    median of its signals, not of its bins (a bin of many signals weighs as many)."""
    rng = np.random.default_rng(5)
    value = np.round(rng.normal(0.0, 3.0, 501) / CN0_BIN) * CN0_BIN
    code = rng.integers(0, 3, value.size)
    bins = pd.DataFrame({"v": value, "g": code}).value_counts().sort_index()
    v, g = (bins.index.get_level_values(k).to_numpy() for k in ("v", "g"))
    found = _weighted_medians(v, bins.to_numpy(dtype=float), g, 3)
    for k in range(3):
        mine = np.sort(value[code == k])
        assert found[k] == mine[(mine.size - 1) // 2]  # the lower middle one


def test_levelling_is_a_run_on_the_levelled_signals():
    """``Estimator(level_phones=True)`` (the default) gives the heights of the signals with
    each phone's C/N0 less its open-sky offset; ``False``, those of the signals as recorded;
    and without an open sky there is nothing to level by."""
    scene = street_scene(np.random.default_rng(7), 24.0, 8.0, walkers=3)
    phones = [SignalModel(device_sd=0.0, session_sd=0.0)] * 2
    phones.append(SignalModel(device_sd=0.0, session_sd=0.0, body_loss=8.0))
    sim = simulate(scene, interval=5.0, seed=2, physics=phones)
    cast = intersections(sim.rays, sim.buildings, position_error=PositionError())
    sky = open_sky(sim.rays, cast)
    offsets = sky_counts(sky).offsets()
    by_hand = estimate_heights(levelled(cast, offsets), Estimator(level_phones=False))
    levelled_run = estimate_heights(cast, Estimator(), open_sky=sky)
    pd.testing.assert_frame_equal(levelled_run, by_hand)
    as_recorded = estimate_heights(cast, Estimator(level_phones=False), open_sky=sky)
    pd.testing.assert_frame_equal(estimate_heights(cast), as_recorded)
    assert not as_recorded.equals(levelled_run)


def test_a_signal_without_a_phone_name_is_neither_counted_nor_levelled():
    """A row whose ``receiver`` is empty belongs to no phone: it says nothing of any phone's
    level (it used to be counted as the last phone's) and keeps its C/N0."""
    sky = _sky({"a": 3.0, "b": -3.0}, 800)
    nameless = pd.DataFrame({"receiver": [None] * 400, "elevation": 45.0, "cn0": 5.0})
    found = sky_counts(pd.concat([sky, nameless], ignore_index=True)).offsets()
    assert found.to_dict() == pytest.approx(sky_counts(sky).offsets().to_dict())
    kept = levelled(nameless, found)
    assert (kept["cn0"] == 5.0).all()
