"""RINEX navigation files: RINEX 2 GPS and RINEX 3 mixed files read (their header's leap
seconds against gpstime's table), and the errors a garbled or truncated file causes."""

import gzip

import numpy as np
import pandas as pd
import pytest
from conftest import BRDM_2023

from gnss_citygml.errors import InputError
from gnss_citygml.gnss.gpstime import gps_minus_utc
from gnss_citygml.gnss.navigation import read_nav
from gnss_citygml.gnss.orbits import load_orbits


@pytest.mark.parametrize(
    ("name", "records", "leap"),
    [
        ("hour1820.16n", 418, 17),
        ("hour2350.16n", 419, 17),
        ("brdc1350.20n", 415, 18),
        ("brdc1180.21n", 105, 18),
        ("brdc1190.21n", 106, 18),
        pytest.param("brdc3200.25n", 415, 18, marks=pytest.mark.shared_data),
    ],
)
def test_rinex2_files_parse(reference_data, name, records, leap):
    orbits_dir = reference_data / "orbits"
    table = read_nav(orbits_dir / name)
    assert len(table) == records and set(table["constellation"]) == {"G"}
    assert table["sqrt_a"].between(5150, 5160).all() and table["e"].between(0, 0.03).all()
    # Every file's header LEAP SECONDS agrees with the table of gpstime.
    header = (orbits_dir / name).read_text().splitlines()
    stated = next(int(line[:6]) for line in header if "LEAP SECONDS" in line)
    assert stated == leap == gps_minus_utc(table["toe"].iloc[:1])[0]


def test_rinex3_mixed_file(orbits_dir):
    table = read_nav(orbits_dir / BRDM_2023)
    assert table["constellation"].value_counts().to_dict() == {
        "R": 7,
        "G": 6,
        "E": 6,
        "C": 6,
        "J": 6,
    }
    assert table.attrs["skipped"] == {"S": 6, "I": 6}
    g01 = table[(table["constellation"] == "G") & (table["svid"] == 1)].iloc[0]
    assert g01["sqrt_a"] == pytest.approx(5153.655818939)  # 5.153655818939e+03
    assert g01["toe"] == np.datetime64("2023-03-14T00:00")
    # BeiDou: toe 172800 s of the BDT week is 14 s later in GPS time.
    c01 = table[(table["constellation"] == "C") & (table["svid"] == 1)].iloc[0]
    assert c01["toe"] == np.datetime64("2023-03-14T00:00:14")
    orbits = load_orbits(orbits_dir / BRDM_2023)
    assert orbits.source == "broadcast"
    assert orbits.notes == [
        f"{BRDM_2023}: 6 S records skipped (system not supported)",
        f"{BRDM_2023}: 6 I records skipped (system not supported)",
    ]


@pytest.mark.parametrize(
    ("line", "old", "new", "why"),
    [
        (10, "D+02", "Dx02", "unreadable number"),
        (11, "   ", " 9 ", "expected a continuation line"),
        (1, "NAVIGATION DATA ", "OBSERVATION DATA", "unsupported RINEX file"),
    ],
)
def test_garbled_nav_line_names_file_and_line(tmp_path, orbits_dir, line, old, new, why):
    lines = (orbits_dir / "brdc1180.21n").read_text().splitlines(keepends=True)
    lines[line - 1] = lines[line - 1].replace(old, new, 1)
    path = tmp_path / "garbled.21n"
    path.write_text("".join(lines))
    with pytest.raises(InputError, match=why) as info:
        read_nav(path)
    assert info.value.where == f"{path}, line {line}"


def test_truncated_nav_record_names_its_first_line(tmp_path, orbits_dir):
    lines = (orbits_dir / "brdc1180.21n").read_text().splitlines(keepends=True)
    path = tmp_path / "truncated.21n"
    path.write_text("".join(lines[:12]))  # the header and half of the first record
    with pytest.raises(InputError, match="truncated record") as info:
        read_nav(path)
    assert info.value.where == f"{path}, line 9"


@pytest.mark.parametrize("name", ["brdc1190.21n.gz", "BRDC1190.21N.GZ", "brdc1190.21n"])
def test_gzipped_files_are_read(tmp_path, orbits_dir, name):
    """A gzipped file is told by its first bytes, whatever its name says (an upper-case .GZ,
    a download that lost its suffix)."""
    path = tmp_path / name
    path.write_bytes(gzip.compress((orbits_dir / "brdc1190.21n").read_bytes()))
    pd.testing.assert_frame_equal(read_nav(path), read_nav(orbits_dir / "brdc1190.21n"))
    assert load_orbits(path).source == "broadcast"


# --- found by fuzzing (tests/fuzz/test_fuzz_gnss.py) ------------------------------------------


@pytest.mark.parametrize(
    ("line", "old", "new", "why", "named"),
    [
        (27, "2023 03 14", "2023 13 14", "unreadable epoch", 27),
        (30, "1.728000000000e+05", "nan".rjust(18), "unreadable number: 'nan'", 30),
        (30, "1.728000000000e+05", "1.000e+99".rjust(18), r"time of ephemeris 1e\+99 s", 27),
    ],
)
def test_impossible_nav_epoch_or_ephemeris_time(tmp_path, orbits_dir, line, old, new, why, named):
    lines = (orbits_dir / BRDM_2023).read_text().splitlines(keepends=True)
    assert old in lines[line - 1]
    lines[line - 1] = lines[line - 1].replace(old, new, 1)
    path = tmp_path / "garbled.rnx"
    path.write_text("".join(lines))
    with pytest.raises(InputError, match=why) as info:
        read_nav(path)
    assert info.value.where == f"{path}, line {named}"  # the line, or the record's first
