"""Shared fixtures: small datasets drawn from known curves and simulated scenes, and the
reference data.

Reference data comes from two places: ``tests/data`` (small public files, in the repository)
and the project's shared data folder beside the clone (``../shared/data``, or
``$GNSS_CITYGML_SHARED_DATA``), which holds what may not or need not be in the repository (OS
MasterMap, larger logs and orbits, schemas). A test that needs the shared folder is marked
``shared_data``; without the folder it is skipped and the run ends with one line saying how
many did not run. With ``$CI`` set, missing shared data is a failure, never a skip.
"""

import functools
import json
import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path
from typing import NoReturn

import numpy as np
import pandas as pd
import pytest

import gnss_citygml
from gnss_citygml.errors import InputError
from gnss_citygml.geodesy.grids import BUNDLED_GRID_DIR, GRID_DIR_ENV, GridError, grid_status
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
def orbits_dir(repo_data) -> Path:
    return repo_data / "orbits"


@pytest.fixture(scope="session")
def cod(orbits_dir) -> pd.DataFrame:
    """CODE's final multi-GNSS orbits of 2021-04-28, 18:00 to 24:00 (SP3-d)."""
    return read_sp3(orbits_dir / COD_2021)


@pytest.fixture(scope="session")
def gfz(shared_data) -> pd.DataFrame:
    """GFZ's rapid multi-GNSS orbits of the whole of 2025-11-16 (SP3-d): only in the shared
    data (no licence stated where it was found), as is brdc3200.25n of the same day."""
    return read_sp3(shared_data / "orbits" / GFZ_2025)


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


# --- reference data: tests/data and the shared data folder ------------------------------------

#: The project's reference data beside the repository: real logs, orbits, OS MasterMap, schemas.
SHARED_DATA_ENV = "GNSS_CITYGML_SHARED_DATA"
SHARED_DATA = Path(
    os.environ.get(SHARED_DATA_ENV) or Path(__file__).resolve().parents[2] / "shared" / "data"
)
#: Small public reference data kept in the repository (sources and licences: data/README.md).
REPO_DATA = Path(__file__).resolve().parent / "data"
#: How to give a run the shared data, for the messages below.
HOW_TO_GET = (
    "put the project's shared folder beside this clone (../shared/data) "
    f"or set ${SHARED_DATA_ENV} to its data folder"
)
#: Starts the reason of every test left out for lack of shared data (counted at the end).
LACKING = "needs the shared data"


def in_ci() -> bool:
    """True under continuous integration (``$CI`` set, as CI services do): data must be there."""
    return os.environ.get("CI", "").strip().lower() not in ("", "0", "false", "no")


def lacking(what: str) -> NoReturn:
    """Leave out the running test for lack of shared data: a skip, or under CI a failure."""
    if in_ci():
        pytest.fail(
            f"{LACKING}: {what}; with $CI set this is a failure: {HOW_TO_GET}", pytrace=False
        )
    pytest.skip(f"{LACKING}: {what}")


class SharedPath(type(Path())):
    """A path in the shared data folder: joining a name that is not there leaves the test out
    (:func:`lacking`), so an incomplete folder never lets a test pass on a missing file."""

    def __truediv__(self, name):
        path = super().__truediv__(name)
        if not path.exists():
            lacking(f"{path} is missing")
        return path


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """The project's reference data (``../shared/data`` or ``$GNSS_CITYGML_SHARED_DATA``).

    A test using it is marked ``shared_data`` (:func:`pytest_collection_modifyitems`) and does
    not run without the folder; a file missing from the folder leaves the test out too."""
    if not SHARED_DATA.is_dir():
        lacking(f"no folder {SHARED_DATA}")
    return SharedPath(SHARED_DATA)


@pytest.fixture(scope="session")
def repo_data() -> Path:
    """The reference data kept in the repository (``tests/data``, laid out as the shared)."""
    return REPO_DATA


@pytest.fixture
def reference_data(request) -> Path:
    """The reference data of one test: ``tests/data``, or for a test marked ``shared_data``
    the shared folder (which holds every file of ``tests/data`` too). A test parametrized over
    files of both marks the parameters whose files are only in the shared folder:
    ``pytest.param(name, marks=pytest.mark.shared_data)``."""
    if request.node.get_closest_marker("shared_data"):
        return request.getfixturevalue("shared_data")
    return REPO_DATA


@functools.cache
def grids_found_by_default() -> bool:
    """The toolkit, given no folder, finds the OSTN15/OSGM15 grids (PROJ's user folder, the
    copies bundled with the package...)."""
    try:
        return bool(grid_status()["found"].all())
    except GridError:  # e.g. $GNSS_CITYGML_GRID_DIR names no folder
        return False


@pytest.fixture(scope="session")
def grid_dir(request) -> Path | None:
    """The grid folder for a test that transforms coordinates: None (the toolkit's own grid
    discovery, as for a user) when that finds the grids, else the shared data's copies."""
    if grids_found_by_default():
        return None
    return request.getfixturevalue("shared_data") / "geodesy"


@pytest.fixture(scope="session")
def grid_args(grid_dir) -> list[str]:
    """:func:`grid_dir` as command-line options: none, or ``--grid-dir FOLDER``."""
    return [] if grid_dir is None else ["--grid-dir", str(grid_dir)]


def needs_shared_data(item) -> bool:
    """A test needs the shared data: marked so, or using :func:`shared_data` (directly or
    through other fixtures), or :func:`grid_dir` when only the shared folder has the grids."""
    names = getattr(item, "fixturenames", ())
    return (
        item.get_closest_marker("shared_data") is not None
        or "shared_data" in names
        or ("grid_dir" in names and not grids_found_by_default())
    )


def pytest_collection_modifyitems(config, items):
    """Mark the tests that need the shared data; without the folder skip them, or under CI
    stop the run before any test with one message."""
    needing = [item for item in items if needs_shared_data(item)]
    for item in needing:
        item.add_marker(pytest.mark.shared_data)
    if not needing or SHARED_DATA.is_dir():
        return
    if in_ci():
        pytest.exit(
            f"NO SHARED DATA: {len(needing)} tests need the shared data folder {SHARED_DATA}, "
            f"which does not exist; with $CI set they must run, not skip: {HOW_TO_GET}",
            returncode=pytest.ExitCode.USAGE_ERROR,
        )
    skip = pytest.mark.skip(reason=f"{LACKING}: no folder {SHARED_DATA}")
    for item in needing:
        item.add_marker(skip)


def _reason(report) -> str:
    longrepr = report.longrepr
    return longrepr[2] if isinstance(longrepr, tuple) else str(longrepr)


@pytest.hookimpl(wrapper=True, tryfirst=True)
def pytest_terminal_summary(terminalreporter):
    """One loud line last (before the counts): how many tests did not run for lack of shared
    data, why, and how to run them."""
    result = yield
    reasons = [_reason(r) for r in terminalreporter.stats.get("skipped", [])]
    lacks = [r.split(f"{LACKING}: ", 1)[1] for r in reasons if f"{LACKING}: " in r]
    if lacks:
        why = sorted(set(lacks))
        shown = "; ".join(why[:3]) + (f"; and {len(why) - 3} more" if len(why) > 3 else "")
        n = len(lacks)
        tests, them = ("TEST", "it") if n == 1 else ("TESTS", "them")
        terminalreporter.write_sep(
            "!",
            f"{n} {tests} DID NOT RUN FOR LACK OF THE SHARED DATA ({shown}): to run {them}, "
            + HOW_TO_GET,
            red=True,
            bold=True,
        )
    return result


# --- geodesy: the OS test points, fresh interpreters, an install without its grids ----------


@pytest.fixture(scope="session")
def os_points(repo_data):
    """The OS test inputs and expected outputs of both directions, one row per point."""
    vectors = repo_data / "geodesy"
    etrs = pd.read_csv(vectors / "OSTN15_OSGM15_TestInput_ETRStoOSGB.txt")
    etrs.columns = ["point", "lat", "lon", "h"]
    osgb = pd.read_csv(vectors / "OSTN15_OSGM15_TestOutput_ETRStoOSGB.txt").iloc[:, :5]
    osgb.columns = ["point", "e", "n", "odn", "flag"]
    back_in = pd.read_csv(vectors / "OSTN15_OSGM15_TestInput_OSGBtoETRS.txt")
    back_in.columns = ["point", "e_in", "n_in", "odn_in"]
    back = pd.read_csv(vectors / "OSTN15_OSGM15_TestOutput_OSGBtoETRS.txt").iloc[:, :5]
    back.columns = ["point", "step", "lat_out", "lon_out", "h_out"]
    back = back[back["step"] == "RESULT"].drop(columns="step")
    table = etrs.merge(osgb, on="point").merge(back_in, on="point").merge(back, on="point")
    assert len(table) == 40
    return table


@pytest.fixture(scope="session")
def unbundled(tmp_path_factory):
    """A folder holding the package without its bundled grids (an install that lost them), for
    a fresh interpreter's PYTHONPATH: only then is a grid found nowhere."""
    site = tmp_path_factory.mktemp("unbundled")
    package = Path(gnss_citygml.__file__).parent
    shutil.copytree(
        package,
        site / "gnss_citygml",
        ignore=lambda folder, names: (
            ["grids"] if Path(folder) == BUNDLED_GRID_DIR.parent else ["__pycache__"]
        ),
    )
    return site


def fresh_env(tmp_path, endpoint=None, package=None):
    """The environment of a fresh interpreter whose home is the empty ``tmp_path/home`` and PROJ
    user directory the empty ``tmp_path/user`` (so grids fetched on this machine do not count),
    without $GNSS_CITYGML_GRID_DIR and, if given, with another CDN endpoint and the package
    imported from the folder ``package`` (:func:`unbundled`). No grid folder is on its PROJ
    search path at the start, as for a user's run (in this process, earlier tests added some)."""
    (tmp_path / "home").mkdir(parents=True, exist_ok=True)
    env = dict(
        os.environ,
        HOME=str(tmp_path / "home"),
        PROJ_USER_WRITABLE_DIRECTORY=str(tmp_path / "user"),
    )
    for name in (GRID_DIR_ENV, "XDG_DATA_HOME", "PYTHONPATH"):
        env.pop(name, None)
    if endpoint:
        env["PROJ_NETWORK_ENDPOINT"] = endpoint
    if package:
        env["PYTHONPATH"] = str(package)
    return env


def isolated(code, tmp_path, endpoint=None, package=None):
    """Run ``code`` in a fresh interpreter (:func:`fresh_env`); its printed lines. With
    ``package``, the first line is checked to be the package's folder and left out."""
    code = textwrap.dedent(code)
    if package:
        code = "import gnss_citygml; print(gnss_citygml.__file__)\n" + code
    run = subprocess.run(
        [sys.executable, "-c", code],
        env=fresh_env(tmp_path, endpoint, package),
        capture_output=True,
        text=True,
        check=True,
        cwd=tmp_path,
    )
    lines = run.stdout.splitlines()
    if package:
        assert Path(lines.pop(0)).is_relative_to(package)
    return lines


def commands(runs, tmp_path, package=None):
    """Several ``gnss-citygml`` runs (argument lists) in one fresh interpreter
    (:func:`fresh_env`): (exit code, stdout, stderr) of each."""
    code = f"""
        import contextlib, io, json
        from gnss_citygml.cli import main
        results = []
        for args in {[[str(a) for a in args] for args in runs]!r}:
            out, err = io.StringIO(), io.StringIO()
            with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
                try:
                    main(args)
                except SystemExit as exit_:
                    results.append((exit_.code, out.getvalue(), err.getvalue()))
        print(json.dumps(results))
    """
    (line,) = isolated(code, tmp_path, package=package)
    return json.loads(line)


@pytest.fixture(scope="module")
def engine():
    """A local Dask cluster of two worker processes (the ``[dask]`` extra), for a module's
    runs in tiles."""
    from gnss_citygml.settings import Tiling
    from gnss_citygml.tiling.cluster import connect

    with connect(Tiling("local", workers=2)) as engine:
        yield engine


@pytest.fixture(scope="session")
def node_dir():
    """Khronos' glTF validator, installed when missing (``$GNSS_CITYGML_NODE_DIR`` or the
    user's cache folder)."""
    from gnss_citygml.validate import install_gltf_validator

    try:
        return install_gltf_validator()
    except InputError as exc:
        message = f"needs Khronos' glTF validator, which could not be installed: {exc}"
        if in_ci():
            pytest.fail(f"{message}; with $CI set this is a failure", pytrace=False)
        pytest.skip(message)


@pytest.fixture(scope="session")
def tiles3d_schema_dir(shared_data):
    """The official 3D Tiles 1.1 JSON schemas, in the shared data."""
    return shared_data / "schemas" / "3dtiles-1.1"
