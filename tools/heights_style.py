"""Write the default QGIS style of the heights layer (gnss_citygml/data/styles/heights.qml).

Run with QGIS's Python (``QT_QPA_PLATFORM=offscreen /usr/bin/python3 tools/heights_style.py``)
after changing the style here; the QML is committed, so neither the package nor its tests need
QGIS to write it. The writer of the heights layer stores it as the layer's default style in
the GeoPackage (``layer_styles``), and the QGIS plugin applies it to the layers it loads.

The style, for an analyst who wants to see the estimates and their failures at a glance:

- buildings with a height: filled by their height above the ground (``relative_height``) in
  fixed classes of metres, so that two maps compare;
- buildings without one: light grey and hatched, labelled with their ``status`` if labels are
  turned on (they are off by default: a city is thousands of labels);
- a 3D renderer extruding each footprint by ``relative_height`` from the terrain.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")

from qgis._3d import Qgs3D, QgsPhongMaterialSettings, QgsPolygon3DSymbol, QgsVectorLayer3DRenderer
from qgis.core import (
    QgsApplication,
    QgsFillSymbol,
    QgsLinePatternFillSymbolLayer,
    QgsMapLayer,
    QgsPalLayerSettings,
    QgsProperty,
    QgsRuleBasedRenderer,
    QgsTextFormat,
    QgsVectorLayer,
    QgsVectorLayerSimpleLabeling,
)
from qgis.PyQt.QtGui import QColor

QML = Path(__file__).resolve().parents[1] / "gnss_citygml" / "data" / "styles" / "heights.qml"

#: Classes of the height above the ground (m, lower bound inclusive) and their fill (a
#: colour-blind-safe sequential ramp, viridis).
CLASSES = [
    (0, 5, "#440154"),
    (5, 10, "#443983"),
    (10, 15, "#31688e"),
    (15, 20, "#21918c"),
    (20, 30, "#35b779"),
    (30, 50, "#90d743"),
    (50, None, "#fde725"),
]
OUTLINE = "#303030"


def _fill(colour: str) -> QgsFillSymbol:
    return QgsFillSymbol.createSimple(
        {"color": colour, "outline_color": OUTLINE, "outline_width": "0.2"}
    )


def _not_converged() -> QgsFillSymbol:
    """Light grey with a 45° hatch: no height, never a guess."""
    symbol = _fill("#e0e0e0")
    hatch = QgsLinePatternFillSymbolLayer()
    hatch.setLineAngle(45)
    hatch.setDistance(1.6)
    hatch.setLineWidth(0.25)
    hatch.setColor(QColor("#707070"))
    symbol.appendSymbolLayer(hatch)
    return symbol


def _renderer() -> QgsRuleBasedRenderer:
    root = QgsRuleBasedRenderer.Rule(None)
    for low, high, colour in CLASSES:
        test = f'"relative_height" >= {low}' + (
            "" if high is None else f' AND "relative_height" < {high}'
        )
        label = f"{low}-{high} m" if high is not None else f"{low} m and above"
        rule = QgsRuleBasedRenderer.Rule(_fill(colour), 0, 0, f'"converged" AND {test}', label)
        root.appendChild(rule)
    no_height = QgsRuleBasedRenderer.Rule(
        _not_converged(),
        0,
        0,
        'NOT "converged" OR "relative_height" IS NULL',
        "no height (see status)",
    )
    root.appendChild(no_height)
    return QgsRuleBasedRenderer(root)


def _labels() -> QgsVectorLayerSimpleLabeling:
    """The height (m above ground) or, without one, why not: defined, but off by default."""
    settings = QgsPalLayerSettings()
    settings.isExpression = True
    settings.fieldName = (
        'CASE WHEN "converged" THEN format_number("relative_height", 1) || \' m\' ELSE "status" END'
    )
    settings.autoWrapLength = 16  # a status runs to a few words
    text = QgsTextFormat()
    text.setSize(8)
    buffer = text.buffer()
    buffer.setEnabled(True)
    buffer.setSize(0.8)
    text.setBuffer(buffer)
    settings.setFormat(text)
    return QgsVectorLayerSimpleLabeling(settings)


def _renderer_3d() -> QgsVectorLayer3DRenderer:
    """Footprints extruded by their height above the ground, standing on the terrain."""
    symbol = QgsPolygon3DSymbol()
    properties = symbol.dataDefinedProperties()
    properties.setProperty(
        QgsPolygon3DSymbol.PropertyExtrusionHeight,
        QgsProperty.fromExpression('coalesce("relative_height", 0)'),
    )
    symbol.setDataDefinedProperties(properties)
    material = QgsPhongMaterialSettings()
    material.setDiffuse(QColor("#c8b496"))
    material.setAmbient(QColor("#5a5046"))
    symbol.setMaterial(material)
    symbol.setEdgesEnabled(True)
    symbol.setEdgeColor(QColor(OUTLINE))
    return QgsVectorLayer3DRenderer(symbol)


def main() -> int:
    app = QgsApplication([], False)
    app.initQgis()
    Qgs3D.initialize()
    fields = (
        "field=id:string&field=relative_height:double&field=converged:boolean&field=status:string"
    )
    layer = QgsVectorLayer(f"Polygon?crs=EPSG:27700&{fields}", "heights", "memory")
    layer.setRenderer(_renderer())
    layer.setLabeling(_labels())
    layer.setLabelsEnabled(False)
    layer.setRenderer3D(_renderer_3d())
    QML.parent.mkdir(exist_ok=True)
    categories = QgsMapLayer.Symbology | QgsMapLayer.Symbology3D | QgsMapLayer.Labeling
    message, ok = layer.saveNamedStyle(str(QML), categories=categories)
    if not ok:
        print(f"cannot write {QML}: {message}", file=sys.stderr)
        return 1
    print(f"wrote {QML}")
    app.exitQgis()
    return 0


if __name__ == "__main__":
    sys.exit(main())
