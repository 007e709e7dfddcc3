"""The heights layer's QGIS style travels in the GeoPackage (issue 12): saved as QGIS saves
styles, the layer's default unless the user has one, replaced (not piled up) on a rerun, and
nothing else in the file touched. That QGIS itself opens the layer styled is checked in a real
QGIS (qgis_plugin/tests)."""

import sqlite3
import xml.etree.ElementTree as ET

import geopandas as gpd
import pyogrio
import shapely

from gnss_citygml.files.styles import STYLE_NAME, heights_qml, save_default_style
from gnss_citygml.files.tables import write_layer


def _layer(n: int = 3) -> gpd.GeoDataFrame:
    boxes = [shapely.box(529500 + 20 * i, 182300, 529510 + 20 * i, 182308) for i in range(n)]
    return gpd.GeoDataFrame(
        {"id": [f"b{i}" for i in range(n)], "relative_height": [5.0 * (i + 1) for i in range(n)]},
        geometry=boxes,
        crs="EPSG:27700",
    )


def _styles(path) -> list[tuple]:
    with sqlite3.connect(path) as db:
        rows = db.execute(
            "SELECT f_table_name, f_geometry_column, styleName, useAsDefault, styleQML "
            "FROM layer_styles ORDER BY id"
        ).fetchall()
    return rows


def test_the_style_is_qgis_qml_with_the_rules_the_docs_promise():
    root = ET.fromstring(heights_qml().split("\n", 1)[1])  # past the DOCTYPE line
    assert root.tag == "qgis" and root.get("labelsEnabled") == "0"
    filters = [rule.get("filter") for rule in root.iter("rule")]
    assert any(f and 'NOT "converged"' in f for f in filters)
    assert sum('"relative_height" >=' in (f or "") for f in filters) == 7
    assert root.find("renderer-3d") is not None
    assert "relative_height" in ET.tostring(root.find("renderer-3d"), encoding="unicode")


def test_write_layer_saves_the_default_style_as_qgis_does(tmp_path):
    path = tmp_path / "h.gpkg"
    write_layer(_layer(), path, "heights", style=heights_qml())
    (row,) = _styles(path)
    assert row == ("heights", "geom", STYLE_NAME, 1, heights_qml())
    # GDAL lists the table as an attribute table of the GeoPackage, as QGIS's own
    layers = dict(pyogrio.list_layers(path))
    assert layers["layer_styles"] is None and layers["heights"] == "Polygon"
    with sqlite3.connect(path) as db:
        assert db.execute("PRAGMA user_version").fetchone()[0] == 10200  # GeoPackage 1.2
        (kind,) = db.execute(
            "SELECT data_type FROM gpkg_contents WHERE table_name = 'layer_styles'"
        ).fetchone()
    assert kind == "attributes"


def test_a_rerun_replaces_the_style_and_keeps_the_users_own(tmp_path):
    path = tmp_path / "h.gpkg"
    write_layer(_layer(), path, "heights", style=heights_qml())
    write_layer(_layer(4), path, "other", style="<qgis/>")
    with sqlite3.connect(path) as db:  # the user saves a style of their own, as QGIS would
        db.execute(
            "INSERT INTO layer_styles (f_table_catalog, f_table_schema, f_table_name, "
            "f_geometry_column, styleName, styleQML, useAsDefault) "
            "VALUES ('', '', 'heights', 'geom', 'mine', '<qgis mine=\"1\"/>', 1)"
        )
    write_layer(_layer(5), path, "heights", overwrite=True, style=heights_qml())
    rows = _styles(path)
    assert [(r[0], r[2], r[3]) for r in rows] == [
        ("other", STYLE_NAME, 1),
        ("heights", "mine", 1),
        ("heights", STYLE_NAME, 0),  # theirs stays the default
    ]
    assert len(gpd.read_file(path, layer="heights")) == 5
    assert len(gpd.read_file(path, layer="other")) == 4


def test_save_default_style_on_a_geopackage_from_elsewhere(tmp_path):
    """A GeoPackage written by another program (here geopandas, geometry column 'geometry')."""
    path = tmp_path / "theirs.gpkg"
    _layer().to_file(path, layer="buildings", driver="GPKG", GEOMETRY_NAME="shape")
    save_default_style(path, "buildings", "<qgis/>")
    (row,) = _styles(path)
    assert row[:4] == ("buildings", "shape", STYLE_NAME, 1)
