"""Render the README's QGIS pictures (`make screenshots`): docs/qgis-estimate-dialog.png, the
dialog of "Estimate building heights from GNSS", and docs/qgis-heights-map.png, the sample
city's heights layer as the plugin loads it, on a map canvas.

Runs headless (Qt's offscreen platform) in the QGIS tests' environment (.venv-qgis, made by
qgis_plugin/run-tests). The estimate is the plugin's, run on the bundled sample city; the
labels, off by default, are turned on to show what they say.
"""

from __future__ import annotations

import os
import shutil
import sys
import tempfile
from pathlib import Path

os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
CITY = ROOT / "gnss_citygml" / "data" / "city"
sys.path[:0] = [str(ROOT / "qgis_plugin"), "/usr/share/qgis/python/plugins"]

from qgis.core import QgsApplication, QgsProject  # noqa: E402
from qgis.gui import QgsMapCanvas  # noqa: E402
from qgis.PyQt.QtCore import QSize  # noqa: E402
from qgis.PyQt.QtGui import QColor  # noqa: E402


def main() -> int:
    folder = Path(tempfile.mkdtemp(prefix="gnss-citygml-shots-"))
    os.environ["QGIS_CUSTOM_CONFIG_PATH"] = str(folder / "profile")
    app = QgsApplication([], True)
    app.initQgis()
    try:
        return _shoot(folder)
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def _shoot(folder: Path) -> int:
    import gnss_citygml_qgis
    from processing.core.Processing import Processing
    from qgis._3d import Qgs3D

    canvas = QgsMapCanvas()
    canvas.resize(QSize(900, 620))
    canvas.setCanvasColor(QColor("white"))
    Qgs3D.initialize()
    Processing.initialize()
    plugin = gnss_citygml_qgis.classFactory(None)
    plugin.initGui()

    import processing

    DOCS.mkdir(exist_ok=True)
    from processing.gui.AlgorithmDialog import AlgorithmDialog

    algorithm = QgsApplication.processingRegistry().createAlgorithmById("gnsscitygml:estimate")
    dialog = AlgorithmDialog(algorithm, False, None)
    dialog.resize(QSize(1000, 760))
    dialog.show()
    QgsApplication.processEvents()
    dialog.grab().save(str(DOCS / "qgis-estimate-dialog.png"))
    dialog.close()

    city = folder / "city"
    shutil.copytree(CITY, city)  # (QGIS writes its statistics beside a raster it opens)
    processing.runAndLoadResults(
        "gnsscitygml:estimate",
        {
            "OBSERVATIONS": str(city / "observations.parquet"),
            "FOOTPRINTS": str(city / "footprints.gpkg"),
            "DEM": str(city / "dem.tif"),
            "OUTPUT": str(folder / "heights.gpkg"),
        },
    )
    (layer,) = QgsProject.instance().mapLayers().values()
    layer.setLabelsEnabled(True)  # off by default; on here to show what they say
    canvas.setDestinationCrs(layer.crs())
    canvas.setLayers([layer])
    canvas.setExtent(layer.extent().buffered(15))
    canvas.refresh()
    canvas.waitWhileRendering()
    canvas.grab().save(str(DOCS / "qgis-heights-map.png"))
    plugin.unload()
    for name in ("qgis-estimate-dialog.png", "qgis-heights-map.png"):
        print(DOCS / name)
    return 0


if __name__ == "__main__":
    sys.exit(main())
