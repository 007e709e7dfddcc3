import io
import re
import warnings

import numpy as np
import pandas as pd
import pytest

from gnss_citygml.errors import InputError, MissingColumnError
from gnss_citygml.gnss.gnsslogger import GnssLog, read_gnsslogger

LONDON = "london_ucl_2020-02-11_SM-G973F_gnss_log.txt"
DEMO_JUNE = "google_demo_pseudoranges_log_2016_06_30_21_26_07.txt"
DEMO_AUG = "google_demo_pseudoranges_log_2016_08_22_14_45_50.txt"
PIXEL4 = "gsdc2021_mtv_2020-05-14_Pixel4_GnssLog_excerpt.txt"
PIXEL7PRO = "gsdc2023_2023-09-07_Pixel7Pro_gnss_log_excerpt.txt"
STANFORD = "stanford_2023-11-07_Pixel7_gnss_log.txt"
NO_LOCK = "no code lock (State)"
INCOMPLETE = "incomplete epoch (a row of it is bad, cut off or missing)"
FCN = "GLONASS slot unknown (Svid is a frequency channel)"
#: The mark of a test of the London log: too large for tests/data, only in the shared folder.
SHARED = pytest.mark.shared_data

# Figures from ../shared/data/gnss/README.md (Raw rows per constellation before any filtering,
# epochs, satellites, Fix rows per provider, first and last epoch in UTC), and the rows this
# reader keeps and drops. London: the README's BeiDou 2239 includes the cut-off last line, and
# the 19 locked rows of the epoch that line belongs to are dropped with it.
EXPECTED = {
    DEMO_JUNE: dict(
        version="1.4.0.0",
        rows={"G": 1379},
        epochs=223,
        satellites=9,
        fixes={"gps": 216},
        span=("2016-06-30 21:26:08", "2016-06-30 21:29:50"),
        kept=1379,
        dropped={},
    ),
    DEMO_AUG: dict(
        version="1.4.0.0",
        rows={"G": 2484, "R": 1833, "E": 517, "C": 207},
        epochs=207,
        satellites=26,
        fixes={"gps": 207},
        span=("2016-08-22 21:45:55", "2016-08-22 21:49:21"),
        kept=3110,
        dropped={FCN: 1637, NO_LOCK: 294},
    ),
    PIXEL4: dict(
        version="2.0.4.2",
        rows={"G": 10, "R": 7, "E": 12},
        epochs=1,
        satellites=21,
        fixes={"flp": 2, "gps": 2},  # + the NLP row with the corrupted altitude
        span=("2020-05-14 22:10:45", "2020-05-14 22:10:45"),
        kept=29,
        dropped={},
    ),
    PIXEL7PRO: dict(
        version="Not Available",
        rows={"G": 90, "E": 50, "R": 30, "J": 10},
        epochs=5,
        satellites=22,
        fixes={},
        span=("2023-09-07 18:59:58", "2023-09-07 19:00:02"),
        kept=170,
        dropped={NO_LOCK: 10},
    ),
    LONDON: dict(
        version="2.0.0.1",
        rows={"G": 2800, "R": 2520, "C": 2238, "E": 2232},
        epochs=280,
        satellites=35,
        fixes={"gps": 280},
        span=("2020-02-11 08:49:28", "2020-02-11 08:54:07"),
        kept=6032,
        dropped={NO_LOCK: 3739, INCOMPLETE: 19},
    ),
    STANFORD: dict(
        version="3.0.6.4",
        rows={"G": 496, "R": 186, "E": 248},
        epochs=31,
        satellites=20,
        fixes={"gps": 94, "flp": 95, "nlp": 54},
        span=("2023-11-07 23:43:14", "2023-11-07 23:52:14"),
        kept=897,
        dropped={NO_LOCK: 33},
    ),
}


def _read(path, **kwargs) -> GnssLog:
    """Read a log, ignoring the warnings of the known defects of the staged files."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return read_gnsslogger(path, **kwargs)


def _raw_table(path) -> pd.DataFrame:
    """The complete Raw rows of a log read with plain pandas: the oracle for the reader."""
    lines = path.read_text().splitlines()
    header = next(line for line in lines if line.startswith("# Raw,"))
    names = [name.strip() for name in header[2:].split(",")]
    rows = [line for line in lines if line.startswith("Raw,") and line.count(",") == len(names) - 1]
    table = pd.read_csv(io.StringIO("\n".join(rows)), header=None)
    table.columns = [f"{name}.{i}" if name in names[:i] else name for i, name in enumerate(names)]
    return table


@pytest.fixture
def gnss_dir(reference_data):
    return reference_data / "gnss"


@SHARED
def test_every_staged_log_has_expected_figures(gnss_dir):
    assert {p.name for p in gnss_dir.glob("*.txt")} == set(EXPECTED)


@pytest.mark.parametrize(
    "name", [pytest.param(n, marks=SHARED) if n == LONDON else n for n in sorted(EXPECTED)]
)
def test_log_matches_readme(gnss_dir, name):
    want = EXPECTED[name]
    log = _read(gnss_dir / name, lenient=True)
    every = pd.concat([log.raw, log.dropped])
    assert log.version == want["version"]
    assert every.groupby("constellation").size().to_dict() == want["rows"]
    assert every["time_utc"].nunique() == want["epochs"]
    assert len(every.groupby(["constellation", "svid"])) == want["satellites"]
    assert log.fixes["provider"].value_counts().to_dict() == want["fixes"]
    assert len(log.raw) == want["kept"]
    assert log.dropped["reason"].value_counts().to_dict() == want["dropped"]
    first, last = (pd.Timestamp(t, tz="UTC") for t in want["span"])
    assert abs(every["time_utc"].min() - first) < pd.Timedelta("1s")
    assert abs(every["time_utc"].max() - last) < pd.Timedelta("1s")
    assert str(log.raw["time_utc"].dtype) == "datetime64[ns, UTC]"
    assert log.raw["cn0"].between(5, 60).all()
    assert set(log.raw["band"]) <= {"L1", "L5"}


@pytest.mark.parametrize("name", [PIXEL4, PIXEL7PRO, STANFORD])
def test_epochs_match_utc_time_millis(gnss_dir, name):
    # v2+ logs: GnssLogger's own UTC (ms, truncated) of every Raw row
    log = _read(gnss_dir / name, lenient=True)
    every = pd.concat([log.raw, log.dropped])
    own = pd.to_datetime(np.unique(_raw_table(gnss_dir / name)["utcTimeMillis"]), unit="ms")
    ours = pd.DatetimeIndex(every["time_utc"].unique()).sort_values().tz_localize(None)
    assert len(ours) == len(own)
    assert np.abs(ours - own).max() < pd.Timedelta("1ms")


@pytest.mark.parametrize(
    ("name", "leap"), [(DEMO_AUG, 17), pytest.param(LONDON, 18, marks=SHARED), (STANFORD, 18)]
)
def test_epochs_match_gps_fix_times_with_leap_seconds(gnss_dir, name, leap):
    # logs whose Fix time is that of the epoch: a wrong leap second would be 1 s off
    log = _read(gnss_dir / name)
    fixes = log.fixes[log.fixes["provider"] == "gps"]["time_utc"].to_numpy()
    epochs = log.epochs.to_numpy()
    nearest = np.abs(epochs[:, None] - fixes[None, :]).min(axis=1)
    assert nearest.max() < np.timedelta64(2, "ms")
    # and the offset from GPS time is the leap second of the date, to the nanosecond
    row = _raw_table(gnss_dir / name).iloc[0]
    gps_ns = int(row["TimeNanos"]) - int(row["FullBiasNanos"]) - round(row["BiasNanos"])
    gps = pd.Timestamp("1980-01-06", tz="UTC") + pd.Timedelta(gps_ns, unit="ns")
    assert gps - log.epochs[0] == pd.Timedelta(seconds=leap)


def test_epochs_of_the_june_2016_demo_within_a_second_of_its_fixes(gnss_dir):
    # this 1.4 log stamps fixes at whole seconds, epochs at .4 s
    log = _read(gnss_dir / DEMO_JUNE)
    fixes = log.fixes["time_utc"].to_numpy()
    nearest = np.abs(log.epochs.to_numpy()[:, None] - fixes[None, :]).min(axis=1)
    assert nearest.max() < np.timedelta64(1, "s")


@SHARED
def test_state_rule_matches_the_receivers_time_uncertainty(gnss_dir):
    # rows kept for code lock are exactly those with a known received time (< 1 s uncertainty)
    for name in (LONDON, STANFORD, PIXEL7PRO):
        table = _raw_table(gnss_dir / name)
        known = table["ReceivedSvTimeUncertaintyNanos"] < 1e9
        log = _read(gnss_dir / name)
        assert known.sum() == len(log.raw) + (log.dropped["reason"] == INCOMPLETE).sum()
        assert table.loc[known, "ReceivedSvTimeUncertaintyNanos"].max() < 1000


def test_l1_and_l5_kept_apart_in_the_pixel4_excerpt(gnss_dir):
    log = _read(gnss_dir / PIXEL4, lenient=True)
    bands = log.raw.groupby(["constellation", "band"]).size().to_dict()
    assert bands == {("E", "L1"): 6, ("E", "L5"): 6, ("G", "L1"): 8, ("G", "L5"): 2, ("R", "L1"): 7}
    # the same satellite on two bands: two signals with their own C/N0
    e27 = log.raw[(log.raw["constellation"] == "E") & (log.raw["svid"] == 27)]
    assert sorted(e27["band"]) == ["L1", "L5"]
    assert e27["cn0"].nunique() == 2


def test_device_gnss_csv_has_the_same_measurements(gnss_dir):
    # Google's processed device_gnss.csv of the GSDC 2023 trace against the raw log's rows
    log = _read(gnss_dir / PIXEL7PRO)
    ours = pd.concat([log.raw, log.dropped])
    ours = ours.assign(ms=ours["time_utc"].dt.floor("ms").dt.tz_localize(None))
    google = pd.read_csv(gnss_dir / "gsdc2023_2023-09-07_Pixel7Pro_device_gnss_excerpt.csv")
    letter = google["ConstellationType"].map({1: "G", 3: "R", 4: "J", 6: "E"})
    google = pd.DataFrame(
        {
            "ms": pd.to_datetime(google["utcTimeMillis"], unit="ms").astype("datetime64[ns]"),
            "constellation": letter,
            "svid": google["Svid"] - np.where(letter == "J", 192, 0),
            "band": np.where(google["CarrierFrequencyHz"] > 1.3e9, "L1", "L5"),
            "cn0_google": google["Cn0DbHz"],
        }
    )
    both = ours.merge(google, on=["ms", "constellation", "svid", "band"], validate="1:1")
    assert len(both) == len(google) == len(ours) == 180
    np.testing.assert_allclose(both["cn0"], both["cn0_google"], atol=1e-9)


def test_status_rows_of_the_pixel4_excerpt(gnss_dir):
    status = _read(gnss_dir / PIXEL4, lenient=True).status
    assert len(status) == 14
    assert set(status["constellation"]) == {"E"}
    assert status.groupby("band").size().to_dict() == {"L1": 7, "L5": 7}
    assert sorted(set(status["svid"])) == [1, 13, 15, 21, 26, 27, 33]
    assert (status["time_utc"] == pd.Timestamp(1589494303000, unit="ms", tz="UTC")).all()
    e13 = status[(status["svid"] == 13) & (status["band"] == "L1")].iloc[0]
    assert (e13["azimuth"], e13["elevation"], e13["cn0"]) == (30.0, 66.0, 38.5)


def test_corrupted_altitude_names_file_and_line(gnss_dir):
    path = gnss_dir / PIXEL4
    with pytest.raises(InputError) as err:
        read_gnsslogger(path)
    assert err.value.where == f"{path}, line 88"
    assert "-29co.199999" in err.value.what and "AltitudeMeters" in err.value.what
    with pytest.warns(UserWarning, match="skipped 1 bad line.*line 88"):
        log = read_gnsslogger(path, lenient=True)
    assert log.skipped_lines == 1
    assert len(log.fixes) == 4 and len(log.raw) == 29


@SHARED
def test_cut_off_last_line_of_the_london_log_is_skipped_with_a_warning(gnss_dir):
    # the cut line is a BeiDou row of the last epoch: that epoch is dropped whole
    with pytest.warns(
        UserWarning,
        match=r"last line \(10082\) is cut off .*dropped the 1 epoch\(s\) it may belong to, "
        r"whose rows are not all there: 2020-02-11T08:54:06.999Z$",
    ):
        log = read_gnsslogger(gnss_dir / LONDON)
    assert log.skipped_lines == 1
    last = log.dropped[log.dropped["reason"] == INCOMPLETE]["time_utc"]
    assert last.nunique() == 1 and last.iloc[0] > log.epochs[-1]
    assert log.receiver == "london_ucl_2020-02-11_SM-G973F_gnss_log"


# --- bad input, on small logs made from the Stanford log ------------------------------------


@pytest.fixture(scope="module")
def small_log_lines(repo_data):
    """Header, 20 Raw rows (one epoch and part of the next) and 3 Fix rows of a v3 log."""
    lines = (repo_data / "gnss" / STANFORD).read_text().splitlines()
    header = [line for line in lines if line.startswith("#")]
    raw = [line for line in lines if line.startswith("Raw,")][:20]
    fix = [line for line in lines if line.startswith("Fix,")][:3]
    return header + raw + fix


# field numbers in the Raw rows of the Stanford log (0 is the record type)
TIME_NANOS, FULL_BIAS, SVID, STATE, CN0 = 2, 5, 11, 13, 16


def _set(line, index, value):
    fields = line.split(",")
    fields[index] = value
    return ",".join(fields)


def _write(tmp_path, lines, end="\n"):
    path = tmp_path / "gnss_log.txt"
    path.write_text("\n".join(lines) + end)
    return path


def _first(lines, prefix):
    return next(i for i, line in enumerate(lines) if line.startswith(prefix))


def test_small_log_reads(tmp_path, small_log_lines):
    log = read_gnsslogger(_write(tmp_path, small_log_lines))
    assert len(log.raw) + len(log.dropped) == 20 and len(log.fixes) == 3
    assert log.skipped_lines == 0


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda line: "Raw,###garbage###", "Raw row of 2 fields where its header"),
        (lambda line: line[: len(line) // 2], r"Raw row of \d+ fields"),
        (lambda line: line + ",1,2", r"Raw row of 39 fields where its header \(line 5\) has 37"),
        (lambda line: "12:00 ???", "not a GnssLogger record"),
        (lambda line: _set(line, STATE, "16x31"), "Raw State is '16x31', not an integer"),
        (lambda line: _set(line, SVID, ""), "Raw Svid is empty"),
        (lambda line: _set(line, CN0, "3O.5"), "Raw Cn0DbHz is '3O.5', not a number"),
    ],
    ids=["garbled", "truncated", "extra-fields", "not-a-record", "bad-int", "empty", "bad-float"],
)
def test_bad_lines_name_the_line_or_are_skipped(tmp_path, small_log_lines, edit, message):
    lines = list(small_log_lines)
    k = _first(lines, "Raw,") + 5
    lines[k] = edit(lines[k])
    path = _write(tmp_path, lines)
    with pytest.raises(InputError, match=message) as err:
        read_gnsslogger(path)
    assert err.value.where == f"{path}, line {k + 1}"
    with pytest.warns(UserWarning, match=f"skipped 1 bad line.*line {k + 1}"):
        log = read_gnsslogger(path, lenient=True)
    assert log.skipped_lines == 1
    assert len(log.raw) + len(log.dropped) == 19


def test_unterminated_cut_last_line_warns_in_strict_mode(tmp_path, small_log_lines):
    lines = list(small_log_lines[:-3])  # end with a Raw row
    lines[-1] = lines[-1][:60]
    with pytest.warns(UserWarning, match="is cut off"):
        log = read_gnsslogger(_write(tmp_path, lines, end=""))
    assert log.skipped_lines == 1 and len(log.raw) + len(log.dropped) == 19
    # the same line with a line end is a truncated line like any other
    with pytest.raises(InputError, match="fields"):
        read_gnsslogger(_write(tmp_path, lines))


@pytest.fixture(scope="module")
def three_epochs(repo_data):
    """Header, the 90 Raw rows of the first three epochs (30 each) of the Stanford log, and the
    line numbers of each epoch's first row."""
    lines = (repo_data / "gnss" / STANFORD).read_text().splitlines()
    header = [line for line in lines if line.startswith("#")]
    raw = [line for line in lines if line.startswith("Raw,")][:90]
    firsts = [len(header) + 1 + 30 * k for k in range(3)]
    return header + raw, firsts


def _named(rows: pd.DataFrame) -> list[str]:
    """The sorted epochs of some rows as warnings name them (ISO 8601, to the millisecond)."""
    times = pd.DatetimeIndex(rows["time_utc"].unique()).sort_values()
    return [t.strftime("%Y-%m-%dT%H:%M:%S.%f")[:23] + "Z" for t in times]


def _epoch_times(path) -> list[str]:
    """The epochs of a clean log."""
    log = read_gnsslogger(path)
    return _named(pd.concat([log.raw, log.dropped]))


@pytest.mark.parametrize(
    ("row", "edit", "dropped"),
    [
        (10, lambda line: _set(line, CN0, "3O.5"), [0]),  # inside an epoch
        (10, lambda line: line[:80], [0]),  # a row cut short
        (10, lambda line: "12:00 ???", [0]),  # not a record
        (10, lambda line: _set(line, FULL_BIAS, "-1000000000"), [0]),  # impossible time
        (10, lambda line: _set(_set(line, CN0, ""), TIME_NANOS, "1"), [0]),  # another clock
        (29, lambda line: _set(line, STATE, "16x31"), [0]),  # the last row of an epoch
        (30, lambda line: _set(line, SVID, ""), [1]),  # its clock says: the next epoch
        (30, lambda line: line[:20], [0, 1]),  # nothing says which: both
    ],
    ids=[
        "bad-float",
        "truncated",
        "not-a-record",
        "bad-time",
        "other-clock",
        "last-row",
        "next-first",
        "between",
    ],
)
def test_a_bad_row_drops_its_epoch_whole(tmp_path, three_epochs, row, edit, dropped):
    lines, firsts = three_epochs
    clean = _write(tmp_path, lines)
    times = _epoch_times(clean)
    k = firsts[0] - 1 + row
    lines = list(lines)
    lines[k] = edit(lines[k])
    path = tmp_path / "bad_log.txt"
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError, match=f"line {k + 1}"):
        read_gnsslogger(path)
    shown = ", ".join(times[i] for i in dropped)
    with pytest.warns(UserWarning) as record:
        log = read_gnsslogger(path, lenient=True)
    assert [str(w.message) for w in record] == [
        f"{path}: skipped 1 bad line(s); the first, line {k + 1}: "
        + str(record[0].message).split(f"line {k + 1}: ")[1].split(";")[0]
        + f"; dropped the {len(dropped)} epoch(s) they may belong to, whose rows are not all "
        f"there: {shown}"
    ]
    assert _named(log.raw) == [t for i, t in enumerate(times) if i not in dropped]
    assert _named(log.dropped[log.dropped["reason"] == INCOMPLETE]) == [times[i] for i in dropped]
    assert len(log.raw) + len(log.dropped) == 89


@pytest.mark.parametrize(
    ("keep", "message", "dropped"),
    [
        (100, "dropped the 1 epoch(s) it may belong to, whose rows are not all there: {2}", [2]),
        (60, "it begins epoch {2}, of which no other row was written", []),
        (25, "it begins a new epoch, of which no other row was written", []),
        (2, "dropped the 1 epoch(s) it may belong to, whose rows are not all there: {1}", [1]),
    ],
    ids=["inside", "first-row-with-clock", "first-row-without-bias", "first-row-no-clock"],
)
def test_a_cut_off_last_line_drops_the_epoch_it_may_belong_to(
    tmp_path, three_epochs, keep, message, dropped
):
    lines, firsts = three_epochs
    times = _epoch_times(_write(tmp_path, lines))
    row = 10 if keep == 100 else 0  # a row inside the last epoch, or its first
    cut = lines[: firsts[2] - 1 + row] + [lines[firsts[2] - 1 + row][:keep]]
    path = _write(tmp_path, cut, end="")
    with pytest.warns(UserWarning) as record:
        log = read_gnsslogger(path)  # strict: a cut-off last line is no error
    assert [str(w.message) for w in record] == [
        f"{path}: the last line ({len(cut)}) is cut off (no line end: the log was closed while "
        f"being written); skipped it"
        + ("; " if dropped else " (")
        + message.format(*times)
        + ("" if dropped else ")")
    ]
    assert _named(log.raw) == [t for i, t in enumerate(times[:2]) if i not in dropped]


def test_a_log_cut_at_a_line_end_inside_its_last_epoch(tmp_path, three_epochs):
    lines, firsts = three_epochs
    times = _epoch_times(_write(tmp_path, lines))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a log that ends with a whole epoch: no warning
        assert len(read_gnsslogger(_write(tmp_path, lines)).epochs) == 3
    path = _write(tmp_path, lines[: firsts[2] - 1 + 12])
    with pytest.warns(UserWarning) as record:
        log = read_gnsslogger(path)
    assert [str(w.message) for w in record] == [
        f"{path}: the log ends inside epoch {times[2]}: its 12 rows are the first of the 30 of "
        "the epoch before, in the same order (the log was cut at a line end); dropped it"
    ]
    assert len(log.epochs) == 2
    assert (log.dropped["reason"] == INCOMPLETE).sum() == 12


def test_a_log_cut_inside_its_last_field_is_a_cut_off_line(tmp_path, repo_data):
    # a 1.4 log ends its rows with ConstellationType: cut just before it, the row has all its
    # fields, one of them empty
    text = (repo_data / "gnss" / DEMO_JUNE).read_text()
    end = text.index("\n", text.index("\nRaw,") + 1000)
    path = tmp_path / "june.txt"
    path.write_text(text[: end - 1])
    assert text[end - 2 : end] == ",1"
    with pytest.warns(UserWarning, match=r"is cut off .*dropped the 1 epoch\(s\)"):
        log = read_gnsslogger(path)
    assert log.skipped_lines == 1


def test_unknown_version(tmp_path, small_log_lines):
    lines = [
        line.replace("v3.0.6.4", "v9.1") if "Version:" in line else line for line in small_log_lines
    ]
    path = _write(tmp_path, lines)
    with pytest.raises(InputError, match="unknown GnssLogger version '9.1'") as err:
        read_gnsslogger(path)
    assert err.value.where == f"{path}, line {_first(lines, '# Version') + 1}"
    with pytest.warns(UserWarning, match="unknown GnssLogger version"):
        log = read_gnsslogger(path, lenient=True)
    assert log.version == "9.1" and len(log.raw) + len(log.dropped) == 20


def test_missing_headers(tmp_path, small_log_lines):
    no_version = [line for line in small_log_lines if "Version:" not in line]
    with pytest.raises(InputError, match="no '# Version:' header line"):
        read_gnsslogger(_write(tmp_path, no_version), lenient=True)
    no_raw_header = [line for line in small_log_lines if not line.startswith("# Raw,")]
    path = _write(tmp_path, no_raw_header)
    with pytest.raises(InputError, match="Raw records but no '# Raw,...' header") as err:
        read_gnsslogger(path, lenient=True)
    assert err.value.where == f"{path}, line {_first(no_raw_header, 'Raw,') + 1}"
    renamed = [line.replace(",Cn0DbHz,", ",Cn0,", 1) for line in small_log_lines]
    with pytest.raises(MissingColumnError, match="'Cn0DbHz'"):
        read_gnsslogger(_write(tmp_path, renamed))
    with pytest.raises(InputError, match="cannot read the log"):
        read_gnsslogger(tmp_path / "missing.txt")


def test_columns_found_by_header_name_not_position(tmp_path, small_log_lines):
    # swap two columns in the header and in every Raw row: same measurements
    def swap(line):
        fields = line.split(",")
        fields[SVID], fields[CN0] = fields[CN0], fields[SVID]
        return ",".join(fields)

    lines = [
        swap(line) if line.startswith(("Raw,", "# Raw,")) else line for line in small_log_lines
    ]
    swapped = read_gnsslogger(_write(tmp_path, lines))
    original = read_gnsslogger(_write(tmp_path, small_log_lines))
    pd.testing.assert_frame_equal(swapped.raw, original.raw)


# --- found by fuzzing (tests/fuzz/test_fuzz_gnss.py) ----------------------------------------


@pytest.mark.parametrize(
    ("record", "index", "value", "message"),
    [
        ("Raw,", CN0, "1e308", "Raw Cn0DbHz is '1e308', outside 0..100"),
        ("Raw,", CN0, "Infinity", "Raw Cn0DbHz is 'Infinity', not a finite number"),
        ("Raw,", 6, "1e300", "Raw BiasNanos is '1e300', outside -1e+15..1e+15"),
        ("Raw,", TIME_NANOS, "9223372036854775808", "TimeNanos is '9223372036854775808', beyond"),
        (
            "Raw,",
            TIME_NANOS,
            "8000000000000000000",
            "Raw GPS time 9.383e+18 ns after 1980-01-06 is after 2100-01-01",
        ),
        (
            "Raw,",
            FULL_BIAS,
            "-1065446151445559028",
            "Raw GPS time 2013-10-10T13:16:52.535 is before 2015-07-01",
        ),
        ("Fix,", 2, "91.5", "Fix LatitudeDegrees is '91.5', outside -90..90"),
        ("Fix,", 3, "-inf", "Fix LongitudeDegrees is '-inf', not a finite number"),
        ("Fix,", 4, "1e308", "Fix AltitudeMeters is '1e308', outside -100000..100000"),
        ("Fix,", 8, "9223372036854775", "Fix UnixTimeMillis is '9223372036854775', outside"),
    ],
    ids=["cn0", "cn0-inf", "bias", "int64", "overflow", "2013", "lat", "lon", "h", "fix-time"],
)
def test_values_outside_their_range_are_bad_lines(
    tmp_path, small_log_lines, record, index, value, message
):
    lines = list(small_log_lines)
    k = _first(lines, record) + 1
    lines[k] = _set(lines[k], index, value)
    path = _write(tmp_path, lines)
    with pytest.raises(InputError, match=re.escape(message)) as err:
        read_gnsslogger(path)
    assert err.value.where == f"{path}, line {k + 1}"


def test_a_log_of_headers_only(tmp_path, small_log_lines):
    # cut inside its header, or a Raw header without the columns no row needs: no rows, no error
    headers = [line for line in small_log_lines if line.startswith("#")]
    log = read_gnsslogger(_write(tmp_path, headers))
    assert log.raw.empty and log.dropped.empty and log.fixes.empty
    without = [line.replace(",ConstellationType", "") for line in headers]
    assert read_gnsslogger(_write(tmp_path, without)).raw.empty


def test_clock_without_gps_time_or_before_2015(tmp_path, small_log_lines):
    lines = list(small_log_lines)
    k = _first(lines, "Raw,")
    lines[k] = _set(lines[k], FULL_BIAS, "")
    log = read_gnsslogger(_write(tmp_path, lines))
    assert log.dropped["reason"].tolist().count("no GPS time (FullBiasNanos empty)") == 1
    assert log.dropped["time_utc"].isna().sum() == 1
    lines[k] = _set(lines[k], FULL_BIAS, "-1000000000")
    with pytest.raises(InputError, match="before 2015-07-01"):
        read_gnsslogger(_write(tmp_path, lines))


def test_random_corruption_is_an_input_error_or_a_clean_read(tmp_path, small_log_lines):
    # bytes changed, deleted or inserted anywhere after the header: never another exception
    rng = np.random.default_rng(7)
    header = sum(len(line) + 1 for line in small_log_lines if line.startswith("#"))
    clean = ("\n".join(small_log_lines) + "\n").encode()
    path = tmp_path / "gnss_log.txt"
    outcomes = {"error": 0, "read": 0}
    for _ in range(40):
        data = bytearray(clean)
        pos = int(rng.integers(header, len(data)))
        data[pos : pos + int(rng.integers(0, 20))] = (
            rng.integers(0, 256, 3).astype(np.uint8).tobytes()
        )
        path.write_bytes(bytes(data))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            try:
                read_gnsslogger(path)
                outcomes["read"] += 1
            except InputError:
                outcomes["error"] += 1
            log = read_gnsslogger(path, lenient=True)
        assert len(log.raw) + len(log.dropped) + log.skipped_lines >= 19
    assert outcomes["error"] > 20
