"""Broadcast ephemerides propagated, against data no one here wrote: SP3 precise orbits of
three analysis centres, Google's satellite positions, and the next ephemeris of the same
satellite (BeiDou GEO too)."""

import numpy as np
import pandas as pd
import pytest
from conftest import BRDM_2023, COD_2023, XYZ, compare, distance, sp3_times_utc

from gnss_citygml.gnss.gpstime import GPS_EPOCH, gps_to_utc
from gnss_citygml.gnss.navigation import read_nav
from gnss_citygml.gnss.orbits import BroadcastOrbits, Sp3Orbits, load_orbits
from gnss_citygml.gnss.sp3 import read_sp3

LIGHT = 299_792_458.0


def test_sp3_vs_broadcast_gps_2021(orbits_dir, cod):
    nav = load_orbits(orbits_dir / "brdc1180.21n")
    times = gps_to_utc(np.unique(cod["time_gps"]))
    diff = compare(Sp3Orbits(cod).positions_all(times, "G"), nav.positions_all(times, "G"))
    print(f"COD vs brdc1180 GPS: n {diff.size} max {diff.max():.2f} median {np.median(diff):.2f}")
    # Centre of mass vs antenna phase centre plus broadcast errors: 1-2 m typical, G14 ~5 m.
    assert diff.size == 73 * 31
    assert np.median(diff) < 2.0 and diff.max() < 6.0


def test_sp3_vs_broadcast_gps_full_day_2025(shared_data, gfz):
    nav = load_orbits(shared_data / "orbits" / "brdc3200.25n")
    times = gps_to_utc(np.unique(gfz["time_gps"]))
    diff = compare(Sp3Orbits(gfz).positions_all(times, "G"), nav.positions_all(times, "G"))
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
def test_broadcast_gps_matches_google(repo_data, nav, csv, time_col, clock_col, columns, limit):
    """Google's satellite positions are at the transmit time: received SV time - SV clock."""
    table = pd.read_csv(repo_data / "gnss" / csv)
    kind = "ConstellationType" if "ConstellationType" in table else "constellationType"
    svid = "Svid" if "Svid" in table else "svid"
    table = table[(table[kind] == 1) & table[columns[0]].notna()]
    transmit_ns = table[time_col].to_numpy() - table[clock_col].to_numpy() / LIGHT * 1e9
    transmit_utc = gps_to_utc(GPS_EPOCH + transmit_ns.astype(np.int64).astype("timedelta64[ns]"))
    orbits = load_orbits(repo_data / "orbits" / nav)
    diff = distance(orbits.positions(transmit_utc, "G", table[svid]), table[columns])
    print(f"{nav} vs {csv}: {diff.size} signals, max {diff.max():.3f} m")
    assert diff.size >= 60 and diff.max() < limit
    # At the receive time instead, the ~0.07 s travel time moves a satellite ~250 m.
    arrival = transmit_utc + np.timedelta64(70, "ms")
    assert distance(orbits.positions(arrival, "G", table[svid]), table[columns]).min() > 100


def test_rinex3_against_sp3_at_0000_to_0010(orbits_dir):
    """Broadcast GPS, Galileo and GLONASS against CODE's rapid orbit (3 epochs, no interpolation
    needed: the positions are compared at the SP3 epochs themselves)."""
    precise = read_sp3(orbits_dir / COD_2023)
    orbits = load_orbits(orbits_dir / BRDM_2023)
    got = orbits.positions(sp3_times_utc(precise), precise["constellation"], precise["svid"])
    diff = pd.Series(distance(got, precise[XYZ]), index=precise["constellation"]).dropna()
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
            worst[name] = max(worst.get(name, 0.0), distance(a, b)[0])
    print(
        "successive ephemerides, max difference (m):",
        {k: round(float(v), 2) for k, v in worst.items()},
    )
    assert set(worst) == {"C01", "C02", "E01", "E02", "G01", "G02", "J02", "J03", "R01", "R02"}
    assert max(worst.values()) < 2.0
    geo = np.linalg.norm(load_orbits(orbits_dir / BRDM_2023).positions("2023-03-14T00:30", "C", 1))
    assert geo == pytest.approx(42_164_000, abs=50_000)  # geostationary radius
