"""The QGIS style of the heights layer, and how it travels inside a GeoPackage.

The style (``data/styles/heights.qml``, made by ``tools/heights_style.py``) fills each building
by its height above the ground in fixed classes of metres, hatches the buildings without a
height, keeps labels (height or status) ready but off, and extrudes the footprints in QGIS's 3D
view. The heights writer saves it in the GeoPackage's ``layer_styles`` table, the table QGIS
itself uses, as the layer's default style: QGIS opens the CLI's output styled, with no plugin.
"""

from __future__ import annotations

import contextlib
import datetime as dt
import sqlite3
from importlib.resources import files
from pathlib import Path

import pandas as pd

from .geopackage import has_table

__all__ = ["HEIGHTS_STYLE", "heights_qml", "save_default_style", "style_saved"]

#: The style of the heights layer (QGIS QML).
HEIGHTS_STYLE = files("gnss_citygml") / "data" / "styles" / "heights.qml"

#: The name the toolkit's styles have in ``layer_styles``.
STYLE_NAME = "gnss-citygml"


def heights_qml() -> str:
    """The QML text of the heights layer's style."""
    return HEIGHTS_STYLE.read_text(encoding="utf-8")


def save_default_style(path: Path, layer: str, qml: str, *, description: str = "") -> None:
    """Save ``qml`` in the GeoPackage ``path`` as the style of ``layer``, as QGIS does.

    The row replaces the toolkit's earlier style of that layer. It is the layer's default
    style unless the user has saved one of their own as the default (theirs stays so); every
    other style, of this layer or others, is kept. The table is made through GDAL when the file
    has none yet, so that GDAL and QGIS list it as an attribute table of the GeoPackage.
    """
    import pyogrio

    with contextlib.closing(sqlite3.connect(path)) as db, db:
        if has_table(db, "layer_styles"):
            db.execute(
                "DELETE FROM layer_styles WHERE f_table_name = ? AND styleName = ?",
                (layer, STYLE_NAME),
            )
            theirs = db.execute(
                "SELECT count(*) FROM layer_styles WHERE f_table_name = ? AND useAsDefault",
                (layer,),
            ).fetchone()[0]
        else:
            theirs = 0
        (geometry,) = db.execute(
            "SELECT column_name FROM gpkg_geometry_columns WHERE table_name = ?", (layer,)
        ).fetchone()
    row = pd.DataFrame(
        {
            "f_table_catalog": [""],
            "f_table_schema": [""],
            "f_table_name": [layer],
            "f_geometry_column": [geometry],
            "styleName": [STYLE_NAME],
            "styleQML": [qml],
            "styleSLD": [""],
            "useAsDefault": [not theirs],
            "description": [description],
            "owner": [""],
            "ui": [""],
            "update_time": [dt.datetime.now(dt.UTC).replace(tzinfo=None)],
        }
    )
    pyogrio.write_dataframe(
        row, path, layer="layer_styles", driver="GPKG", append=True, layer_options={"FID": "id"}
    )


def style_saved(path: Path, layer: str, qml: str) -> bool:
    """Whether the GeoPackage ``path`` holds ``qml`` as the toolkit's style of ``layer``."""
    with contextlib.closing(sqlite3.connect(path)) as db:
        if not has_table(db, "layer_styles"):
            return False
        query = (
            "SELECT count(*) FROM layer_styles "
            "WHERE f_table_name = ? AND styleName = ? AND styleQML = ?"
        )
        return bool(db.execute(query, (layer, STYLE_NAME, qml)).fetchone()[0])
