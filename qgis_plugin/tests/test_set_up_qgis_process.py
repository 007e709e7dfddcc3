"""Issue 32's test of set-up, through QGIS's own command line: from a fresh QGIS profile with the
plugin zip installed (``make plugin``'s, with the library's wheel inside), QGIS's Python without
the library and no GNSS_CITYGML_PYTHON, ``qgis_process run gnsscitygml:setup``, then
``gnsscitygml:estimate`` gives the command line's heights.

``qgis_process`` runs Debian's Python, which has no gnss-citygml (checked): the test's own
environment (.venv-qgis) is not on its path, nor anything of the test's variables (PYTHON*,
GNSS_CITYGML_*, QGIS_*); PATH is the system's, so set-up finds /usr/bin/python3, QGIS's own.

The environment set-up makes (about 800 MB on disk: numpy, scipy, pandas, pyarrow, and GDAL's
and PROJ's wheels) is kept between runs in ``~/.cache/gnss-citygml/qgis-setup-test``
(``$XDG_CACHE_HOME``), one per content of the library's wheel (its RECORD's digest), with pip's
own cache beside it: the profile's ``gnss-citygml`` folder is a link to it. The first run with
a library downloads its requirements (a minute or more); a later run with the same library
finds the environment there, and set-up upgrades it in place. Without a network on a first
run, the test is skipped with one loud line (in CI, it fails).
"""

import json
import os
import shutil
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import geopandas as gpd
import pytest
from conftest import ROOT, assert_same_heights, estimate_with_the_cli
from gnss_citygml_qgis.environment import MARKER, wheel_digest
from gnss_citygml_qgis.library import plugin_version

CACHE = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
CACHE = CACHE / "gnss-citygml" / "qgis-setup-test"

#: An environment another run used this recently is not removed (runs side by side).
IN_USE = 600


def loudly_skip(why):
    """Skip (fail in CI) with one line that cannot be missed."""
    message = f"!!! THE SET-UP TEST DID NOT RUN: {why} !!!"
    if os.environ.get("CI"):
        pytest.fail(message)
    print(f"\n{message}", file=sys.stderr)
    pytest.skip(message)


@pytest.fixture(scope="session")
def plugin_zip(tmp_path_factory):
    """``make plugin``'s zip, built here (its wheel from this repository)."""
    sys.path.insert(0, str(ROOT / "tools"))
    from build_plugin import build

    try:
        return build(tmp_path_factory.mktemp("dist"))
    except RuntimeError as exc:  # pip fetches the build backend from the index here
        loudly_skip(f"the library's wheel could not be built ({str(exc).strip()[-300:]})")


@pytest.fixture(scope="session")
def timings():
    """Seconds per step, printed at the end (run with -s to see them)."""
    steps = {}
    yield steps
    print("\nset-up test: " + ", ".join(f"{k} {v:.1f} s" for k, v in steps.items()))


@pytest.fixture
def fresh_qgis(tmp_path, plugin_zip):
    """A new profile with the plugin zip installed, and the environment for ``qgis_process``."""
    profile = tmp_path / "profile"
    default = profile / "profiles" / "default"
    plugins = default / "python" / "plugins"
    plugins.mkdir(parents=True)
    with zipfile.ZipFile(plugin_zip) as archive:
        archive.extractall(plugins)
    env = {
        name: value
        for name, value in os.environ.items()
        if not name.startswith(("PYTHON", "GNSS_CITYGML_", "QGIS_", "VIRTUAL_ENV", "PIP_CACHE"))
    }
    env.update(
        QGIS_CUSTOM_CONFIG_PATH=str(profile),
        XDG_CACHE_HOME=str(tmp_path / "cache"),
        XDG_CONFIG_HOME=str(tmp_path / "config"),
        XDG_RUNTIME_DIR=str(tmp_path / "runtime"),
        HOME=str(tmp_path / "home"),
        QT_QPA_PLATFORM="offscreen",
        PATH="/usr/bin:/bin",
        PIP_CACHE_DIR=str(CACHE / "pip"),
    )
    (wheel,) = (plugins / "gnss_citygml_qgis" / "wheels").glob("gnss_citygml-*.whl")
    return {"env": env, "profile": default, "wheel": wheel, "home": tmp_path / "home"}


def qgis_process(env, *args, check=True):
    process = subprocess.run(
        ["qgis_process.bin", *map(str, args)],
        capture_output=True,
        text=True,
        env=env,
        timeout=1800,
    )
    if check:
        assert process.returncode == 0, process.stdout[-3000:] + process.stderr[-3000:]
    return process


def cached_environment(wheel):
    """The cache's folder for this wheel's environment (others not used lately removed)."""
    folder = CACHE / f"env-{wheel_digest(wheel)[:16]}"
    for other in CACHE.glob("env-*"):
        used = other / "venv" / MARKER
        recent = used.exists() and time.time() - used.stat().st_mtime < IN_USE
        if other != folder and not recent:
            shutil.rmtree(other, ignore_errors=True)
    folder.mkdir(parents=True, exist_ok=True)
    return folder


def test_set_up_then_estimate_from_a_fresh_profile(fresh_qgis, scene, tmp_path, timings):
    env, profile = fresh_qgis["env"], fresh_qgis["profile"]
    without = subprocess.run(
        ["/usr/bin/python3", "-c", "import gnss_citygml"],
        env=env,
        cwd=tmp_path,
        capture_output=True,
    )
    assert without.returncode != 0, "QGIS's Python must not have the library for this test"
    qgis_process(env, "plugins", "enable", "gnss_citygml_qgis")
    assert "gnsscitygml:setup\tSet up gnss-citygml" in qgis_process(env, "list").stdout
    inputs = [
        f"OBSERVATIONS={scene['observations']}",
        f"FOOTPRINTS={scene['footprints']}",
        f"DEM={scene['dem']}",
    ]
    output = tmp_path / "heights.gpkg"
    refused = qgis_process(
        env, "run", "gnsscitygml:estimate", "--", *inputs, f"OUTPUT={output}", check=False
    )
    assert refused.returncode != 0
    assert (
        "the gnss-citygml library is missing from QGIS's Python: run Set up gnss-citygml"
        in refused.stdout + refused.stderr
    )

    cached = cached_environment(fresh_qgis["wheel"])
    (profile / "gnss-citygml").symlink_to(cached, target_is_directory=True)
    reused = (cached / "venv" / MARKER).exists()
    start = time.perf_counter()
    done = qgis_process(env, "--json", "run", "gnsscitygml:setup", check=False)
    said = done.stdout + done.stderr
    if done.returncode != 0 and "no network: " in said:
        loudly_skip("no network to install the library's requirements: " + said[-300:])
    assert done.returncode == 0, said[-3000:]
    timings[f"set-up {scene['name']} ({'reused' if reused else 'new'})"] = (
        time.perf_counter() - start
    )
    results = json.loads(done.stdout)["results"]
    folder = profile / "gnss-citygml" / "venv"
    assert results["ACTION"] in (("upgraded",) if reused else ("made", "remade"))
    assert results["FOLDER"] == str(folder)
    assert results["PYTHON"] == str(folder / "bin" / "python")
    assert results["BASE_PYTHON"] == "/usr/bin/python3"
    assert results["VERSION"] == plugin_version()

    start = time.perf_counter()
    done = qgis_process(
        env, "--json", "run", "gnsscitygml:estimate", "--", *inputs, f"OUTPUT={output}"
    )
    timings[f"estimate {scene['name']}"] = time.perf_counter() - start
    estimated = json.loads(done.stdout)["results"]
    theirs = estimate_with_the_cli(scene, tmp_path / "cli.gpkg")
    ours = gpd.read_file(output, layer="heights")
    assert estimated["CONVERGED"] == ours["converged"].sum() > 0
    assert_same_heights(ours, theirs)

    home = fresh_qgis["home"]
    assert not home.exists() or not any(home.rglob("*")), sorted(home.rglob("*"))
