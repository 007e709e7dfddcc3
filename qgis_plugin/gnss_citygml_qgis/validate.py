"""``gnsscitygml:validate``: a CityGML / CityJSON file or 3D Tiles tileset -> a table of its
errors.

The same check as ``gnss-citygml validate`` (:func:`gnss_citygml.validate.validate_file`).
"""

from qgis.core import (
    QgsFeature,
    QgsFeatureSink,
    QgsField,
    QgsFields,
    QgsProcessing,
    QgsProcessingException,
    QgsProcessingOutputBoolean,
    QgsProcessingOutputNumber,
    QgsProcessingOutputString,
    QgsProcessingParameterFeatureSink,
    QgsProcessingParameterFile,
    QgsWkbTypes,
)
from qgis.PyQt.QtCore import QVariant

from .algorithm import Algorithm, folder

#: Errors listed in the log (all are in the errors table), as the command line lists.
SHOWN = 50

HELP = """Checks a CityGML 2.0, CityJSON 2.0 or CityJSONSeq file: the schema (CityGML XSD or \
CityJSON JSON Schema, with the Extensions the file declares), the rules of the format and the \
geometry of the solids. A 3D Tiles 1.1 <i>tileset.json</i> is checked as a tileset: the 3D \
Tiles JSON schemas (bundled), its content files, its GLBs (the package's own checks, and \
Khronos' glTF validator when Node.js is installed; the log says which ran) and their metadata.

The <b>errors</b> table has one row per error: the object's id (empty for the whole file), the \
rule and the message. The log ends with a summary. A file that cannot be checked at all (not a \
city model, schemas missing) is an error of the algorithm. The same as \
<tt>gnss-citygml validate</tt> on the command line."""


class ValidateAlgorithm(Algorithm):
    section = "validate-is-a-city-model-valid"

    def name(self):
        return "validate"

    def displayName(self):  # noqa: N802 (the name QGIS calls)
        return "Validate a CityGML / CityJSON file or 3D Tiles tileset"

    def shortHelpString(self):  # noqa: N802 (the name QGIS calls)
        return HELP

    def define(self):
        self.addParameter(
            QgsProcessingParameterFile(
                "INPUT",
                "City model",
                fileFilter="City models, 3D Tiles (*.json *.jsonl *.gml *.xml);;All files (*)",
            )
        )
        self.addParameter(folder("SCHEMA_DIR", "Folder with the official schemas"))
        self.addParameter(
            QgsProcessingParameterFeatureSink(
                "ERRORS", "Errors", QgsProcessing.TypeVector, optional=True
            )
        )
        self.addOutput(QgsProcessingOutputBoolean("VALID", "Valid"))
        self.addOutput(QgsProcessingOutputNumber("N_ERRORS", "Errors"))
        self.addOutput(QgsProcessingOutputString("SUMMARY", "Summary"))

    def job(self, parameters, context, feedback):
        args = {
            "path": self.parameterAsFile(parameters, "INPUT", context),
            "schema_dir": self.optional_text(parameters, "SCHEMA_DIR", context),
        }
        report = self.run_job("validate", args, feedback)
        for note in report["notes"]:
            feedback.pushInfo(f"note: {note}")
        if report["exit_code"] == 2:  # could not be checked
            raise QgsProcessingException(report["summary"])
        fields = QgsFields()
        for name in ("object", "rule", "message"):
            fields.append(QgsField(name, QVariant.String))
        sink, sink_id = self.parameterAsSink(
            parameters, "ERRORS", context, fields, QgsWkbTypes.NoGeometry
        )
        for object_id, rule, message, _ in report["errors"]:
            if sink is not None:
                feature = QgsFeature(fields)
                feature.setAttributes([object_id, rule, message])
                sink.addFeature(feature, QgsFeatureSink.FastInsert)
        for *_, line in report["errors"][:SHOWN]:
            feedback.pushInfo(line)
        if len(report["errors"]) > SHOWN:
            counts = ", ".join(f"{rule} {n}" for rule, n in report["rule_counts"].items())
            feedback.pushInfo(f"... {len(report['errors']) - SHOWN} more ({counts})")
        feedback.pushInfo(report["summary"])
        results = {
            "VALID": report["valid"],
            "N_ERRORS": len(report["errors"]),
            "SUMMARY": report["summary"],
        }
        if sink is not None:
            results["ERRORS"] = sink_id
        return results
