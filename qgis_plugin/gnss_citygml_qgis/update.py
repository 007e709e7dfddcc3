"""``gnsscitygml:update``: new observations -> the estimate columns of a GeoPackage map layer.

The same job as ``gnss-citygml update`` (:func:`gnss_citygml.update.update_map`): the map is
replaced as a whole when the update is complete, and the layer is reloaded in QGIS.
"""

from qgis.core import (
    QgsProcessing,
    QgsProcessingException,
    QgsProcessingOutputBoolean,
    QgsProcessingOutputNumber,
    QgsProcessingParameterBoolean,
    QgsProcessingParameterField,
    QgsProcessingParameterMultipleLayers,
    QgsProcessingParameterNumber,
    QgsProcessingParameterRasterLayer,
    QgsProcessingParameterVectorLayer,
    QgsProviderRegistry,
)

from .algorithm import SIGNAL_MODEL_HELP, Algorithm, advanced, folder, option

#: The library's options (``gnss_citygml.options``) the algorithm offers (advanced), in order.
_OPTIONS = (
    "METHOD",
    "HEIGHT_RULE",
    "SIGNAL_MODEL",
    "LEVEL_PHONES",
    "INIT_THRESHOLD",
    "MAX_ITER",
    "FIT_MAX_ITER",
)

HELP = (
    """Keeps the building heights of a GeoPackage map up to date as new GNSS observations \
arrive: adds or updates the columns height_gnss, height_lower, height_upper, height_paper, \
c_gnss, n_signals, converged, method, status_gnss and updated_utc of the map layer, for the \
buildings with enough signals; on the heights layer of "Estimate building heights from \
GNSS", its own height, relative_height, ground, status, a, b, c, d and iterations too, so that \
no row keeps an old height beside a fit that no longer converges. Every other column, feature, \
layer and style of the GeoPackage is kept, and so are the feature ids.

The evidence (every intersection cast so far) is kept in the GeoPackage: an update casts only \
the new observations and refits on all of them, so it equals one run over all the data, and \
running again with the same data changes nothing. The map is written as a whole when the \
update is complete, with a backup (MAP.bak.gpkg) of the map as it was: a failure or Cancel \
leaves it untouched. A map that another program (or this QGIS, in editing mode) is writing to \
is refused.

"""
    + SIGNAL_MODEL_HELP
    + """

The same as <tt>gnss-citygml update</tt> on the command line."""
)


class UpdateAlgorithm(Algorithm):
    section = "keeping-a-map-up-to-date-gnss-citygml-update"

    def name(self):
        return "update"

    def displayName(self):  # noqa: N802 (the name QGIS calls)
        return "Update a GeoPackage map with new GNSS data"

    def shortHelpString(self):  # noqa: N802 (the name QGIS calls)
        return HELP

    def define(self):
        self.addParameter(
            QgsProcessingParameterVectorLayer(
                "MAP", "Map layer (in a GeoPackage)", [QgsProcessing.TypeVectorPolygon]
            )
        )
        self.addParameter(
            QgsProcessingParameterMultipleLayers(
                "OBSERVATIONS", "New observations (Parquet or CSV files)", QgsProcessing.TypeFile
            )
        )
        self.addParameter(QgsProcessingParameterRasterLayer("DEM", "DEM (British National Grid)"))
        self.addParameter(
            QgsProcessingParameterField(
                "ID_FIELD",
                "Building id field (default: toid, id or fid)",
                parentLayerParameterName="MAP",
                optional=True,
            )
        )
        self.addParameter(
            QgsProcessingParameterNumber(
                "MIN_SIGNALS", "Fewest signals for a building to get values", defaultValue=1,
                minValue=1,
            )
        )  # fmt: skip
        self.addParameter(
            QgsProcessingParameterNumber(
                "THRESHOLD",
                "List the buildings whose height changes by more than (m)",
                QgsProcessingParameterNumber.Double,
                0.5,
                minValue=0,
            )
        )
        self.addParameter(
            QgsProcessingParameterBoolean("DRY_RUN", "Dry run: say what would change", False)
        )
        self.addParameter(
            QgsProcessingParameterBoolean("BACKUP", "Keep the map as it was (MAP.bak.gpkg)", True)
        )
        for name in _OPTIONS:
            self.addParameter(advanced(option(name)))
        self.addParameter(folder("GRID_DIR", "Folder with the OSTN15/OSGM15 grids"))
        self.addOutput(QgsProcessingOutputNumber("UPDATED", "Buildings updated"))
        self.addOutput(QgsProcessingOutputBoolean("WRITTEN", "Map written"))

    def job(self, parameters, context, feedback):
        layer = self.parameterAsVectorLayer(parameters, "MAP", context)
        parts = QgsProviderRegistry.instance().decodeUri(layer.providerType(), layer.source())
        path = parts.get("path", "")
        if not path.lower().endswith(".gpkg"):
            raise QgsProcessingException(
                f"the map must be a layer of a GeoPackage (.gpkg), not {layer.source()}: "
                "save it as a GeoPackage first (Export > Save Features As)"
            )
        dem = self.parameterAsRasterLayer(parameters, "DEM", context)
        args = {
            "path": path,
            "observations": self.parameterAsFileList(parameters, "OBSERVATIONS", context),
            "dem": dem.source(),
            "layer": parts.get("layerName") or None,
            "id_field": self.optional_text(parameters, "ID_FIELD", context),
            "min_signals": self.parameterAsInt(parameters, "MIN_SIGNALS", context),
            "threshold": self.parameterAsDouble(parameters, "THRESHOLD", context),
            "dry_run": self.parameterAsBoolean(parameters, "DRY_RUN", context),
            "backup": self.parameterAsBoolean(parameters, "BACKUP", context),
            **self.settings(parameters, _OPTIONS, context),
            "grid_dir": self.optional_text(parameters, "GRID_DIR", context),
            "dem_crs": dem.crs().authid() or None,
        }
        result = self.run_job("update", args, feedback)
        for line in result["lines"]:
            feedback.pushInfo(line)
        if result["written"]:
            self.reload = layer.id()
            feedback.pushInfo(f"updated -> {path}" + (f" (as it was: {result['backup']})"
                                                      if result["backup"] else ""))  # fmt: skip
        return {"UPDATED": result["updated"], "WRITTEN": result["written"]}

    def postProcessAlgorithm(self, context, feedback):  # noqa: N802 (the name QGIS calls)
        """In QGIS's main thread, once the map is replaced: the layer reads the new file."""
        layer = (
            context.project().mapLayer(getattr(self, "reload", "")) if context.project() else None
        )
        if layer is not None:
            layer.dataProvider().reloadData()
            layer.reload()
            layer.updateFields()
            layer.triggerRepaint()
        return {}
