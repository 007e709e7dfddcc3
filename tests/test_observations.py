"""The observations table: schema, round trip, and one clear error per kind of bad row."""

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from gnss_citygml.errors import InputError, MissingColumnError
from gnss_citygml.observations import (
    OBSERVATION_COLUMNS,
    check_observations,
    read_observation_files,
    read_observations,
    satellites,
    write_observations,
)
from gnss_citygml.simulate import simulate

CITY = Path(__file__).resolve().parents[1] / "examples" / "city"


@pytest.fixture(scope="module")
def observations():
    return simulate("hermitage", locations="manual", seed=0, interval=60.0).observations


@pytest.mark.parametrize("suffix", [".csv", ".parquet"])
def test_round_trip(tmp_path, observations, suffix):
    path = tmp_path / f"obs{suffix}"
    write_observations(observations, path)
    back = read_observations(path)
    assert list(back.columns[: len(OBSERVATION_COLUMNS)]) == OBSERVATION_COLUMNS
    assert str(back["time_utc"].dtype) == "datetime64[ns, UTC]"
    assert back["svid"].dtype == np.int64
    assert len(back) == len(observations)
    np.testing.assert_array_equal(back["cn0"].isna(), observations["cn0"].isna())
    np.testing.assert_allclose(back["azimuth"], observations["azimuth"])
    assert (back["time_utc"] == observations["time_utc"]).all()


def test_h_is_optional(observations):
    out = check_observations(observations.drop(columns="h"))
    assert out["h"].isna().all()


def test_missing_columns_are_named(observations):
    with pytest.raises(MissingColumnError, match="'azimuth'.*'cn0'"):
        check_observations(observations.drop(columns=["azimuth", "cn0"]))


@pytest.mark.parametrize(
    ("column", "value", "message"),
    [
        ("azimuth", 360.0, "azimuth 360 outside 0..360"),
        ("azimuth", -1.0, "azimuth -1 outside"),
        ("elevation", 91.0, "elevation 91 outside -90..90"),
        ("lat", 530000.0, "lat 530000 outside"),
        ("cn0", "strong", "cn0 'strong' is not a number"),
        ("time_utc", "yesterday", "time_utc 'yesterday' is not a time"),
        ("constellation", "X", "unknown constellation 'X'"),
        ("svid", 3.5, "svid 3.5 is not a satellite number"),
        ("elevation", np.nan, "elevation is empty"),
    ],
)
def test_bad_value_names_the_csv_line(tmp_path, observations, column, value, message):
    table = observations.head(10).copy()
    table[column] = table[column].astype(object)
    table.loc[7, column] = value
    path = tmp_path / "obs.csv"
    table.to_csv(path, index=False)
    with pytest.raises(InputError) as err:
        read_observations(path)
    assert message in err.value.what
    assert err.value.where == f"{path}, line 9"  # header is line 1, row 0 is line 2
    assert err.value.fix


def test_blocked_signals_stay_empty(tmp_path, observations):
    path = tmp_path / "obs.csv"
    write_observations(observations, path)
    text = path.read_text().splitlines()
    n_empty = sum(1 for line in text[1:] if ",," in line or line.endswith(","))
    assert n_empty >= observations["cn0"].isna().sum() > 0
    assert read_observations(path)["cn0"].isna().sum() == observations["cn0"].isna().sum()


def test_other_columns_are_kept(observations):
    out = check_observations(observations.assign(note="x"))
    assert (out["note"] == "x").all()
    assert isinstance(out, pd.DataFrame)


# --- found by fuzzing (tests/fuzz/test_fuzz_observations.py) ---------------------------------


def _parquet(tmp_path, table: pd.DataFrame):
    path = tmp_path / "obs.parquet"
    table.to_parquet(path, index=False)
    return path


@pytest.mark.parametrize(
    ("column", "values", "message"),
    [
        ("time_utc", ["-5"], "time_utc '-5' is not a time"),  # year -5: beyond datetime64[ns]
        ("time_utc", [1581415200], "time_utc 1581415200 is not a time"),  # seconds? ns? ms?
        ("lat", [True], "lat True is not a number"),
        ("h", [np.inf], "h inf is not a finite number"),
        ("svid", [1e20], "svid 1e+20 is not a satellite number"),
        ("cn0", [[30.5, 31.0]], "cn0 [30.5, 31.0] is not a number"),
        ("receiver", [None], "receiver is empty"),
    ],
)
def test_values_no_observation_can_have(tmp_path, observations, column, values, message):
    table = observations.head(3).copy()
    table[column] = pd.Series(values * 3, dtype=object if column != "h" else float)
    with pytest.raises(InputError) as err:
        read_observations(_parquet(tmp_path, table))
    assert err.value.what == message
    assert err.value.where == f"{tmp_path / 'obs.parquet'}, row 0"


def test_duplicate_columns_are_named(observations):
    table = pd.concat([observations.head(3), observations.head(3)[["cn0"]]], axis=1)
    with pytest.raises(InputError, match=r"column\(s\) 'cn0' more than once"):
        check_observations(table)


def test_csv_errors_name_the_line_past_blank_lines_and_quoted_line_ends(tmp_path, observations):
    table = observations.head(6).copy()
    table["note"] = ["a", "two\nlines", "b", "c", "d", "e"]
    table.loc[4, "elevation"] = 95.0
    text = table.to_csv(index=False).splitlines(keepends=True)
    # the header, row 0, a blank line, row 1 over two lines, a line of spaces, rows 2 to 5
    path = tmp_path / "obs.csv"
    path.write_text("".join(text[:2] + ["\n"] + text[2:4] + ["   \n"] + text[4:]))
    with pytest.raises(InputError, match="elevation 95 outside") as err:
        read_observations(path)
    assert err.value.where == f"{path}, line 9"
    assert path.read_text().splitlines()[8] == text[6].rstrip("\n")  # row 4


def test_a_number_beyond_float_in_a_csv(tmp_path, observations):
    # whole numbers in the column: pandas reads them as Python ints, beyond float here
    table = observations.head(3).assign(lon=[0, int("1" * 400), 0])
    path = tmp_path / "obs.csv"
    table.to_csv(path, index=False)
    with pytest.raises(InputError) as err:
        read_observations(path)
    assert err.value.what == f"lon {'1' * 37}... is not a finite number"
    assert err.value.where == f"{path}, line 3"


def test_a_time_beyond_datetime64_in_parquet(tmp_path, observations):
    import pyarrow as pa
    import pyarrow.parquet as pq

    table = pa.Table.from_pandas(observations.head(3), preserve_index=False)
    year_1 = pa.array(np.array(["0001-01-01"] * 3, "datetime64[ms]")).cast(
        pa.timestamp("ms", tz="Europe/London")
    )
    table = table.set_column(0, "time_utc", year_1).replace_schema_metadata(None)
    pq.write_table(table, tmp_path / "t.parquet")  # no pandas metadata: read as ms, not ns
    with pytest.raises(InputError) as err:
        read_observations(tmp_path / "t.parquet")
    assert err.value.what == "time_utc 0001-01-01T00:00:00.000 is not a time"


def test_parquet_with_damaged_pandas_metadata(tmp_path, observations):
    import json

    import pyarrow as pa
    import pyarrow.parquet as pq

    table = pa.Table.from_pandas(observations.head(3), preserve_index=False)
    meta = json.loads(table.schema.metadata[b"pandas"])
    del meta["columns"][2]["numpy_type"]
    table = table.replace_schema_metadata({b"pandas": json.dumps(meta).encode()})
    pq.write_table(table, tmp_path / "m.parquet")
    with pytest.raises(InputError) as err:
        read_observations(tmp_path / "m.parquet")
    assert err.value.one_line() == (
        "cannot read the table: damaged pandas metadata (KeyError 'numpy_type') "
        f"({tmp_path / 'm.parquet'}): give a well-formed CSV (with a header row) or Parquet file"
    )


def test_a_column_name_with_a_line_end_stays_on_one_line(tmp_path, observations):
    path = tmp_path / "obs.csv"
    observations.head(3).rename(columns={"time_utc": "time\nutc"}).to_csv(path, index=False)
    with pytest.raises(MissingColumnError) as err:
        read_observations(path)
    assert "\n" not in err.value.one_line()
    assert "the table has: time\\nutc, receiver," in err.value.fix


def test_long_column_names_alike_in_their_first_40_characters_are_two_columns(observations):
    """Duplicates are found on the real names, not on the names cut short for messages."""
    stem = "multipath_indicator_from_the_receiver_raw_band_"
    table = observations.head(3).assign(**{stem + "L1": 1, stem + "L5": 5})
    assert list(check_observations(table).columns[-2:]) == [stem + "L1", stem + "L5"]


def test_satellites_name_each_rows_satellite():
    table = pd.DataFrame({"constellation": ["G", "E", "G", "R"], "svid": [5, 21, 5, 3]})
    names = satellites(table)
    assert list(names) == ["G05", "E21", "G05", "R03"]
    assert list(names.categories) == ["G05", "E21", "R03"]  # each satellite once


def _first_rows(observations, n=40):
    """The first ``n`` rows with the schema's columns only (as a user's file has them)."""
    return observations[OBSERVATION_COLUMNS].head(n).reset_index(drop=True)


def test_a_signal_received_and_blocked_is_refused_naming_both_lines(tmp_path, observations):
    table = _first_rows(observations)
    flipped = table.assign(cn0=np.where(table["cn0"].isna(), 40.0, np.nan))
    path = tmp_path / "obs.csv"
    pd.concat([table, flipped], ignore_index=True).to_csv(path, index=False)
    with pytest.raises(InputError, match="the same signal twice with different values") as caught:
        read_observations(path)
    message = caught.value.one_line()
    assert f"{path}, line 2 and {path}, line {2 + len(table)}" in message
    assert "cn0" in message and "empty" in message and "\n" not in message


@pytest.mark.parametrize(
    "change",
    [
        {"azimuth": 0.01},  # the same signal, slightly another direction
        {"elevation": -0.01},
        {"lat": 1e-6},
        {"position_sd": 1.0},
    ],
)
def test_a_signal_with_slightly_other_values_is_refused(observations, change):
    table = _first_rows(observations)
    ((column, step),) = change.items()
    other = table.iloc[[3]].copy()
    other[column] = other[column].fillna(0.0) + step
    with pytest.raises(InputError, match=f"same signal twice .* {column} "):
        check_observations(pd.concat([table, other], ignore_index=True))


def test_exact_repeats_count_once_with_a_warning(observations):
    table = _first_rows(observations)
    with pytest.warns(UserWarning, match=r"40 repeated observation\(s\) .* counted once"):
        out = check_observations(pd.concat([table, table], ignore_index=True))
    pd.testing.assert_frame_equal(out, check_observations(table))


def test_repeats_are_found_however_the_signal_is_written(observations):
    """The same signal written another way: svid as text, the constellation in lower case,
    the time in another zone or a fraction of a millisecond off; a receiver name with spaces."""
    table = _first_rows(observations, 5)
    other = table.assign(
        svid=table["svid"].astype(str),
        constellation=table["constellation"].str.lower(),
        time_utc=(table["time_utc"] + pd.Timedelta("0.3ms"))
        .dt.tz_convert("Europe/Paris")
        .map(lambda t: t.isoformat()),
        receiver=" " + table["receiver"] + " ",
    )
    with pytest.warns(UserWarning, match=r"5 repeated observation\(s\)"):
        out = check_observations(pd.concat([table, other], ignore_index=True))
    assert len(out) == 5
    flipped = other.assign(cn0=np.where(table["cn0"].isna(), 40.0, np.nan))
    with pytest.raises(InputError, match="same signal twice"):
        check_observations(pd.concat([table, flipped], ignore_index=True))


def test_repeats_across_files_read_together(tmp_path, observations):
    table = _first_rows(observations)
    a, b = tmp_path / "a.csv", tmp_path / "b.parquet"
    table.to_csv(a, index=False)
    table.iloc[10:].to_parquet(b)
    with pytest.warns(UserWarning, match=r"30 repeated .* first: .*b.parquet, row 0 repeats"):
        out = read_observation_files([a, b])
    assert len(out) == len(table)
    table.iloc[10:].assign(cn0=table["cn0"].iloc[10:].fillna(20.0) + 1).to_parquet(b)
    with pytest.raises(InputError, match=r"a.csv, line 12 and .*b.parquet, row 0"):
        read_observation_files([a, b])


@pytest.mark.parametrize(
    "change, message",
    [
        ({"azimuth": np.radians}, "every azimuth is within 0..6.28: radians"),
        ({"elevation": np.radians}, "every elevation is within \\+-1.57: radians"),
        ({"lat": np.radians, "lon": np.radians}, "every lat is within .* radians"),
        ({"cn0": lambda c: c / 10}, "every C/N0 is below 10 dB-Hz"),
        ({"cn0": lambda c: c + 100 - c.max()}, None),  # above 60 only at the top: no warning
        ({"cn0": lambda c: c * 0 + 75}, "every C/N0 is above 60 dB-Hz"),
        ({"position_sd": lambda s: s.fillna(2.0) * 100}, "every position_sd is over 100 m"),
    ],
)
def test_a_column_in_other_units_is_warned_about(observations, change, message, recwarn):
    table = observations.assign(**{c: f(observations[c]) for c, f in change.items()})
    out = check_observations(table)
    said = [str(w.message) for w in recwarn.list]
    if message is None:
        assert not said
    else:
        assert len(said) == 1 and pd.Series(said).str.contains(message).all(), said
    assert len(out) == len(table)  # a warning: the values are kept


def test_no_unit_warning_for_good_or_scant_data(observations, recwarn):
    check_observations(observations)
    # a few rows of two satellites may all be in the north-east: no evidence of radians
    few = _first_rows(observations, 6).assign(azimuth=[1.0, 2.0, 3.0, 4.0, 5.0, 6.0])
    check_observations(few)
    checked = check_observations(observations.assign(azimuth=np.radians(observations["azimuth"])))
    recwarn.clear()
    check_observations(checked)  # checked before (the pipeline checks what it is given): once
    assert not recwarn.list


def _not_utf8(values: list[str], row: int):
    """A Parquet string column whose value at ``row`` is bytes that are not UTF-8 (Parquet
    does not check its text: found by fuzzing the file's bytes)."""
    import pyarrow as pa

    raw = [v.encode() for v in values]
    raw[row] = b"\xff\xfe"
    offsets = np.cumsum([0] + [len(v) for v in raw]).astype(np.int32)
    return pa.Array.from_buffers(
        pa.string(), len(raw), [None, pa.py_buffer(offsets.tobytes()), pa.py_buffer(b"".join(raw))]
    )


@pytest.mark.parametrize("column", ["receiver", "constellation"])
def test_text_that_is_not_utf8_is_named_by_row(tmp_path, column):
    import pyarrow as pa
    import pyarrow.parquet as pq

    rows = pd.read_parquet(CITY / "observations.parquet").head(20)
    table = pa.Table.from_pandas(rows, preserve_index=False)
    at = table.schema.get_field_index(column)
    pq.write_table(
        table.set_column(at, column, _not_utf8(rows[column].tolist(), 3)), tmp_path / "o.parquet"
    )
    message = rf"the column '{column}' is not UTF-8 text \(.*o.parquet, row 3\)"
    with pytest.raises(InputError, match=message):
        read_observations(tmp_path / "o.parquet")
