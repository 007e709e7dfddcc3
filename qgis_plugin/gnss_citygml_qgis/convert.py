"""``gnsscitygml:convert``: a polygon layer with a height field -> LOD1 CityGML / CityJSON.

The same job as ``gnss-citygml convert`` (:func:`gnss_citygml.jobs.convert_file`): the file is
validated before it is put in place.
"""

from qgis.core import (
    QgsProcessing,
    QgsProcessingOutputBoolean,
    QgsProcessingOutputNumber,
    QgsProcessingParameterBoolean,
    QgsProcessingParameterFeatureSource,
    QgsProcessingParameterField,
    QgsProcessingParameterFileDestination,
    QgsProcessingParameterRasterLayer,
)

from .algorithm import Algorithm, advanced, folder

HELP = """Writes the buildings of a polygon layer as LOD1 solids: CityJSON 2.0 (.city.json), \
CityJSONSeq (.city.jsonl) or CityGML 2.0 (.gml), by the output's name. The file is validated \
(CityJSON schema or CityGML XSD, and the geometry) before it is put in place: an invalid model \
is never written.

<b>Input</b>: the heights layer of "Estimate building heights from GNSS", or any polygon \
layer with a height field (e.g. OS Building Height Attribute's abshmax, or relh2 as relative).
<b>Height field</b>: the roof height in metres, absolute (ODN) unless <i>relative</i> is ticked.
<b>Ground</b>: a ground field (m ODN) or a DEM; neither for the heights layer, which has its \
ground column.

Buildings without a usable height are skipped and listed in the log, with the reason. The \
same as <tt>gnss-citygml convert</tt> on the command line."""


class ConvertAlgorithm(Algorithm):
    section = "convert-heights-to-cityjson-citygml-or-3d-tiles"

    def name(self):
        return "convert"

    def displayName(self):  # noqa: N802 (the name QGIS calls)
        return "Export LOD1 CityGML / CityJSON"

    def shortHelpString(self):  # noqa: N802 (the name QGIS calls)
        return HELP

    def define(self):
        numeric = QgsProcessingParameterField.Numeric
        self.addParameter(
            QgsProcessingParameterFeatureSource(
                "INPUT", "Buildings", [QgsProcessing.TypeVectorPolygon]
            )
        )
        self.addParameter(
            QgsProcessingParameterField(
                "HEIGHT_FIELD",
                "Height field (m; default: height)",
                "height",
                "INPUT",
                type=numeric,
                optional=True,  # so that the default holds when none is given (QGIS 3.22)
            )
        )
        self.addParameter(
            QgsProcessingParameterBoolean(
                "RELATIVE", "The height is above the ground (relative)", False
            )
        )
        self.addParameter(
            QgsProcessingParameterField(
                "GROUND_FIELD", "Ground field (m ODN)", None, "INPUT", type=numeric, optional=True
            )
        )
        self.addParameter(
            QgsProcessingParameterRasterLayer(
                "DEM", "DEM for the ground (instead of a ground field)", optional=True
            )
        )
        self.addParameter(
            QgsProcessingParameterField(
                "ID_FIELD",
                "Building id field (default: toid, id or fid)",
                parentLayerParameterName="INPUT",
                optional=True,
            )
        )
        self.addParameter(QgsProcessingParameterBoolean("VALIDATE", "Validate the output", True))
        self.addParameter(
            advanced(
                QgsProcessingParameterBoolean(
                    "STRICT", "Stop if a building has no usable height", False
                )
            )
        )
        self.addParameter(
            advanced(
                QgsProcessingParameterBoolean(
                    "TYPED_ATTRIBUTES",
                    "CityJSON: typed attributes (the GnssCityGML Extension)",
                    False,
                )
            )
        )
        self.addParameter(folder("GRID_DIR", "Folder with the OSTN15/OSGM15 grids"))
        self.addParameter(folder("SCHEMA_DIR", "Folder with the official schemas"))
        self.addParameter(
            QgsProcessingParameterFileDestination(
                "OUTPUT",
                "City model",
                "CityJSON (*.city.json);;CityJSONSeq (*.city.jsonl);;CityGML 2.0 (*.gml)",
            )
        )
        self.addOutput(QgsProcessingOutputNumber("WRITTEN", "Buildings written"))
        self.addOutput(QgsProcessingOutputNumber("SKIPPED", "Buildings skipped"))
        self.addOutput(QgsProcessingOutputBoolean("VALIDATED", "Validated"))

    def job(self, parameters, context, feedback):
        source, layer = self.parameterAsCompatibleSourceLayerPathAndLayerName(
            parameters, "INPUT", context, ["gpkg", "fgb", "shp", "gml"], "gpkg", feedback
        )
        dem = self.parameterAsRasterLayer(parameters, "DEM", context)
        output = self.parameterAsFileOutput(parameters, "OUTPUT", context)
        args = {
            "source": source,
            "output": output,
            "layer": layer or None,
            "id_field": self.optional_text(parameters, "ID_FIELD", context),
            "height_field": self.parameterAsString(parameters, "HEIGHT_FIELD", context),
            "relative": self.parameterAsBoolean(parameters, "RELATIVE", context),
            "ground_field": self.optional_text(parameters, "GROUND_FIELD", context),
            "dem": None if dem is None else dem.source(),
            "dem_crs": None if dem is None else dem.crs().authid() or None,
            "grid_dir": self.optional_text(parameters, "GRID_DIR", context),
            "overwrite": True,  # QGIS's file dialog has asked
            "strict": self.parameterAsBoolean(parameters, "STRICT", context),
            "validate": self.parameterAsBoolean(parameters, "VALIDATE", context),
            "schema_dir": self.optional_text(parameters, "SCHEMA_DIR", context),
            "typed_attributes": self.parameterAsBoolean(parameters, "TYPED_ATTRIBUTES", context),
        }
        result = self.run_job("convert", args, feedback)
        for building, reason in result["skipped"]:
            feedback.pushWarning(f"skipped {building}: {reason}")
        feedback.pushInfo(result["summary"])
        return {
            "OUTPUT": output,
            "WRITTEN": result["written"],
            "SKIPPED": len(result["skipped"]),
            "VALIDATED": result["validated"],
        }
