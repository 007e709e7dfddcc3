"""Orbits against data no one here wrote: withheld SP3 epochs, SP3 vs broadcast, Google's
satellite positions, and the errors a user can cause (times outside the orbits, garbled files).
"""

import gzip
import time

import numpy as np
import pandas as pd
import pytest

from gnss_citygml.errors import InputError
from gnss_citygml.gnss.gpstime import (
    GPS_EPOCH,
    gps_minus_utc,
    gps_seconds,
    gps_to_utc,
    to_datetime64,
    utc_to_gps,
)
from gnss_citygml.gnss.orbits import (
    BroadcastOrbits,
    OrbitSpanError,
    Sp3Orbits,
    load_orbits,
    read_nav,
    read_sp3,
)

COD_2021 = "COD0MGXFIN_20211180000_01D_05M_ORB.SP3"
GRG_2021 = "grg21553.sp3"
GFZ_2025 = "GFZ0MGXRAP_20253200000_01D_05M_ORB.SP3"
COD_2023 = "COD0OPSRAP_20230730000_01D_05M_ORB.SP3"
BRDM_2023 = "BRDM00DLR_S_20230730000_01D_MN.rnx"
LIGHT = 299_792_458.0
XYZ = ["x", "y", "z"]


@pytest.fixture(scope="module")
def orbits_dir(shared_data):
    return shared_data / "orbits"


@pytest.fixture(scope="module")
def cod(orbits_dir):
    return read_sp3(orbits_dir / COD_2021)


@pytest.fixture(scope="module")
def gfz(orbits_dir):
    return read_sp3(orbits_dir / GFZ_2025)


def _utc(table):
    return gps_to_utc(table["time_gps"].to_numpy())


def _distance(a, b):
    return np.linalg.norm(np.asarray(a) - np.asarray(b), axis=1)


def _compare(precise: pd.DataFrame, broadcast: pd.DataFrame) -> np.ndarray:
    both = precise.merge(broadcast, on=["time_utc", "constellation", "svid"])
    return _distance(both[["x_x", "y_x", "z_x"]], both[["x_y", "y_y", "z_y"]])


# ----------------------------------------------------------------------------- GPS time


def test_leap_seconds_around_the_2017_step():
    assert gps_minus_utc(["1980-01-06", "2016-06-30", "2016-12-31T23:59:59"]).tolist() == [
        0,
        17,
        17,
    ]
    assert gps_minus_utc(["2017-01-01", "2020-02-11", "2025-11-16"]).tolist() == [18, 18, 18]
    utc = to_datetime64(["2016-12-31T23:59:59", "2017-01-01T00:00:01", "2021-04-29T22:35:26"])
    gps = utc_to_gps(utc)
    assert (gps - utc).astype("timedelta64[s]").astype(int).tolist() == [17, 18, 18]
    assert (gps_to_utc(gps) == utc).all()


def test_times_before_gps_and_numbers_are_errors():
    with pytest.raises(InputError, match="before the start of GPS time"):
        gps_minus_utc("1979-12-31")
    with pytest.raises(InputError, match="numbers, not dates"):
        to_datetime64(np.array([1.5e9]))


def test_aware_times_are_converted_to_utc():
    local = pd.Series(pd.to_datetime(["2021-04-29 15:35:26"]).tz_localize("America/Los_Angeles"))
    assert to_datetime64(local)[0] == np.datetime64("2021-04-29T22:35:26")


# ----------------------------------------------------------------------------------- SP3


def test_sp3_files_parse(orbits_dir, cod, gfz):
    assert cod.attrs == {"version": "d", "time_system": "GPS"}
    # The header announces 289 epochs; the staged file is a cut of 73 (18:00 to 24:00).
    assert cod["time_gps"].nunique() == 73
    assert cod["time_gps"].min() == np.datetime64("2021-04-28T18:00")
    per_system = cod.groupby("constellation")["svid"].nunique().to_dict()
    assert per_system == {"C": 37, "E": 24, "G": 31, "J": 3, "R": 21}
    assert len(cod) == 73 * 116
    first = cod.iloc[0]  # PG01  13287.682546 -15491.926575  16545.690647    703.963460
    assert (first["constellation"], first["svid"]) == ("G", 1)
    assert first[XYZ].tolist() == pytest.approx([13287682.546, -15491926.575, 16545690.647])
    assert first["clock"] == pytest.approx(703.963460)
    assert gfz["time_gps"].nunique() == 289 and len(gfz) == 289 * 130
    grg = read_sp3(orbits_dir / GRG_2021)
    assert grg.attrs["version"] == "c" and set(grg["constellation"]) == {"G", "R"}


def test_sp3_bad_clock_is_nan_but_position_kept(gfz):
    # Two R26 records of the GFZ file carry the 999999.999999 "no clock" value.
    bad = gfz[gfz["clock"].isna()]
    assert len(bad) == 2 and set(bad["constellation"] + bad["svid"].astype(str)) == {"R26"}
    assert np.isfinite(bad[XYZ].to_numpy()).all()


def test_lagrange_reproduces_withheld_epochs_to_millimetres(cod, gfz):
    """Drop an epoch, interpolate it from the rest: mm level with a centred window."""
    worst = {}
    for name, table in (("COD", cod), ("GFZ", gfz)):
        epochs = np.unique(table["time_gps"])
        for k in (5, 10, len(epochs) // 2, len(epochs) - 6):
            truth = table[table["time_gps"] == epochs[k]]
            orbits = Sp3Orbits(table[table["time_gps"] != epochs[k]])
            got = orbits.positions(_utc(truth), truth["constellation"], truth["svid"])
            err = _distance(got, truth[XYZ])
            worst[name, k] = err.max()
            assert np.isfinite(err).all()
    print(
        "withheld-epoch error, max per case (m):", {k: round(float(v), 4) for k, v in worst.items()}
    )
    assert max(worst.values()) < 0.005
    # The first epoch after the start has a one-sided window: centimetres, not millimetres.
    epochs = np.unique(gfz["time_gps"])
    truth = gfz[gfz["time_gps"] == epochs[1]]
    got = Sp3Orbits(gfz[gfz["time_gps"] != epochs[1]]).positions(
        _utc(truth), truth["constellation"], truth["svid"]
    )
    assert _distance(got, truth[XYZ]).max() < 0.1


def test_two_sp3_files_and_a_gap_of_one_satellite(tmp_path, orbits_dir, gfz):
    """The GFZ day cut in two files that share one epoch (as consecutive days share midnight),
    with G05 marked missing (0.000000) from 14:00 to 14:40 in the second."""
    lines = (orbits_dir / GFZ_2025).read_text().splitlines(keepends=True)
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


def test_utc_time_system_shifts_the_epochs(tmp_path, orbits_dir):
    lines = (orbits_dir / COD_2023).read_text().splitlines(keepends=True)
    lines = [line.replace("%c M  cc GPS", "%c M  cc UTC") for line in lines]
    (tmp_path / "utc.sp3").write_text("".join(lines))
    table = read_sp3(tmp_path / "utc.sp3")
    assert table.attrs["time_system"] == "UTC"
    assert table["time_gps"].min() == np.datetime64("2023-03-14T00:00:18")


def test_sp3_agrees_with_another_analysis_centre(orbits_dir, cod):
    """CODE and CNES/CLS GRG final orbits of the same day: centimetres apart."""
    grg = Sp3Orbits(read_sp3(orbits_dir / GRG_2021))
    times = gps_to_utc(np.unique(read_sp3(orbits_dir / GRG_2021)["time_gps"]))
    diff = _compare(Sp3Orbits(cod).positions_all(times, "GR"), grg.positions_all(times, "GR"))
    print(f"COD vs GRG (GPS+GLONASS, {diff.size} positions): max {diff.max():.3f} m")
    assert diff.size > 2500 and diff.max() < 0.5


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


# ------------------------------------------------------------------------ broadcast orbits


def test_sp3_vs_broadcast_gps_2021(orbits_dir, cod):
    nav = load_orbits(orbits_dir / "brdc1180.21n")
    times = gps_to_utc(np.unique(cod["time_gps"]))
    diff = _compare(Sp3Orbits(cod).positions_all(times, "G"), nav.positions_all(times, "G"))
    print(f"COD vs brdc1180 GPS: n {diff.size} max {diff.max():.2f} median {np.median(diff):.2f}")
    # Centre of mass vs antenna phase centre plus broadcast errors: 1-2 m typical, G14 ~5 m.
    assert diff.size == 73 * 31
    assert np.median(diff) < 2.0 and diff.max() < 6.0


def test_sp3_vs_broadcast_gps_full_day_2025(orbits_dir, gfz):
    nav = load_orbits(orbits_dir / "brdc3200.25n")
    times = gps_to_utc(np.unique(gfz["time_gps"]))
    diff = _compare(Sp3Orbits(gfz).positions_all(times, "G"), nav.positions_all(times, "G"))
    print(f"GFZ vs brdc3200 GPS: n {diff.size} max {diff.max():.2f} median {np.median(diff):.2f}")
    assert diff.size == 289 * 32
    assert np.median(diff) < 2.0 and diff.max() < 6.0


@pytest.mark.parametrize(
    ("nav", "csv", "time_col", "clock_col", "columns", "limit"),
    [
        (
            "brdc1190.21n",
            "gsdc2022_mtv_2021-04-29_device_gnss_excerpt.csv",
            "ReceivedSvTimeNanosSinceGpsEpoch",
            "SvClockBiasMeters",
            ["SvPositionXEcefMeters", "SvPositionYEcefMeters", "SvPositionZEcefMeters"],
            0.01,
        ),
        (
            "brdc1350.20n",
            "gsdc2021_mtv_2020-05-14_Pixel4_derived_excerpt.csv",
            "receivedSvTimeInGpsNanos",
            "satClkBiasM",
            ["xSatPosM", "ySatPosM", "zSatPosM"],
            0.05,  # the CSV stores its times with 15 digits: 10 microseconds
        ),
    ],
)
def test_broadcast_gps_matches_google(shared_data, nav, csv, time_col, clock_col, columns, limit):
    """Google's satellite positions are at the transmit time: received SV time - SV clock."""
    table = pd.read_csv(shared_data / "gnss" / csv)
    kind = "ConstellationType" if "ConstellationType" in table else "constellationType"
    svid = "Svid" if "Svid" in table else "svid"
    table = table[(table[kind] == 1) & table[columns[0]].notna()]
    transmit_ns = table[time_col].to_numpy() - table[clock_col].to_numpy() / LIGHT * 1e9
    transmit_utc = gps_to_utc(GPS_EPOCH + transmit_ns.astype(np.int64).astype("timedelta64[ns]"))
    orbits = load_orbits(shared_data / "orbits" / nav)
    diff = _distance(orbits.positions(transmit_utc, "G", table[svid]), table[columns])
    print(f"{nav} vs {csv}: {diff.size} signals, max {diff.max():.3f} m")
    assert diff.size >= 60 and diff.max() < limit
    # At the receive time instead, the ~0.07 s travel time moves a satellite ~250 m.
    arrival = transmit_utc + np.timedelta64(70, "ms")
    assert _distance(orbits.positions(arrival, "G", table[svid]), table[columns]).min() > 100


@pytest.mark.parametrize(
    ("name", "records", "leap"),
    [
        ("hour1820.16n", 418, 17),
        ("hour2350.16n", 419, 17),
        ("brdc1350.20n", 415, 18),
        ("brdc1180.21n", 105, 18),
        ("brdc1190.21n", 106, 18),
        ("brdc3200.25n", 415, 18),
    ],
)
def test_rinex2_files_parse(orbits_dir, name, records, leap):
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


def test_rinex3_against_sp3_at_0000_to_0010(orbits_dir):
    """Broadcast GPS, Galileo and GLONASS against CODE's rapid orbit (3 epochs, no interpolation
    needed: the positions are compared at the SP3 epochs themselves)."""
    precise = read_sp3(orbits_dir / COD_2023)
    orbits = load_orbits(orbits_dir / BRDM_2023)
    got = orbits.positions(_utc(precise), precise["constellation"], precise["svid"])
    diff = pd.Series(_distance(got, precise[XYZ]), index=precise["constellation"]).dropna()
    print("BRDM vs COD rapid, max per system (m):", diff.groupby(level=0).max().round(2).to_dict())
    assert diff.groupby(level=0).size().to_dict() == {"E": 6, "G": 6, "R": 6}
    assert diff.drop("R").max() < 2.0
    assert diff["R"].max() < 5.0  # GLONASS: integrated state vectors, 5-15 min from tb


def test_successive_ephemerides_agree_including_beidou_geo(orbits_dir):
    """Each ephemeris and the next of the same satellite, both propagated to the midpoint
    between them: metres apart at most. Without the GEO rotation C01/C02 are 100-800 km apart.
    """
    table = read_nav(orbits_dir / BRDM_2023)
    worst = {}
    for (cons, svid), rows in table.groupby(["constellation", "svid"]):
        toe = rows["toe"].sort_values().to_numpy()
        for before, after in zip(toe[:-1], toe[1:], strict=True):
            mid = gps_to_utc(before + (after - before) / 2)
            a = BroadcastOrbits(rows[rows["toe"] == before]).positions(mid, cons, svid)
            b = BroadcastOrbits(rows[rows["toe"] == after]).positions(mid, cons, svid)
            name = f"{cons}{svid:02d}"
            worst[name] = max(worst.get(name, 0.0), _distance(a, b)[0])
    print(
        "successive ephemerides, max difference (m):",
        {k: round(float(v), 2) for k, v in worst.items()},
    )
    assert set(worst) == {"C01", "C02", "E01", "E02", "G01", "G02", "J02", "J03", "R01", "R02"}
    assert max(worst.values()) < 2.0
    geo = np.linalg.norm(load_orbits(orbits_dir / BRDM_2023).positions("2023-03-14T00:30", "C", 1))
    assert geo == pytest.approx(42_164_000, abs=50_000)  # geostationary radius


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


# ------------------------------------------------------------------------- the public API


def test_load_orbits_prefers_sp3_and_reports_nav_ignored(orbits_dir):
    orbits = load_orbits([orbits_dir / "brdc1180.21n", orbits_dir / COD_2021])
    assert orbits.source == "sp3"
    assert orbits.notes == ["brdc1180.21n ignored: SP3 precise orbits were given"]
    assert len(orbits.satellites) == 116 and orbits.satellites[0] == ("C", 6)
    start, end = orbits.span
    assert start == pd.Timestamp("2021-04-28 17:59:42", tz="UTC")
    assert end == pd.Timestamp("2021-04-28 23:59:42", tz="UTC")


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


@pytest.mark.parametrize("edit", ["x", "nan", "inf"])
def test_garbled_sp3_line_names_file_and_line(tmp_path, orbits_dir, edit):
    lines = (orbits_dir / COD_2023).read_text().splitlines(keepends=True)
    lines[30] = lines[30][:10] + edit + lines[30][10 + len(edit) :]
    path = tmp_path / "garbled.sp3"
    path.write_text("".join(lines))
    with pytest.raises(InputError) as info:
        read_sp3(path)
    assert info.value.where == f"{path}, line 31"
    assert "unreadable number" in info.value.what


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


def test_gzipped_files_are_read(tmp_path, orbits_dir):
    path = tmp_path / "brdc1190.21n.gz"
    path.write_bytes(gzip.compress((orbits_dir / "brdc1190.21n").read_bytes()))
    pd.testing.assert_frame_equal(read_nav(path), read_nav(orbits_dir / "brdc1190.21n"))
    assert load_orbits(path).source == "broadcast"


def test_not_an_orbit_file(shared_data):
    with pytest.raises(InputError, match="neither an SP3 orbit file nor a RINEX navigation"):
        load_orbits(shared_data / "gnss" / "gsdc2022_mtv_2021-04-29_ground_truth_excerpt.csv")


def test_gps_seconds_of_the_sp3_start(cod):
    # 2021-04-28 18:00 GPST = week 2155, 3 d 18 h.
    assert gps_seconds(cod["time_gps"].iloc[:1])[0] == 2155 * 604800 + 3 * 86400 + 18 * 3600


# --- found by fuzzing (tests/fuzz/test_fuzz_gnss.py) ------------------------------------------


@pytest.mark.parametrize(
    ("epoch", "why"),
    [
        ("*  2023  0 14  0  0  0.00000000", "unreadable epoch"),  # month 0
        ("*  2023  2 30  0  0  0.00000000", "unreadable epoch"),  # 30 February
        ("*  2023  3 14  0  0       inf", "impossible epoch"),
        ("*  nan  3 14  0  0  0.00000000", "unreadable epoch"),
        ("*  1900  3 14  0  0  0.00000000", "impossible epoch"),
        ("*  " + "1" * 30 + "  3 14  0  0  0.00000000", "unreadable epoch"),  # beyond a C long
    ],
)
def test_impossible_sp3_epoch_names_its_line(tmp_path, orbits_dir, epoch, why):
    lines = (orbits_dir / COD_2023).read_text().splitlines(keepends=True)
    k = next(i for i, line in enumerate(lines) if line.startswith("*"))
    lines[k] = epoch + "\n"
    path = tmp_path / "epoch.sp3"
    path.write_text("".join(lines))
    with pytest.raises(InputError, match=why) as info:
        read_sp3(path)
    assert info.value.where == f"{path}, line {k + 1}"


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
