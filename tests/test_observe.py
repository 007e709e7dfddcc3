"""Logs + orbits -> observations, checked against Google's satellite positions and the phone."""

import re

import numpy as np
import pandas as pd
import pytest
from test_cli import run

from gnss_citygml.cli import main
from gnss_citygml.errors import InputError
from gnss_citygml.gnss.gnsslogger import read_gnsslogger
from gnss_citygml.gnss.gpstime import gps_to_utc
from gnss_citygml.gnss.observe import observe
from gnss_citygml.gnss.orbits import OrbitSpanError, load_orbits
from gnss_citygml.gnss.positions import ACCURACY_PER_SD
from gnss_citygml.gnss.sky import azimuth_elevation
from gnss_citygml.observations import OBSERVATION_COLUMNS, check_observations

DEMO_2016 = "google_demo_pseudoranges_log_2016_08_22_14_45_50.txt"


def separation(az1, el1, az2, el2):
    """Angle (deg) between two sky directions: the metric that does not blow up near zenith."""
    az1, el1, az2, el2 = map(np.radians, (az1, el1, az2, el2))
    cos = np.sin(el1) * np.sin(el2) + np.cos(el1) * np.cos(el2) * np.cos(az1 - az2)
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def test_orbit_sky_matches_googles_derived_positions(repo_data):
    """Azimuth and elevation from the broadcast orbits vs from Google's own satellite positions
    for the same GPS satellites at the same (transmission) times, seen from the ground truth:
    within 0.01 deg. (The file's ``millisSinceGpsEpoch`` labels are ~1 s off its positions.)"""
    gnss = repo_data / "gnss"
    derived = pd.read_csv(gnss / "gsdc2021_mtv_2020-05-14_Pixel4_derived_excerpt.csv")
    derived = derived[derived["signalType"] == "GPS_L1"]
    truth = pd.read_csv(gnss / "gsdc2021_mtv_2020-05-14_Pixel4_ground_truth_excerpt.csv").iloc[0]
    sent = derived["receivedSvTimeInGpsNanos"] - derived["satClkBiasM"] / 299792458.0 * 1e9
    times = gps_to_utc(np.round(sent.to_numpy()).astype(np.int64))
    orbits = load_orbits([repo_data / "orbits" / "brdc1350.20n"])
    ours = orbits.positions(times, "G", derived["svid"].to_numpy())
    place = (truth["latDeg"], truth["lngDeg"], truth["heightAboveWgs84EllipsoidM"])
    google = derived[["xSatPosM", "ySatPosM", "zSatPosM"]].to_numpy()
    assert len(derived) >= 50
    assert np.linalg.norm(ours - google, axis=1).max() < 0.1
    assert (
        separation(*azimuth_elevation(*place, ours), *azimuth_elevation(*place, google)).max()
        < 0.01
    )


def test_google_positions_match_the_phones_status_angles(repo_data):
    """The phone's own (whole-degree) Status directions of its Galileo satellites vs those from
    Google's positions: within 2 deg. (No Galileo orbits exist for that day here.)"""
    gnss = repo_data / "gnss"
    with pytest.warns(UserWarning, match="skipped 1 bad line"):  # its corrupted Fix altitude
        log = read_gnsslogger(
            gnss / "gsdc2021_mtv_2020-05-14_Pixel4_GnssLog_excerpt.txt", lenient=True
        )
    derived = pd.read_csv(gnss / "gsdc2021_mtv_2020-05-14_Pixel4_derived_excerpt.csv")
    first = derived[derived["millisSinceGpsEpoch"] == derived["millisSinceGpsEpoch"].min()]
    galileo = first[first["constellationType"] == 6].drop_duplicates("svid").set_index("svid")
    truth = pd.read_csv(gnss / "gsdc2021_mtv_2020-05-14_Pixel4_ground_truth_excerpt.csv").iloc[0]
    status = log.status[log.status["band"] == "L1"].set_index("svid")
    both = status.index.intersection(galileo.index)
    assert len(both) >= 5
    az, el = azimuth_elevation(
        truth["latDeg"],
        truth["lngDeg"],
        truth["heightAboveWgs84EllipsoidM"],
        galileo.loc[both, ["xSatPosM", "ySatPosM", "zSatPosM"]].to_numpy(),
    )
    phone = status.loc[both, "azimuth"].to_numpy(), status.loc[both, "elevation"].to_numpy()
    assert separation(az, el, *phone).max() < 2.0


@pytest.fixture(scope="module")
def demo_observations(repo_data):
    with pytest.warns(UserWarning, match="without orbit data"):
        return observe([repo_data / "gnss" / DEMO_2016], [repo_data / "orbits" / "hour2350.16n"])


def test_observations_of_a_real_log(repo_data, demo_observations):
    obs = demo_observations
    assert list(obs.columns) == OBSERVATION_COLUMNS
    check_observations(obs)  # the schema holds
    log = read_gnsslogger(repo_data / "gnss" / DEMO_2016)
    gps = log.raw[(log.raw["constellation"] == "G") & (log.raw["band"] == "L1")]
    assert obs["time_utc"].nunique() == log.epochs.size == 207
    assert set(obs["constellation"]) == {"G"}  # the nav file has GPS only
    assert obs["elevation"].between(10.0, 85.0).all()
    # every received GPS signal in view is a row with its C/N0; the rest are blocked rows
    received = obs.dropna(subset=["cn0"])
    merged = received.merge(gps, on=["time_utc", "constellation", "svid"], suffixes=("", "_raw"))
    assert len(merged) == len(received)
    np.testing.assert_array_equal(merged["cn0"], merged["cn0_raw"])
    assert obs["cn0"].isna().sum() > 0
    assert obs["receiver"].unique().tolist() == [DEMO_2016.removesuffix(".txt")]
    # how far each position may be off: the phone's own accuracy of its fix, per axis
    fixes = log.fixes[log.fixes["provider"] == "gps"]
    assert obs["position_sd"].notna().all()
    assert obs["position_sd"].isin(fixes["accuracy"] / ACCURACY_PER_SD).all()


def test_mask_changes_the_rows(repo_data, demo_observations):
    with pytest.warns(UserWarning):
        high = observe(
            [repo_data / "gnss" / DEMO_2016],
            [repo_data / "orbits" / "hour2350.16n"],
            min_elevation=30.0,
        )
    assert 0 < len(high) < len(demo_observations)
    assert high["elevation"].min() >= 30.0


def test_orbits_not_covering_the_log(repo_data):
    with pytest.raises(OrbitSpanError, match="2016-08-22"):
        observe([repo_data / "gnss" / DEMO_2016], [repo_data / "orbits" / "hour1820.16n"])


def test_empty_mask_is_an_error(repo_data):
    with pytest.raises(InputError, match="elevation mask"):
        observe(
            [repo_data / "gnss" / DEMO_2016],
            [repo_data / "orbits" / "hour2350.16n"],
            min_elevation=50.0,
            max_elevation=40.0,
        )


# --- from the user's side: a log cut anywhere, outputs never replaced silently (issue 10) -----

DEMO_JUNE = "google_demo_pseudoranges_log_2016_06_30_21_26_07.txt"
ISO_TIME = re.compile(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\.\d{3}Z")


def _observe(args, capsys):
    """``gnss-citygml observe ARGS -q``: (exit code, stdout, the ``warning:`` lines, stderr)."""
    code, out, err = run(["observe", *map(str, args), "-q"], capsys)
    return code, out, [line for line in err.splitlines() if line.startswith("warning:")], err


@pytest.fixture(scope="module")
def june(repo_data, tmp_path_factory):
    """The June 2016 demo log, its observations through the command, and where its last epoch
    starts (with the TimeNanos of the epoch before)."""
    folder = tmp_path_factory.mktemp("june")
    log = repo_data / "gnss" / DEMO_JUNE
    nav = repo_data / "orbits" / "hour1820.16n"
    with pytest.raises(SystemExit) as exc:
        main(["observe", str(log), "--orbits", str(nav), "-o", str(folder / "full.parquet"), "-q"])
    assert exc.value.code == 0
    data = log.read_bytes()
    # (offset, TimeNanos) of every Raw row: the clock its epoch's rows share
    rows = [(m.start(), m.group(1)) for m in re.finditer(rb"^Raw,[^,]*,([^,]*),", data, re.M)]
    start = min(offset for offset, clock in rows if clock == rows[-1][1])
    before = next(clock for offset, clock in reversed(rows) if offset < start)
    full = pd.read_parquet(folder / "full.parquet")
    return dict(data=data, nav=nav, full=full, start=start, clock_before=before)


def _cut_offsets(june) -> list[int]:
    """Byte offsets inside the last epoch: every 4th of its first row's clock fields, at and
    just after the line end of every row but the last, and a few spread over the rest."""
    data, start = june["data"], june["start"]
    ends = [start + k for k, byte in enumerate(data[start:]) if byte == ord("\n")][:-2]
    spread = np.random.default_rng(10).integers(start, ends[-1], 6)
    return sorted({*range(start + 1, start + 60, 4), *ends, *(e + 1 for e in ends), *spread})


def test_a_log_cut_inside_its_last_epoch_reports_no_invented_blocked_signal(june, tmp_path, capsys):
    full = june["full"]
    epochs = sorted(full["time_utc"].unique())
    last, before = (pd.Timestamp(t) for t in epochs[-1:-3:-1])
    cut_log = tmp_path / DEMO_JUNE  # the same name: the same receiver
    for offset in _cut_offsets(june):
        cut_log.write_bytes(june["data"][:offset])
        out = tmp_path / f"cut_{offset}.parquet"
        code, _, warned, err = _observe([cut_log, "--orbits", june["nav"], "-o", out], capsys)
        assert code == 0, err
        table = pd.read_parquet(out)
        kept = full[full["time_utc"].isin(table["time_utc"].unique())].reset_index(drop=True)
        pd.testing.assert_frame_equal(table, kept)  # no received signal turned blocked
        missing = set(epochs) - set(table["time_utc"])
        assert len(warned) == 1 and str(cut_log) in warned[0], (offset, err)
        named = {pd.Timestamp(t) for t in ISO_TIME.findall(warned[0])}
        # a cut in the last epoch's first row: Raw,ElapsedRealtimeMillis,TimeNanos,LeapSecond,
        # TimeUncertaintyNanos,FullBiasNanos,...
        fields = june["data"][june["start"] : offset].split(b",")
        if "\n" in june["data"][june["start"] : offset].decode():
            assert missing == {last} and named == {last.floor("ms")}, (offset, warned)
        elif len(fields) < 3 or (len(fields) == 3 and june["clock_before"].startswith(fields[2])):
            # too little of its clock to tell it from the epoch before: both dropped
            assert missing == {last, before} and named == {before.floor("ms")}, (offset, warned)
            assert "may belong to" in warned[0]
        elif len(fields) < 7:  # a new epoch, but its FullBiasNanos is not there
            assert missing == {last} and not named and "begins a new epoch" in warned[0]
        else:
            assert missing == {last} and named == {last.floor("ms")}, (offset, warned)


def test_observe_refuses_an_existing_output_without_overwrite(june, tmp_path, capsys):
    out = tmp_path / "obs.csv"
    out.write_text("mine\n")
    missing_log = tmp_path / "no_such_log.txt"  # read after the output check, so not reached
    code, _, _, err = _observe([missing_log, "--orbits", june["nav"], "-o", out], capsys)
    assert code == 2
    assert err.strip() == f"error: output exists ({out}): choose another name or --overwrite"
    assert out.read_text() == "mine\n"
    log = tmp_path / DEMO_JUNE
    log.write_bytes(june["data"])
    code, stdout, _, err = _observe(
        [log, "--orbits", june["nav"], "-o", out, "--overwrite"], capsys
    )
    assert code == 0, err
    assert "1338 signals" in stdout
    assert len(pd.read_csv(out)) == 1338
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([DEMO_JUNE, "obs.csv"])


@pytest.mark.parametrize(
    ("name", "message"),
    [
        ("obs.xlsx", "error: unknown table format '.xlsx'"),
        ("nowhere/obs.csv", "error: output folder does not exist"),
    ],
)
def test_observe_checks_the_output_before_reading_the_logs(june, tmp_path, capsys, name, message):
    missing_log = tmp_path / "no_such_log.txt"
    out = tmp_path / name
    code, _, _, err = _observe([missing_log, "--orbits", june["nav"], "-o", out], capsys)
    assert code == 2 and err.startswith(message), err
    assert list(tmp_path.iterdir()) == []


def test_observe_help_offers_overwrite(capsys):
    code, out, _ = run(["observe", "--help"], capsys)
    assert code == 0
    assert "--overwrite" in out and "Replace an existing output." in out


@pytest.mark.parametrize(
    "mask",
    [
        ("--max-elevation", "400"),  # was accepted: every satellite above 10 deg kept
        ("--min-elevation", "-100"),
        ("--min-elevation", "nan"),
        ("--min-elevation", "50", "--max-elevation", "40"),
    ],
)
def test_observe_refuses_a_mask_that_is_no_band_of_elevations(june, tmp_path, capsys, mask):
    """The same physical range as estimate's (settings.check_elevation_mask), before any log
    or orbit file is read; nothing written."""
    log = tmp_path / DEMO_JUNE
    log.write_bytes(june["data"])
    out = tmp_path / "obs.parquet"
    code, _, _, err = _observe([log, "--orbits", june["nav"], "-o", out, *mask], capsys)
    assert code == 2 and err.startswith("error: elevation mask ") and err.count("\n") == 1, err
    assert "-90 <= min < max <= 90" in err and not out.exists()
