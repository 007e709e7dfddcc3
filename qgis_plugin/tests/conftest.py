"""A real headless QGIS (pytest-qgis, offscreen), its Processing framework and the plugin
loaded as QGIS loads it, and simulated scenes made by the library's simulator."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PLUGINS = ROOT / "qgis_plugin"  # the folder QGIS is told to load plugins from
PLUGIN = PLUGINS / "gnss_citygml_qgis"
sys.path.insert(0, str(PLUGINS))


def cli(*args, check=True, env=None):
    """Run ``gnss-citygml`` (this Python's) and return the finished process."""
    process = subprocess.run(
        [sys.executable, "-m", "gnss_citygml", *map(str, args)],
        capture_output=True,
        text=True,
        env=env,
    )
    if check and process.returncode != 0:
        raise AssertionError(f"gnss-citygml {args[0]} failed: {process.stderr}")
    return process


def estimate_with_the_cli(scene, output, *options):
    """The heights layer of ``gnss-citygml estimate`` on ``scene``, with ``options``."""
    import geopandas as gpd

    files = [scene["observations"], scene["footprints"], "--dem", scene["dem"]]
    cli("estimate", *files, "-o", output, "-q", *options)
    return gpd.read_file(output, layer="heights")


def assert_same_heights(ours, theirs):
    """The same buildings, the same converged set, heights within 1 mm, the same status."""
    import numpy as np
    import pandas as pd

    ours, theirs = ours.set_index("id").sort_index(), theirs.set_index("id").sort_index()
    assert ours.index.equals(theirs.index)
    assert ours["converged"].equals(theirs["converged"])
    assert ours["converged"].any()
    for column in ("height", "height_lower", "height_upper", "relative_height", "c"):
        np.testing.assert_allclose(ours[column], theirs[column], atol=1e-3, equal_nan=True)
    pd.testing.assert_series_equal(ours["status"], theirs["status"])
    assert ours.geometry.geom_equals(theirs.geometry).all()


@pytest.fixture(scope="session")
def processing_framework(qgis_processing):
    """QGIS's Processing framework (its Python package, as the desktop loads it)."""
    import processing

    return processing


@pytest.fixture
def plugin(qgis_iface, processing_framework):
    """The plugin, loaded as QGIS loads it (classFactory, then initGui), unloaded after."""
    import gnss_citygml_qgis
    from qgis._3d import Qgs3D

    Qgs3D.initialize()  # as the desktop does: the style's 3D renderer needs it
    loaded = gnss_citygml_qgis.classFactory(qgis_iface)
    loaded.initGui()
    yield loaded
    loaded.unload()


#: The scenes: simulated by the library (not the bundled sample), of two kinds.
SCENES = {
    "city": ["city", "--seed", "3", "--interval", "4", "--format", "csv"],
    "ucl-phone-fixes": ["ucl", "--locations", "gnss", "--seed", "1", "--interval", "4"],
}


@pytest.fixture(scope="session", params=sorted(SCENES))
def scene(request, tmp_path_factory):
    """A simulated scene: observations, footprints.gpkg, dem.tif (and the truth)."""
    folder = tmp_path_factory.mktemp(request.param)
    cli("simulate", *SCENES[request.param], "-o", folder, "--overwrite")
    observations = next(folder.glob("observations.*"))
    return {
        "name": request.param,
        "folder": folder,
        "observations": observations,
        "footprints": folder / "footprints.gpkg",
        "dem": folder / "dem.tif",
    }


@pytest.fixture
def qgis_env(tmp_path):
    """Environment for QGIS's own programs (qgis_process): this plugin folder, a throwaway
    profile and cache (nothing written into $HOME), and this Python's packages (gnss_citygml
    from the repository: an editable install is not seen through PYTHONPATH)."""
    import sysconfig

    env = dict(os.environ)
    env["QGIS_PLUGINPATH"] = str(PLUGINS)
    env["QGIS_CUSTOM_CONFIG_PATH"] = str(tmp_path / "profile")
    env["XDG_CACHE_HOME"] = str(tmp_path / "cache")  # QGIS's network cache is not in the profile
    env["XDG_CONFIG_HOME"] = str(tmp_path / "config")  # and a QSettings file of Qt's own
    env["XDG_RUNTIME_DIR"] = str(tmp_path / "runtime")
    env["HOME"] = str(tmp_path / "home")
    env["QT_QPA_PLATFORM"] = "offscreen"
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), sysconfig.get_paths()["purelib"]])
    # QGIS's Python (this venv's base) first on PATH, as where it is the python3 there:
    # qgis_process's embedded Python names its executable from PATH, and the jobs run in that
    # (another python3 earlier on PATH, e.g. pyenv's, lacks the Debian packages: matplotlib)
    env["PATH"] = os.pathsep.join([os.path.join(sys.base_prefix, "bin"), env.get("PATH", "")])
    return env


def debian_qgis(script, tmp_path):
    """``script`` run by Debian's own Python (QGIS's), isolated (``-I -S``: no user or
    virtual environment's packages), headless, with ``tmp_path`` as its home."""
    return subprocess.run(
        ["/usr/bin/python3", "-I", "-S", "-c", script],
        capture_output=True,
        text=True,
        env={"QT_QPA_PLATFORM": "offscreen", "HOME": str(tmp_path), "PATH": "/usr/bin:/bin"},
        timeout=120,
    )
