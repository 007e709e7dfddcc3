"""Fuzzing the GNSS readers: GnssLogger logs, SP3 orbits, RINEX 2 and 3 navigation files.

Seeds are cut at test time from the reference data, at record boundaries so that each
seed is a valid file: the first 150 lines of GnssLogger logs of five versions (1.4, 2.0.0.1,
2.0.4.2, 3.0.6.4, "Not Available"), the header and a few epochs of SP3-c and SP3-d files, the
header and a few records per system of RINEX 2 and RINEX 3 navigation files. Every case must
end as a result that keeps the reader's promises or as one :class:`GnssCityGMLError` line, and
every warning is one line too (the command line prints each as one ``warning:`` line).
"""

from __future__ import annotations

import tempfile
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import event, given
from hypothesis import strategies as st

from gnss_citygml.gnss.gnsslogger import read_gnsslogger
from gnss_citygml.gnss.navigation import read_nav
from gnss_citygml.gnss.orbits import load_orbits
from gnss_citygml.gnss.sp3 import read_sp3

from .conftest import mutated

LOGS = (
    "google_demo_pseudoranges_log_2016_06_30_21_26_07.txt",  # 1.4.0.0
    "london_ucl_2020-02-11_SM-G973F_gnss_log.txt",  # v2.0.0.1
    "gsdc2021_mtv_2020-05-14_Pixel4_GnssLog_excerpt.txt",  # v2.0.4.2, Status rows
    "stanford_2023-11-07_Pixel7_gnss_log.txt",  # v3.0.6.4, sensor rows
    "gsdc2023_2023-09-07_Pixel7Pro_gnss_log_excerpt.txt",  # "Not Available"
)
LOG_LINES = 150
#: SP3 files and how many epochs of how many satellites each seed keeps.
SP3 = {
    "COD0OPSRAP_20230730000_01D_05M_ORB.SP3": (2, 8),  # SP3-c, GPS/GLONASS/Galileo
    "grg21553.sp3": (2, 8),  # SP3-c, GPS/GLONASS
    "COD0MGXFIN_20211180000_01D_05M_ORB.SP3": (2, 12),  # SP3-d, five systems
}
#: Enough SP3 epochs for the 10-point interpolation: the seed of the orbit source test.
SP3_SOURCE = ("COD0MGXFIN_20211180000_01D_05M_ORB.SP3", 12, 3)
#: Navigation files and how many records of each system a seed keeps.
NAV = {
    "brdc1350.20n": 4,  # RINEX 2 GPS
    "BRDM00DLR_S_20230730000_01D_MN.rnx": 2,  # RINEX 3.04 mixed, SBAS and NavIC too
}


class _Seed(bytes):
    """A seed file's bytes, shown in reports by name and size only."""

    def __new__(cls, data: bytes, name: str):
        seed = super().__new__(cls, data)
        seed.name = name
        return seed

    def __repr__(self) -> str:
        return f"<seed {self.name}: {len(self)} bytes>"


def _text(path: Path) -> str:
    return path.read_text(encoding="ascii", errors="strict")


@pytest.fixture(scope="module")
def log_seeds(shared_data) -> list[bytes]:
    """The first lines of each log, read as they are (a warning at most)."""
    seeds = []
    for name in LOGS:
        lines = (shared_data / "gnss" / name).read_bytes().split(b"\n")[:LOG_LINES]
        seed = b"\n".join(lines) + b"\n"
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            assert len(_read_log(seed, lenient=True).raw) > 0
        seeds.append(_Seed(seed, name))
    return seeds


def _read_log(data: bytes, **options):
    with tempfile.TemporaryDirectory() as name:
        path = Path(name) / "gnss_log.txt"
        path.write_bytes(data)
        return read_gnsslogger(path, **options)


def _sp3_seed(text: str, epochs: int, satellites: int) -> bytes:
    """The header and the first ``epochs`` epochs (the first ``satellites`` records each)."""
    lines = text.splitlines()
    starts = [k for k, line in enumerate(lines) if line.startswith("*")]
    kept = lines[: starts[0]]
    for start, end in zip(starts[:epochs], starts[1 : epochs + 1], strict=True):
        kept += [lines[start]] + lines[start + 1 : end][:satellites]
    return ("\n".join(kept + ["EOF"]) + "\n").encode()


def _nav_seed(text: str, per_system: int) -> bytes:
    """The header and the first ``per_system`` records of each system. A record starts with a
    line whose first columns are not blank; its continuation lines start with blanks."""
    lines = text.splitlines()
    body = next(k for k, line in enumerate(lines) if "END OF HEADER" in line) + 1
    records: list[list[str]] = []
    for line in lines[body:]:
        if line[:3].strip():
            records.append([line])
        elif records:
            records[-1].append(line)
    taken: dict[str, int] = {}
    kept = lines[:body]
    for record in records:
        system = record[0][0] if record[0][0].isalpha() else "G"
        if taken.get(system, 0) < per_system:
            taken[system] = taken.get(system, 0) + 1
            kept += record
    return ("\n".join(kept) + "\n").encode()


@pytest.fixture(scope="module")
def sp3_seeds(repo_data) -> list[bytes]:
    seeds = []
    for name, (epochs, satellites) in SP3.items():
        seed = _sp3_seed(_text(repo_data / "orbits" / name), epochs, satellites)
        assert len(_read_file(read_sp3, seed, "seed.sp3")) == epochs * satellites
        seeds.append(_Seed(seed, name))
    return seeds


@pytest.fixture(scope="module")
def sp3_source_seed(repo_data) -> bytes:
    name, epochs, satellites = SP3_SOURCE
    seed = _sp3_seed(_text(repo_data / "orbits" / name), epochs, satellites)
    assert len(_read_file(_orbits_in_use, seed, "seed.sp3")) == satellites
    return _Seed(seed, name)


@pytest.fixture(scope="module")
def nav_seeds(repo_data) -> list[bytes]:
    seeds = []
    for name, per_system in NAV.items():
        seed = _nav_seed(_text(repo_data / "orbits" / name), per_system)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            assert len(_read_file(_orbits_in_use, seed, name)) > 0
        seeds.append(_Seed(seed, name))
    return seeds


def _read_file(reader, data: bytes, name: str):
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / name
        path.write_bytes(data)
        return reader(path)


def _orbits_in_use(path: Path):
    """Read orbit files as ``observe`` does, then ask for every satellite at mid-span."""
    orbits = load_orbits([path])
    first, last = orbits.span
    return orbits.positions_all([first + (last - first) / 2])


def _one_line_warnings(record) -> None:
    for warning in record:
        assert "\n" not in str(warning.message), f"not one line: {warning.message!r}"


def _outcome(result, what: str = ""):
    """``result``, counted in hypothesis' statistics as a result or a one-line error."""
    event(f"{what}{'result' if result is not None else 'one-line error'}")
    return result


# --- GnssLogger -------------------------------------------------------------------------------


def _check_log(log) -> None:
    """A read log keeps the reader's promises: signals with a time and a plausible C/N0,
    fixes with a position on the globe."""
    if log is None:
        return
    assert not log.raw["time_utc"].isna().any()
    assert log.raw["cn0"].between(0.0, 100.0).all()
    assert set(log.raw["constellation"]) <= set("GRJCESI")
    assert (log.dropped["reason"] != "").all()
    assert log.fixes["lat"].between(-90.0, 90.0).all()
    assert log.fixes["lon"].between(-180.0, 180.0).all()
    assert not log.fixes["time_utc"].isna().any()


@given(data=st.data())
def test_gnsslogger(data, log_seeds, clean):
    seed = data.draw(st.sampled_from(log_seeds), label="log")
    raw = data.draw(mutated(seed), label="bytes")
    lenient = data.draw(st.booleans(), label="lenient")
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        _check_log(_outcome(clean(_read_log, raw, lenient=lenient)))
    _one_line_warnings(record)


# --- SP3 --------------------------------------------------------------------------------------


@given(data=st.data())
def test_sp3(data, sp3_seeds, clean):
    seed = data.draw(st.sampled_from(sp3_seeds), label="sp3")
    table = _outcome(
        clean(_read_file, read_sp3, data.draw(mutated(seed), label="bytes"), "orbit.sp3")
    )
    if table is not None:
        assert not table["time_gps"].isna().any()
        xyz = table[["x", "y", "z"]].to_numpy()
        assert (np.isfinite(xyz) | np.isnan(xyz)).all()


@given(data=st.data())
def test_sp3_orbit_source(data, sp3_source_seed, clean):
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        sky = _outcome(
            clean(_read_file, _orbits_in_use, data.draw(mutated(sp3_source_seed)), "orbit.sp3")
        )
    _one_line_warnings(record)
    if sky is not None:
        assert np.isfinite(sky[["x", "y", "z"]].to_numpy()).all()


# --- RINEX navigation ---------------------------------------------------------------------------


@given(data=st.data())
def test_rinex_nav(data, nav_seeds, clean):
    k = data.draw(st.sampled_from(range(len(nav_seeds))), label="nav")
    raw = data.draw(mutated(nav_seeds[k]), label="bytes")
    name = list(NAV)[k]
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        sky = None
        if _outcome(clean(_read_file, read_nav, raw, name), "read: ") is not None:
            sky = _outcome(clean(_read_file, _orbits_in_use, raw, name), "sky: ")
    _one_line_warnings(record)
    if sky is not None:
        assert np.isfinite(sky[["x", "y", "z"]].to_numpy()).all()
