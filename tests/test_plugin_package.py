"""The QGIS plugin as a package (issue 12): `make plugin`'s zip, its metadata, and code that an
older QGIS Python can still load to say what is missing. The plugin at work is tested in a real
QGIS (qgis_plugin/tests, run by `make test`)."""

import ast
import configparser
import io
import subprocess
import sys
import zipfile
from pathlib import Path

import gnss_citygml

ROOT = Path(__file__).resolve().parents[1]
PLUGIN = ROOT / "qgis_plugin" / "gnss_citygml_qgis"
sys.path.insert(0, str(ROOT / "tools"))

from build_plugin import build  # noqa: E402


def test_the_zip_holds_the_plugin_folder_with_its_licence_and_the_librarys_wheel(tmp_path):
    target = build(tmp_path)
    assert target.name == f"gnss_citygml_qgis-{gnss_citygml.__version__}.zip"
    archive = zipfile.ZipFile(target)
    names = set(archive.namelist())
    expected = {f"gnss_citygml_qgis/{p.name}" for p in PLUGIN.iterdir() if p.is_file()}
    wheel = f"gnss_citygml_qgis/wheels/gnss_citygml-{gnss_citygml.__version__}-py3-none-any.whl"
    assert names == expected | {"gnss_citygml_qgis/LICENSE", wheel}
    assert {"gnss_citygml_qgis/metadata.txt", "gnss_citygml_qgis/icon.svg"} <= names
    assert not list(tmp_path.glob("*.part"))
    # the wheel "Set up gnss-citygml" installs: the library's modules and data, its metadata
    inner = zipfile.ZipFile(io.BytesIO(archive.read(wheel)))
    held = set(inner.namelist())
    assert {"gnss_citygml/__init__.py", "gnss_citygml/worker.py"} <= held
    assert any(n.startswith("gnss_citygml/data/grids/") for n in held)
    info = f"gnss_citygml-{gnss_citygml.__version__}.dist-info/METADATA"
    assert "Requires-Dist: numpy" in inner.read(info).decode()


def test_metadata_version_is_the_librarys():
    meta = configparser.ConfigParser()
    meta.read(PLUGIN / "metadata.txt")
    assert meta["general"]["version"] == gnss_citygml.__version__
    assert meta["general"]["qgisMinimumVersion"] == "3.22"


def test_the_plugin_parses_on_an_old_qgis_python():
    """A QGIS on Python 3.7 must load the plugin far enough to say it needs a newer one."""
    for path in PLUGIN.glob("*.py"):
        ast.parse(path.read_text(), str(path), feature_version=(3, 7))


def test_what_the_plugin_imports_into_qgis_loads_no_compiled_geo_library():
    """The plugin imports only the settings and the method names into QGIS's process (for the
    defaults its dialogs show): no numpy, pandas or the wheels that bundle PROJ, GDAL, GEOS,
    whose symbols would bind to QGIS's own libraries there (gnss_citygml/worker.py)."""
    code = (
        "import sys, gnss_citygml.settings, gnss_citygml.model; "
        "print(sorted(m for m in ('numpy', 'pandas', 'pyproj', 'rasterio', 'pyogrio', "
        "'shapely', 'scipy', 'geopandas') if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"
