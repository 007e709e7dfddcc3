"""Shared fixtures: small datasets drawn from known curves and simulated scenes."""

import os
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from gnss_citygml.gnss.gpstime import gps_to_utc
from gnss_citygml.gnss.sp3 import read_sp3
from gnss_citygml.model.fourpl import logistic4


def draw_4pl(rng, n, a, b, c, d, lo=0.0, hi=60.0):
    """Heights uniform in [lo, hi] and labels drawn from a known 4PL."""
    x = rng.uniform(lo, hi, n)
    y = rng.random(n) < logistic4(x, a, b, c, d)
    return x, y


def synthetic_intersections(rng, truth=45.0, n=4000, building="b1", blocked=0.4, noise=1.0):
    """A building crossed at heights 20-80 m: open signals strong, closed weak or blocked."""
    h = rng.uniform(20.0, 80.0, n)
    is_open = h + rng.normal(0.0, noise, n) > truth
    cn0 = np.where(is_open, rng.normal(40.0, 4.0, n), rng.normal(25.0, 5.0, n))
    cn0[~is_open & (rng.random(n) < blocked)] = np.nan
    cn0[cn0 < 12.0] = np.nan
    return pd.DataFrame({"building": building, "height": h, "cn0": cn0})


SHARED_DATA = Path(
    os.environ.get(
        "GNSS_CITYGML_SHARED_DATA", Path(__file__).resolve().parents[2] / "shared" / "data"
    )
)


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """The project's reference data (``../shared/data`` or ``$GNSS_CITYGML_SHARED_DATA``).

    Missing data fails the test run instead of skipping it: CI always has it."""
    if not SHARED_DATA.is_dir():
        pytest.fail(f"reference data not found at {SHARED_DATA}: set GNSS_CITYGML_SHARED_DATA")
    return SHARED_DATA


@pytest.fixture
def rng():
    return np.random.default_rng(12345)


def occluded_pair(rng, n=6000, front=30.0, back=20.0, alone=0.4):
    """Rays crossing a tall building ``A`` and then a lower one ``B`` behind it, plus rays that
    cross ``B`` alone. A signal is open only if it clears both roofs it crosses."""
    rows = []
    for k in range(n):
        if rng.random() < alone:
            hb = rng.uniform(5.0, 45.0)
            rows.append((k, "B", hb, 0, hb > back))
            continue
        ha = rng.uniform(5.0, 60.0)
        hb = ha + rng.uniform(5.0, 25.0)  # the ray keeps rising on its way to B
        is_open = ha > front and hb > back
        rows.append((k, "A", ha, 0, is_open))
        rows.append((k, "B", hb, 1, is_open))
    sig, bld, h, order, is_open = map(np.array, zip(*rows, strict=True))
    per_signal = {s: o for s, o in zip(sig, is_open, strict=True)}
    strength = {
        s: rng.normal(41.0, 4.0) if o else rng.normal(24.0, 5.0) for s, o in per_signal.items()
    }
    cn0 = np.array([strength[s] for s in sig])
    cn0[cn0 < 12.0] = np.nan
    return pd.DataFrame({"signal": sig, "building": bld, "height": h, "order": order, "cn0": cn0})


# --- orbit files, and the helpers of test_sp3, test_propagation and test_orbits -----------------

COD_2021 = "COD0MGXFIN_20211180000_01D_05M_ORB.SP3"
GRG_2021 = "grg21553.sp3"
GFZ_2025 = "GFZ0MGXRAP_20253200000_01D_05M_ORB.SP3"
COD_2023 = "COD0OPSRAP_20230730000_01D_05M_ORB.SP3"
BRDM_2023 = "BRDM00DLR_S_20230730000_01D_MN.rnx"
XYZ = ["x", "y", "z"]


@pytest.fixture(scope="session")
def orbits_dir(shared_data) -> Path:
    return shared_data / "orbits"


@pytest.fixture(scope="session")
def cod(orbits_dir) -> pd.DataFrame:
    """CODE's final multi-GNSS orbits of 2021-04-28, 18:00 to 24:00 (SP3-d)."""
    return read_sp3(orbits_dir / COD_2021)


@pytest.fixture(scope="session")
def gfz(orbits_dir) -> pd.DataFrame:
    """GFZ's rapid multi-GNSS orbits of the whole of 2025-11-16 (SP3-d)."""
    return read_sp3(orbits_dir / GFZ_2025)


def sp3_times_utc(table: pd.DataFrame) -> np.ndarray:
    """The UTC times of the rows of an SP3 table."""
    return gps_to_utc(table["time_gps"].to_numpy())


def distance(a, b) -> np.ndarray:
    """The distance between two sets of positions, row by row."""
    return np.linalg.norm(np.asarray(a) - np.asarray(b), axis=1)


def compare(precise: pd.DataFrame, broadcast: pd.DataFrame) -> np.ndarray:
    """The distances between two ``positions_all`` tables at the rows they share."""
    both = precise.merge(broadcast, on=["time_utc", "constellation", "svid"])
    return distance(both[["x_x", "y_x", "z_x"]], both[["x_y", "y_y", "z_y"]])
