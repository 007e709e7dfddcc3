"""The sample city's heights layer in QGIS's 3D view, for the README (`make screenshots`):

    xvfb-run -a .venv-qgis/bin/python tools/qgis_3d_screenshot.py demo-out/heights.gpkg \
        docs/qgis-3d-view.png

The layer's own style (the one the plugin saves in the GeoPackage) carries its 3D renderer:
each building extruded from its ground to its estimated roof. QGIS renders the 3D scene
offscreen through a print layout's 3D map item, which needs OpenGL: hence an X server (Xvfb,
with Mesa's software renderer) rather than Qt's offscreen platform.
"""

from __future__ import annotations

import os
import shutil
import sys
import tempfile
from pathlib import Path

os.environ["QT_QPA_PLATFORM"] = "xcb"

from qgis.core import (  # noqa: E402
    QgsApplication,
    QgsLayoutExporter,
    QgsLayoutPoint,
    QgsLayoutSize,
    QgsPrintLayout,
    QgsProject,
    QgsUnitTypes,
    QgsVector3D,
    QgsVectorLayer,
)
from qgis.PyQt.QtGui import QColor  # noqa: E402

#: The view: the camera's distance (m), pitch and heading (degrees), the picture's size (mm).
DISTANCE, PITCH, HEADING = 520.0, 52.0, 20.0
WIDTH, HEIGHT = 240, 150


def main(heights: str, png: str) -> int:
    folder = Path(tempfile.mkdtemp(prefix="gnss-citygml-3d-"))
    os.environ["QGIS_CUSTOM_CONFIG_PATH"] = str(folder / "profile")
    app = QgsApplication([], True)
    app.initQgis()
    try:
        return _shoot(heights, png)
    finally:
        shutil.rmtree(folder, ignore_errors=True)
        del app


def _shoot(heights: str, png: str) -> int:
    from qgis._3d import Qgs3D, Qgs3DMapSettings, QgsCameraPose, QgsLayoutItem3DMap

    Qgs3D.initialize()
    layer = QgsVectorLayer(f"{heights}|layername=heights", "heights", "ogr")
    message, ok = layer.loadDefaultStyle()  # as the plugin loads it: the toolkit's style
    if not layer.isValid() or not ok or layer.renderer3D() is None:
        raise SystemExit(f"{heights}: no heights layer with its 3D style ({message})")
    project = QgsProject.instance()
    project.addMapLayer(layer)
    project.setCrs(layer.crs())
    settings = Qgs3DMapSettings()
    settings.setCrs(layer.crs())
    centre = layer.extent().center()
    settings.setOrigin(QgsVector3D(centre.x(), centre.y(), 0))
    settings.setLayers([layer])
    settings.setBackgroundColor(QColor("white"))
    layout = QgsPrintLayout(project)
    layout.initializeDefaults()
    view = QgsLayoutItem3DMap(layout)
    layout.addLayoutItem(view)
    view.attemptMove(QgsLayoutPoint(0, 0, QgsUnitTypes.LayoutMillimeters))
    view.attemptResize(QgsLayoutSize(WIDTH, HEIGHT, QgsUnitTypes.LayoutMillimeters))
    view.setMapSettings(settings)
    pose = QgsCameraPose()
    pose.setCenterPoint(QgsVector3D(0, 0, 0))
    pose.setDistanceFromCenterPoint(DISTANCE)
    pose.setPitchAngle(PITCH)
    pose.setHeadingAngle(HEADING)
    view.setCameraPose(pose)
    layout.pageCollection().page(0).setPageSize(
        QgsLayoutSize(WIDTH, HEIGHT, QgsUnitTypes.LayoutMillimeters)
    )
    export = QgsLayoutExporter.ImageExportSettings()
    export.dpi = 110
    if QgsLayoutExporter(layout).exportToImage(png, export) != QgsLayoutExporter.Success:
        raise SystemExit(f"the 3D view could not be rendered to {png}")
    print(png)
    return 0


if __name__ == "__main__":
    sys.exit(main(*sys.argv[1:]))
