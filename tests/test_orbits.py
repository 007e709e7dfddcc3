"""The orbits front: one source from any mix of files (SP3 preferred, several files merged),
its span, healthy ephemerides preferred, and the errors a user can cause (times outside the
orbits, unknown satellites, files that are no orbits, positions no GNSS orbit has).
"""

import time

import numpy as np
import pandas as pd
import pytest
from conftest import COD_2021, COD_2023, GFZ_2025, XYZ

from gnss_citygml.errors import InputError
from gnss_citygml.gnss.gpstime import gps_to_utc, utc_to_gps
from gnss_citygml.gnss.navigation import read_nav
from gnss_citygml.gnss.orbits import BroadcastOrbits, OrbitSpanError, Sp3Orbits, load_orbits


def test_load_orbits_prefers_sp3_and_reports_nav_ignored(orbits_dir):
    orbits = load_orbits([orbits_dir / "brdc1180.21n", orbits_dir / COD_2021])
    assert orbits.source == "sp3"
    assert orbits.notes == ["brdc1180.21n ignored: SP3 precise orbits were given"]
    assert len(orbits.satellites) == 116 and orbits.satellites[0] == ("C", 6)
    start, end = orbits.span
    assert start == pd.Timestamp("2021-04-28 17:59:42", tz="UTC")
    assert end == pd.Timestamp("2021-04-28 23:59:42", tz="UTC")


def test_two_sp3_files_and_a_gap_of_one_satellite(tmp_path, shared_data, gfz):
    """The GFZ day cut in two files that share one epoch (as consecutive days share midnight),
    with G05 marked missing (0.000000) from 14:00 to 14:40 in the second."""
    lines = (shared_data / "orbits" / GFZ_2025).read_text().splitlines(keepends=True)
    epoch_at = [i for i, line in enumerate(lines) if line.startswith("*")]
    (tmp_path / "a.sp3").write_text("".join(lines[: epoch_at[150]]) + "EOF\n")
    second = lines[: epoch_at[0]]
    hour_minute = None
    for line in lines[epoch_at[149] :]:
        if line.startswith("*"):
            hour_minute = (int(line[14:16]), int(line[17:19]))
        if line.startswith("PG05") and (14, 0) <= hour_minute <= (14, 40):
            line = "PG05      0.000000      0.000000      0.000000 999999.999999\n"
        second.append(line)
    (tmp_path / "b.sp3").write_text("".join(second))
    orbits = load_orbits([tmp_path / "a.sp3", tmp_path / "b.sp3"])
    whole = Sp3Orbits(gfz)
    assert orbits.span == whole.span
    times = pd.date_range("2025-11-16 10:00", "2025-11-16 18:00", freq="1min", tz="UTC")
    got = orbits.positions(times, "G", 5)
    # NaN exactly between the last position before the gap and the first one after it.
    gps = utc_to_gps(times)
    in_gap = (gps > np.datetime64("2025-11-16T13:55")) & (gps < np.datetime64("2025-11-16T14:45"))
    assert (np.isnan(got[:, 0]) == in_gap).all()
    # Elsewhere the windows move away from the gap: still millimetres from the whole series.
    want = whole.positions(times, "G", 5)
    print(f"next to a 50 min gap: {np.abs(got[~in_gap] - want[~in_gap]).max():.4f} m")
    assert np.abs(got[~in_gap] - want[~in_gap]).max() < 0.005
    # positions_all leaves the satellite out where it has no data.
    table = orbits.positions_all(times[in_gap][:1])
    assert ("G", 5) not in set(zip(table["constellation"], table["svid"], strict=True))
    assert len(table) == 129


def test_positions_all_is_fast(gfz):
    orbits = Sp3Orbits(gfz)
    times = pd.date_range("2025-11-16 10:00", periods=300, freq="s", tz="UTC")
    start = time.perf_counter()
    table = orbits.positions_all(times)
    seconds = time.perf_counter() - start
    print(f"positions_all: {len(orbits.satellites)} satellites x 300 epochs in {seconds:.3f} s")
    assert len(table) == 130 * 300
    assert list(table.columns) == ["time_utc", "constellation", "svid", *XYZ]
    assert str(table["time_utc"].dtype) == "datetime64[ns, UTC]"
    assert seconds < 1.0


def test_healthy_ephemeris_is_preferred(orbits_dir):
    """G18 on 2020-05-14 turns unhealthy (health 63) at 18:29:36; G23 is unhealthy all day."""
    table = read_nav(orbits_dir / "brdc1350.20n")
    g18 = table[(table["constellation"] == "G") & (table["svid"] == 18)]
    at = gps_to_utc("2020-05-14T18:35")  # nearest toe 18:29:36 is unhealthy, 16:00 is not
    orbits = BroadcastOrbits(table)
    healthy = BroadcastOrbits(g18[g18["toe"] == np.datetime64("2020-05-14T16:00")])
    sick = BroadcastOrbits(g18[g18["toe"] == np.datetime64("2020-05-14T18:29:36")])
    assert np.array_equal(orbits.positions(at, "G", 18), healthy.positions(at, "G", 18))
    assert not np.array_equal(orbits.positions(at, "G", 18), sick.positions(at, "G", 18))
    # With nothing healthy, positions() still answers; positions_all() leaves the satellite out.
    assert np.isfinite(orbits.positions(at, "G", 23)).all()
    evening = gps_to_utc(np.arange("2020-05-14T21:00", "2020-05-14T23:00", 600, "datetime64[s]"))
    sats = orbits.positions_all(evening)
    assert ("G", 23) not in set(zip(sats["constellation"], sats["svid"], strict=True))
    assert "G18" not in set(sats["constellation"] + sats["svid"].astype(str).str.zfill(2))
    everyone = orbits.positions_all(evening, healthy_only=False)
    assert len(everyone) == len(sats) + 2 * evening.size


class _PathLike:
    """An ``os.PathLike`` that is neither a str nor a Path (as ``os.DirEntry`` is)."""

    def __init__(self, path):
        self.path = path

    def __fspath__(self):
        return str(self.path)


def test_one_path_of_any_path_like_kind(orbits_dir):
    """One path-like is one file, as a str or a Path is (it used to be iterated, a TypeError)."""
    orbits = load_orbits(_PathLike(orbits_dir / "brdc1190.21n"))
    assert orbits.source == "broadcast" and orbits.paths == (orbits_dir / "brdc1190.21n",)


def test_unknown_satellite_gives_nan_rows(orbits_dir):
    orbits = load_orbits(orbits_dir / "brdc1190.21n")
    times = pd.date_range("2021-04-29 22:00", periods=3, freq="min")
    got = orbits.positions(times, ["G", "E", "G"], [2, 11, 99])
    assert np.isfinite(got[0]).all() and np.isnan(got[1:]).all()
    with pytest.raises(InputError, match="RINEX letter"):
        orbits.positions(times, "GPS", 2)


def test_too_few_sp3_epochs_is_an_error(orbits_dir):
    with pytest.raises(InputError, match="3 SP3 epochs: interpolation needs at least 10"):
        load_orbits(orbits_dir / COD_2023)


@pytest.mark.parametrize(
    ("name", "orbit_span"),
    [
        (COD_2021, "2021-04-28 17:59:42 UTC to 2021-04-28 23:59:42 UTC"),
        ("brdc1180.21n", "2021-04-28 13:59:26 UTC to 2021-04-29 03:59:26 UTC"),
    ],
)
def test_times_outside_the_orbits_name_both_spans(orbits_dir, name, orbit_span):
    orbits = load_orbits(orbits_dir / name)
    times = pd.date_range("2021-04-29 03:00", "2021-04-29 05:00", freq="h", tz="UTC")
    with pytest.raises(OrbitSpanError) as info:
        orbits.positions_all(times)
    message = str(info.value)
    print(message)
    assert orbit_span in message
    assert "2021-04-29 03:00:00 UTC to 2021-04-29 05:00:00 UTC" in message
    assert info.value.where == name


def test_not_an_orbit_file(repo_data):
    with pytest.raises(InputError, match="neither an SP3 orbit file nor a RINEX navigation"):
        load_orbits(repo_data / "gnss" / "gsdc2022_mtv_2021-04-29_ground_truth_excerpt.csv")


# --- found by fuzzing (tests/fuzz/test_fuzz_gnss.py) ------------------------------------------


def test_positions_no_gnss_orbit_has_are_no_data(tmp_path, orbits_dir):
    # G06 with sqrt(a) a thousand times too large: 1.7e10 km from the Earth, no GNSS orbit
    lines = (orbits_dir / "brdc1190.21n").read_text().splitlines(keepends=True)
    body = next(k for k, line in enumerate(lines) if "END OF HEADER" in line) + 1
    for k in range(body, len(lines), 8):
        if lines[k].startswith(" 6 "):
            lines[k + 2] = lines[k + 2][:-5] + "D+07\n"
    path = tmp_path / "far.21n"
    path.write_text("".join(lines))
    orbits = load_orbits(path)
    t = orbits.span[0] + pd.Timedelta("2h")
    assert ("G", 6) in orbits.satellites
    assert np.isnan(orbits.positions([t], "G", 6)).all()
    sky = orbits.positions_all([t])
    assert 6 not in set(sky["svid"]) and len(sky) > 20
    assert np.isfinite(orbits.positions([t], "G", 7)).all()
