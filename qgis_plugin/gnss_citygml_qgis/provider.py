"""The Processing provider ``gnsscitygml``: its algorithms, icon and output formats."""

from qgis.core import QgsProcessingProvider

from .algorithm import icon
from .convert import ConvertAlgorithm
from .estimate import EstimateAlgorithm
from .library import TITLE, version
from .observe import ObserveAlgorithm
from .report import ReportAlgorithm
from .set_up import SetUpAlgorithm
from .update import UpdateAlgorithm
from .validate import ValidateAlgorithm


class GnssCityGMLProvider(QgsProcessingProvider):
    def id(self):
        return "gnsscitygml"

    def name(self):
        return TITLE

    def longName(self):
        return f"{TITLE} {version()}"

    def icon(self):
        return icon()

    def loadAlgorithms(self):  # noqa: N802 (the name QGIS calls)
        algorithms = (
            ObserveAlgorithm(),
            EstimateAlgorithm(),
            ReportAlgorithm(),
            ConvertAlgorithm(),
            ValidateAlgorithm(),
            UpdateAlgorithm(),
            SetUpAlgorithm(),
        )
        for algorithm in algorithms:
            self.addAlgorithm(algorithm)

    def supportedOutputVectorLayerExtensions(self):  # noqa: N802 (the name QGIS calls)
        """The heights layer is a GeoPackage: its style travels inside it."""
        return ["gpkg"]
