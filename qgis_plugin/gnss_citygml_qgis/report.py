"""``gnsscitygml:report``: observations + footprint layer + DEM -> the report of the run.

The same job as ``gnss-citygml report`` (:func:`gnss_citygml.jobs.estimate_file` with a report
folder and no heights layer), with the inputs and options of ``estimate``
(:class:`~.estimate.RunAlgorithm`); the page opens in the web browser when QGIS's desktop ran
it and the user did not say otherwise.
"""

from qgis.core import (
    QgsApplication,
    QgsProcessingOutputHtml,
    QgsProcessingOutputNumber,
    QgsProcessingParameterBoolean,
    QgsProcessingParameterFile,
    QgsProcessingParameterFolderDestination,
)
from qgis.PyQt.QtCore import QUrl
from qgis.PyQt.QtGui import QDesktopServices

from .algorithm import SIGNAL_MODEL_HELP, advanced
from .estimate import INPUTS_HELP, RunAlgorithm

HELP = (
    """Estimates the building heights as "Estimate building heights from GNSS" does, with \
the same inputs and options, and writes the report of the run into a folder: report.html, \
one page with its figures embedded (so it can be mailed or archived as one file), and the \
figures as PNGs in figures/. It shows a map of the buildings by height (those without one \
hatched by their status) with the receivers' tracks, the heights' ranges, the height fits of \
the worst, best and sampled buildings, skyplots, C/N0 by final label with the signal \
classifier, and a table of every building. The page opens in the web browser when the run is \
done (advanced: untick to leave it closed).

"""
    + INPUTS_HELP
    + """
<b>Truth table</b> (advanced, optional): a simulator's truth (id, height, ground; CSV or \
Parquet), which adds the true heights and the errors to the report.

The report draws its figures with matplotlib, an extra of the library (pip install \
"gnss-citygml[plot]"): the algorithm says so when it is missing.

"""
    + SIGNAL_MODEL_HELP
    + """

The same as <tt>gnss-citygml report</tt> on the command line, with the same defaults."""
)


def shows_pages():
    """Whether a page may be opened in the web browser: in QGIS's desktop, not in
    ``qgis_process``, a script or the tests (QGIS's ``platform()`` names which)."""
    return QgsApplication.platform() == "desktop"


class ReportAlgorithm(RunAlgorithm):
    section = "the-report-what-the-estimator-did"

    def name(self):
        return "report"

    def displayName(self):  # noqa: N802 (the name QGIS calls)
        return "Report of a height estimate"

    def shortHelpString(self):  # noqa: N802 (the name QGIS calls)
        return HELP

    def define(self):
        self.define_run()
        self.addParameter(
            advanced(
                QgsProcessingParameterFile(
                    "TRUTH",
                    "Truth table (a simulator's: CSV or Parquet)",
                    fileFilter="Tables (*.csv *.parquet);;All files (*)",
                    optional=True,
                )
            )
        )
        self.addParameter(
            advanced(
                QgsProcessingParameterBoolean(
                    "OPEN", "Open the report in the web browser when done", True
                )
            )
        )
        self.addParameter(QgsProcessingParameterFolderDestination("OUTPUT", "Report folder"))
        self.addOutput(QgsProcessingOutputHtml("PAGE", "Report"))
        self.addOutput(QgsProcessingOutputNumber("BUILDINGS", "Buildings"))
        self.addOutput(QgsProcessingOutputNumber("CONVERGED", "Buildings with a height"))

    def job(self, parameters, context, feedback):
        folder = self.parameterAsFileOutput(parameters, "OUTPUT", context)
        args = {
            **self.run_args(parameters, context, feedback),
            "report": folder,
            "truth": self.optional_text(parameters, "TRUTH", context),
            "overwrite": True,  # the report's own files only (report.html, figures/*.png)
        }
        result = self.run_job("report", args, feedback)
        feedback.pushInfo(
            f"{result['converged']} of {result['buildings']} buildings have a height; "
            f"report -> {result['page']}"
        )
        opens = self.parameterAsBoolean(parameters, "OPEN", context) and shows_pages()
        self.page = result["page"] if opens else None
        return {
            "OUTPUT": folder,
            "PAGE": result["page"],
            "BUILDINGS": result["buildings"],
            "CONVERGED": result["converged"],
        }

    def postProcessAlgorithm(self, context, feedback):  # noqa: N802 (the name QGIS calls)
        """In QGIS's main thread, once the report is written: the page in the web browser."""
        page = getattr(self, "page", None)
        if page is not None and not QDesktopServices.openUrl(QUrl.fromLocalFile(page)):
            feedback.pushWarning(f"the report could not be opened in a web browser: {page}")
        return {}
