"""Each row's chance that its ray crosses its building (``PositionError(crossing=True)``): the
height fits weigh a row by it, and whole-ray blame takes the footprints a ray passes near."""

import numpy as np
import pandas as pd
import pytest
from conftest import occluded_pair

from gnss_citygml import Estimator, estimate_heights
from gnss_citygml.errors import InputError
from gnss_citygml.settings import PositionError
from gnss_citygml.tiling.from_partition import partitioned_heights


def with_near_misses(table, rng, building="A", chance=0.02):
    """``table`` with a row on ``building`` for each signal that crosses only the other one:
    its ray passes near ``building``'s footprint below its roof (order -1), open or not as the
    signal is; every row given its chance of crossing (near ones ``chance``)."""
    alone = table.groupby("signal")["building"].transform("size") == 1
    near = table[alone & (table["building"] != building)].copy()
    near["building"], near["order"] = building, -1
    near["height"] = rng.uniform(5.0, 25.0, len(near))
    return pd.concat(
        [table.assign(crossing=1.0), near.assign(crossing=chance)], ignore_index=True
    ).sort_values(["signal", "order"], key=lambda s: s.where(s >= 0, 99), kind="stable")


def test_without_whole_ray_blame_the_near_misses_are_left_out(rng):
    table = with_near_misses(occluded_pair(rng), rng)
    entered = table[table["order"] >= 0]
    for estimator in (Estimator(), Estimator(method="hinge")):
        pd.testing.assert_frame_equal(
            estimate_heights(table, estimator), estimate_heights(entered, estimator)
        )


def test_a_row_weighs_by_its_chance_of_crossing(rng):
    """Rows sure not to cross their building say nothing of it; rows sure to, all they say."""
    table = occluded_pair(rng)
    bogus = table[table["building"] == "B"].assign(signal=lambda t: t["signal"] + 10**6)
    bogus = bogus.assign(height=bogus["height"] - 15.0, order=0)  # open rows far below the roof
    sure, never = table.assign(crossing=1.0), bogus.assign(crossing=0.0)
    clean = estimate_heights(sure).set_index("id")
    weighed = estimate_heights(pd.concat([sure, never], ignore_index=True)).set_index("id")
    counted = estimate_heights(pd.concat([table, bogus], ignore_index=True)).set_index("id")
    # (the signals still teach the C/N0 classifier: a shade of difference)
    assert weighed.loc["B", "height"] == pytest.approx(clean.loc["B", "height"], abs=1e-3)
    assert not counted.loc["B", "converged"] or abs(counted.loc["B", "height"] - 20.0) > 1.0


def test_whole_ray_blame_counts_a_near_miss_by_its_chance(rng):
    """Open rays that pass near the tall building A below its roof: each may well have missed
    it (2 %), and the heights are as without them; counted as crossing A surely, they would
    say that open rays pass through A below its roof, and the closed ones that B blocked."""
    table = with_near_misses(occluded_pair(rng), rng)
    ray = Estimator(blame="ray")
    near = estimate_heights(table, ray).set_index("id")
    without = estimate_heights(table[table["order"] >= 0], ray).set_index("id")
    assert near["converged"].all()
    np.testing.assert_allclose(near["height"], without["height"], atol=0.01)
    np.testing.assert_allclose(near.loc[["A", "B"], "height"], [30.0, 20.0], atol=0.1)
    sure = table.assign(crossing=1.0, order=table["order"].abs())
    counted = estimate_heights(sure, ray).set_index("id")
    assert near.loc["A", "d"] < 0.05 < 0.3 < counted.loc["A", "d"]  # open below the roof line


@pytest.mark.parametrize("bad", [1.5, -0.1, "x"])
def test_a_crossing_chance_that_is_not_one_is_refused(rng, bad):
    table = occluded_pair(rng).assign(crossing=0.5).astype({"crossing": object})
    table.loc[7, "crossing"] = bad
    with pytest.raises(InputError, match=r"crossing|not numbers") as err:
        estimate_heights(table)
    assert "rows 7" in str(err.value) or "7" in str(err.value.where)


def test_a_run_from_a_partition_refuses_the_crossing_chance(tmp_path):
    with pytest.raises(InputError, match="chance of crossing"):
        partitioned_heights(tmp_path, position_error=PositionError(crossing=True))


def test_an_order_below_zero_without_a_crossing_chance_is_refused(rng):
    """A near miss (order -1) only means something with its chance of crossing: a table that
    numbers a ray's footprints from -1 is an error that names the rows, not rows left out."""
    table = occluded_pair(rng)
    table.loc[[3, 5], "order"] = -1
    for estimator in (Estimator(), Estimator(blame="ray")):
        with pytest.raises(InputError, match="order below 0") as err:
            estimate_heights(table, estimator)
        assert "rows 3, 5" in str(err.value.where)
