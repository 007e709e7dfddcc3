"""The plugin object: adds the Processing provider, and says so when the library is missing."""

from qgis.core import Qgis, QgsApplication, QgsMessageLog

from .library import TITLE, unavailable
from .provider import GnssCityGMLProvider


class GnssCityGMLPlugin:
    """Registers the provider with QGIS (the desktop and ``qgis_process``)."""

    def __init__(self, iface):
        self.iface = iface
        self.provider = None

    def initProcessing(self):  # noqa: N802 (the name QGIS calls)
        """Add the provider: called by ``qgis_process`` and by :meth:`initGui`."""
        if self.provider is None:
            self.provider = GnssCityGMLProvider()
            QgsApplication.processingRegistry().addProvider(self.provider)

    def initGui(self):  # noqa: N802 (the name QGIS calls)
        self.initProcessing()
        problem = unavailable()
        if problem is not None:
            QgsMessageLog.logMessage(problem, TITLE, Qgis.Warning)
            if self.iface is not None:
                self.iface.messageBar().pushWarning(TITLE, problem)

    def unload(self):
        if self.provider is not None:
            QgsApplication.processingRegistry().removeProvider(self.provider)
            self.provider = None
