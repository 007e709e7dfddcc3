"""Fuzzing the observations table reader (:func:`gnss_citygml.observations.read_observations`).

The seeds are written by the project's own code (:func:`write_observations`): 320 rows of the
bundled example city's observations (eight receivers, four constellations, blocked signals, one
receiver with a height) as CSV and as Parquet. The CSV and Parquet bytes are mutated, and so
are the table's values and types before it is written as Parquet: a column of strings where
numbers are meant, NaN and infinities, an azimuth of 1e308, nulls, other Arrow types, an empty
table, duplicate, missing and renamed columns, nested columns, times out of range.

Every case must end as a table that keeps :func:`check_observations`' promises or as one
:class:`GnssCityGMLError` line.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq
import pytest
from hypothesis import event, given
from hypothesis import strategies as st

from gnss_citygml.observations import (
    CONSTELLATIONS,
    OBSERVATION_COLUMNS,
    read_observations,
    write_observations,
)

from .conftest import mutated

CITY = Path(__file__).resolve().parents[2] / "examples" / "city"
ROWS = 320


def _seed_table() -> pd.DataFrame:
    """320 rows of the example city: 40 from each receiver, heights given for one of them."""
    table = pd.read_parquet(CITY / "observations.parquet")
    per_receiver = ROWS // table["receiver"].nunique()
    rows = table.groupby("receiver", sort=True).head(per_receiver).reset_index(drop=True)
    rows.loc[rows["receiver"] == rows["receiver"].iloc[0], "h"] = 71.25
    assert len(rows) == ROWS and rows["cn0"].isna().any()
    return rows


def _written(table: pd.DataFrame, suffix: str) -> bytes:
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / f"seed{suffix}"
        write_observations(table, path, overwrite=False)
        assert len(read_observations(path)) == len(table)
        return path.read_bytes()


SEED = _seed_table()
CSV_SEED = _written(SEED, ".csv")
PARQUET_SEED = _written(SEED, ".parquet")
SMALL = pq.read_table(pa.BufferReader(_written(SEED.iloc[::16], ".parquet")))  # 20 rows


@pytest.fixture
def folder():
    """One folder per test (hypothesis runs all the examples of a test within one call)."""
    with tempfile.TemporaryDirectory(prefix="fuzz-observations-") as name:
        yield Path(name)


def _check(table) -> None:
    """A table read keeps the schema's promises."""
    if table is None:
        return
    assert list(table.columns[: len(OBSERVATION_COLUMNS)]) == OBSERVATION_COLUMNS
    assert table.columns.is_unique
    assert str(table["time_utc"].dtype) == "datetime64[ns, UTC]"
    assert not table["time_utc"].isna().any()
    for column, (lo, hi) in {
        "lat": (-90, 90),
        "lon": (-180, 180),
        "azimuth": (0, 360),
        "elevation": (-90, 90),
    }.items():
        values = table[column].to_numpy(dtype=float)
        assert ((values >= lo) & (values <= hi)).all(), column
    cn0 = table["cn0"].to_numpy(dtype=float)
    assert (np.isnan(cn0) | ((cn0 >= 0) & (cn0 <= 100))).all()
    h = table["h"].to_numpy(dtype=float)
    assert (np.isnan(h) | np.isfinite(h)).all()
    assert table["svid"].dtype == np.int64 and (table["svid"] >= 0).all()
    assert set(table["constellation"]) <= set(CONSTELLATIONS)


def _write(folder: Path, name: str, data: bytes) -> Path:
    path = folder / name
    path.write_bytes(data)
    return path


def _outcome(result, what: str = ""):
    """``result``, counted in hypothesis' statistics as a result or a one-line error."""
    event(f"{what}{'result' if result is not None else 'one-line error'}")
    return result


@given(data=mutated(CSV_SEED))
def test_csv(data, folder, clean):
    _check(_outcome(clean(read_observations, _write(folder, "observations.csv", data))))


@given(data=mutated(PARQUET_SEED))
def test_parquet_bytes(data, folder, clean):
    _check(_outcome(clean(read_observations, _write(folder, "observations.parquet", data))))


# --- Parquet: the table's values and types mutated before it is written ----------------------

SPECIAL = [np.nan, np.inf, -np.inf, 1e308, -1e308, 0.0, -0.0, 360.0, 90.0000001, 5e-324, 2**63]
TYPES = [
    pa.int8(),
    pa.int64(),
    pa.uint64(),
    pa.float32(),
    pa.float64(),
    pa.string(),
    pa.large_string(),
    pa.bool_(),
    pa.binary(),
    pa.date32(),
    pa.timestamp("s"),
    pa.timestamp("ms", tz="Europe/London"),
    pa.timestamp("ns"),
    pa.dictionary(pa.int32(), pa.string()),
    pa.null(),
]
WORDS = ["", " ", "abc", "nan", "1e308", "-5", "2020-13-45T25:61:61Z", "G", "x" * 10_000, "\x00"]
TIMES = [np.datetime64("0001-01-01", "us"), np.datetime64("9999-12-31", "us")]


def _replace(table: pa.Table, i: int, column: pa.Array | pa.ChunkedArray, name=None) -> pa.Table:
    return table.set_column(i, table.column_names[i] if name is None else name, column)


@st.composite
def mutated_table(draw, seed: pa.Table, max_ops: int = 4) -> pa.Table:
    """A strategy of Arrow tables made from ``seed`` by 1..max_ops edits of values and types."""
    table = seed
    for _ in range(draw(st.integers(1, max_ops))):
        n, width = table.num_rows, table.num_columns
        op = draw(
            st.sampled_from(
                ["strings", "special", "cast", "nulls", "rows", "duplicate", "rename", "drop"]
                + ["nested", "times", "reorder"]
            )
        )
        i = draw(st.integers(0, width - 1)) if width else None
        if op == "strings" and width:
            words = st.lists(st.sampled_from(WORDS), min_size=n, max_size=n)
            table = _replace(table, i, pa.array(draw(words), pa.string()))
        elif op == "special" and width:
            values = table.column(i).to_pylist()
            for k in draw(st.lists(st.integers(0, max(n - 1, 0)), max_size=3)) if n else []:
                values[k] = draw(st.sampled_from(SPECIAL))
            try:
                table = _replace(table, i, pa.array(values, pa.float64()))
            except (pa.ArrowInvalid, pa.ArrowTypeError):
                table = _replace(table, i, pa.array([str(v) for v in values]))
        elif op == "cast" and width:
            try:
                table = _replace(table, i, pc.cast(table.column(i), draw(st.sampled_from(TYPES))))
            except (pa.ArrowInvalid, pa.ArrowNotImplementedError, pa.ArrowTypeError):
                pass  # a cast Arrow refuses: the value cannot be written that way either
        elif op == "nulls" and width:
            mask = pa.array(draw(st.lists(st.booleans(), min_size=n, max_size=n)))
            nulls = pa.nulls(n, table.column(i).type)
            table = _replace(table, i, pc.if_else(mask, nulls, table.column(i)))
        elif op == "rows":
            start = draw(st.integers(0, n))
            table = table.slice(start, draw(st.integers(0, n - start)))
        elif op == "duplicate" and width:
            j = draw(st.integers(0, width - 1))
            table = table.append_column(table.column_names[i], table.column(j))
        elif op == "rename" and width:
            names = table.column_names + ["", "x" * 300, "time_utc ", "Lat"]
            table = _replace(table, i, table.column(i), name=draw(st.sampled_from(names)))
        elif op == "drop" and width:
            table = table.remove_column(i)
        elif op == "nested" and width:
            lists = pa.array([[1.0, 2.0]] * n, pa.list_(pa.float64()))
            structs = pa.array([{"a": 1}] * n)
            table = _replace(table, i, draw(st.sampled_from([lists, structs])))
        elif op == "times" and width and n:
            values = np.array([draw(st.sampled_from(TIMES)) for _ in range(n)], "datetime64[us]")
            table = _replace(table, i, pa.array(values).cast(pa.timestamp("us", tz="UTC")))
        elif op == "reorder" and width:
            table = table.select(draw(st.permutations(range(width))))
    return table.replace_schema_metadata(None)  # no pandas metadata to undo the edits


@given(table=mutated_table(SMALL))
def test_parquet_values(table, folder, clean):
    path = folder / "observations.parquet"
    pq.write_table(table, path)
    _check(_outcome(clean(read_observations, path)))
