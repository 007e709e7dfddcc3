"""The fast codings and sorts of a part's rows (model/parts.py) against their plain numpy and
pandas definitions: the same codes and order, so the same fits."""

import numpy as np
import pandas as pd
import pytest

from gnss_citygml.model.row_codes import building_order as _by_group
from gnss_citygml.model.row_codes import factorized as _factorized
from gnss_citygml.model.row_codes import ranks as _ranks


@pytest.mark.parametrize(
    "values",
    [
        np.array([7, 3, 7, 0, 1_000_000, 3]),  # sparse: hashed
        np.arange(50)[::-1].repeat(3),  # dense: a table
        np.array([-2, 5, -2]),  # negative: hashed
        np.array([2**40, 1]),
        np.array([], dtype=np.int64),
        np.array([0.5, 0.25, 0.5]),  # not whole numbers: hashed
        np.array([3, 1, 3], dtype=np.uint32),
    ],
)
def test_ranks_are_factorize_sorted(values):
    assert np.array_equal(_ranks(values), pd.factorize(values, sort=True)[0])


def test_by_group_is_lexsort(rng):
    """Buildings' codes of 16 bits (radix) and more, heights with many ties (a static phone
    repeats its rays' heights) and negative zero."""
    for top in (30, 2**15 + 5):
        g = rng.integers(0, top, 20_000)
        h = np.round(rng.uniform(-5, 60, g.size), 1)
        h[:50] = -0.0
        assert np.array_equal(_by_group(g, h), np.lexsort((h, g)))


@pytest.mark.parametrize("sort", [False, True])
@pytest.mark.parametrize(
    "values",
    [
        pd.Categorical(["b", "a", None, "b", "c"]),
        pd.array(["b", "a", None, "b", "c"], dtype="string[pyarrow]"),
        np.array(["b", "a", "b", "c"], dtype=object),
    ],
)
def test_factorized_is_factorize_of_the_rows_in_order(values, sort):
    by = np.array([3, 1, 0, 2, 4])[: len(values)] % len(values)
    by = np.argsort(by)  # a permutation of the rows
    codes, names = _factorized(values, by, sort=sort)
    expected, uniques = pd.factorize(np.asarray(values, dtype=object)[by], sort=sort)
    assert np.array_equal(codes, expected)
    assert list(names) == list(np.asarray(uniques, dtype=object))
