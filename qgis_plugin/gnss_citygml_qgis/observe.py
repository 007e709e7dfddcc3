"""``gnsscitygml:observe``: GnssLogger logs + orbit files -> the observations table.

The same job as ``gnss-citygml observe`` (:func:`gnss_citygml.jobs.observe_file`), with the
same defaults: the observations are the command line's.
"""

from qgis.core import (
    QgsProcessing,
    QgsProcessingOutputNumber,
    QgsProcessingParameterBoolean,
    QgsProcessingParameterEnum,
    QgsProcessingParameterFile,
    QgsProcessingParameterFileDestination,
    QgsProcessingParameterMultipleLayers,
)

from .algorithm import Algorithm, advanced, option

#: The choices of the fix provider and of the band, the first the default (the command
#: line's ``--provider`` and ``--band``).
PROVIDERS = ("gps", "flp", "nlp")
BANDS = ("L1", "L5")

HELP = """Turns Android GnssLogger logs and the satellites' orbits into the observations \
table that "Estimate building heights from GNSS" reads: one row per epoch and satellite \
between the elevation masks, with the C/N0 the phone measured, or with an empty C/N0 where \
the phone received nothing (a blocked signal: how 4PL-B learns where buildings block the sky).

<b>GnssLogger logs</b>: the logs of GnssLogger (any version, 1.4 to 3.x; .txt), one receiver \
per log, named by its file name (so no two logs may have the same name).
<b>Orbit files</b>: SP3 precise orbits or RINEX 2/3 navigation files covering the logs (e.g. \
from the IGS or CDDIS archives).
<b>Surveyed positions</b> (optional): a CSV of positions surveyed by hand \
(receiver,start_utc,end_utc,lat,lon,h[,sd]) instead of the logs' own fixes.

Advanced: the fix provider of the logs' positions (gps, the chipset; flp, fused; nlp, \
network), the fixes interpolated in time rather than the nearest, the signal band kept (L1 or \
L5), and bad log lines skipped (counted in the log) instead of stopping.

The output is Parquet or CSV, by its name. The same as <tt>gnss-citygml observe</tt> on the \
command line, with the same defaults."""


class ObserveAlgorithm(Algorithm):
    section = "observe-phone-logs-to-observations"

    def name(self):
        return "observe"

    def displayName(self):  # noqa: N802 (the name QGIS calls)
        return "Turn GnssLogger logs into observations"

    def shortHelpString(self):  # noqa: N802 (the name QGIS calls)
        return HELP

    def define(self):
        for name, description in (
            ("LOGS", "GnssLogger logs (.txt files)"),
            ("ORBITS", "Orbit files (SP3 or RINEX navigation)"),
        ):
            files = QgsProcessingParameterMultipleLayers(name, description, QgsProcessing.TypeFile)
            files.setMinimumNumberInputs(1)  # (as the command line asks for one at least)
            self.addParameter(files)
        self.addParameter(
            QgsProcessingParameterFile(
                "POSITIONS",
                "Surveyed positions (CSV; default: the logs' fixes)",
                fileFilter="CSV (*.csv);;All files (*)",
                optional=True,
            )
        )
        self.addParameter(option("MIN_ELEVATION"))
        self.addParameter(option("MAX_ELEVATION"))
        self.addParameter(
            advanced(
                QgsProcessingParameterEnum(
                    "PROVIDER", "Fix provider of the logs' positions", list(PROVIDERS), False, 0
                )
            )
        )
        self.addParameter(
            advanced(
                QgsProcessingParameterBoolean(
                    "INTERPOLATE", "Interpolate the fixes in time (not the nearest)", False
                )
            )
        )
        self.addParameter(
            advanced(QgsProcessingParameterEnum("BAND", "Signal band kept", list(BANDS), False, 0))
        )
        self.addParameter(
            advanced(
                QgsProcessingParameterBoolean(
                    "LENIENT", "Skip bad log lines (counted) instead of stopping", False
                )
            )
        )
        self.addParameter(
            QgsProcessingParameterFileDestination(
                "OUTPUT", "Observations", "Parquet (*.parquet);;CSV (*.csv)"
            )
        )
        self.addOutput(QgsProcessingOutputNumber("SIGNALS", "Signals"))

    def job(self, parameters, context, feedback):
        output = self.parameterAsFileOutput(parameters, "OUTPUT", context)
        interpolate = self.parameterAsBoolean(parameters, "INTERPOLATE", context)
        args = {
            "logs": self.parameterAsFileList(parameters, "LOGS", context),
            "orbit_files": self.parameterAsFileList(parameters, "ORBITS", context),
            "output": output,
            "surveyed": self.optional_text(parameters, "POSITIONS", context),
            "provider": self.chosen(parameters, "PROVIDER", PROVIDERS, context),
            "method": "interpolate" if interpolate else "nearest",
            "min_elevation": self.parameterAsDouble(parameters, "MIN_ELEVATION", context),
            "max_elevation": self.parameterAsDouble(parameters, "MAX_ELEVATION", context),
            "band": self.chosen(parameters, "BAND", BANDS, context),
            "lenient": self.parameterAsBoolean(parameters, "LENIENT", context),
            "overwrite": True,  # QGIS's file dialog has asked
        }
        result = self.run_job("observe", args, feedback)
        feedback.pushInfo(f"{result['summary']} -> {output}")
        return {"OUTPUT": output, "SIGNALS": result["signals"]}
