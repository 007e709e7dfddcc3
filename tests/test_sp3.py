"""SP3 precise orbits against data no one here wrote: the files of three analysis centres,
withheld epochs, another centre's orbits of the same day, and the errors a garbled file causes.
"""

import numpy as np
import pytest
from conftest import COD_2023, GRG_2021, XYZ, compare, distance, sp3_times_utc

from gnss_citygml.errors import InputError
from gnss_citygml.gnss.gpstime import gps_seconds, gps_to_utc
from gnss_citygml.gnss.orbits import Sp3Orbits
from gnss_citygml.gnss.sp3 import read_sp3


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
            got = orbits.positions(sp3_times_utc(truth), truth["constellation"], truth["svid"])
            err = distance(got, truth[XYZ])
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
        sp3_times_utc(truth), truth["constellation"], truth["svid"]
    )
    assert distance(got, truth[XYZ]).max() < 0.1


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
    diff = compare(Sp3Orbits(cod).positions_all(times, "GR"), grg.positions_all(times, "GR"))
    print(f"COD vs GRG (GPS+GLONASS, {diff.size} positions): max {diff.max():.3f} m")
    assert diff.size > 2500 and diff.max() < 0.5


def test_gps_seconds_of_the_sp3_start(cod):
    # 2021-04-28 18:00 GPST = week 2155, 3 d 18 h.
    assert gps_seconds(cod["time_gps"].iloc[:1])[0] == 2155 * 604800 + 3 * 86400 + 18 * 3600


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
