"""The plugin object: adds the Processing provider, and says so when the library is missing,
with a button that opens "Set up gnss-citygml"."""

from qgis.core import Qgis, QgsApplication, QgsMessageLog

from . import set_up
from .library import TITLE, needs_set_up, private, repair, unavailable
from .provider import GnssCityGMLProvider

#: The set-up algorithm, which the message bar's button opens.
SET_UP = "gnsscitygml:setup"


class GnssCityGMLPlugin:
    """Registers the provider with QGIS (the desktop and ``qgis_process``)."""

    def __init__(self, iface):
        self.iface = iface
        self.provider = None
        self.message = None

    def initProcessing(self):  # noqa: N802 (the name QGIS calls)
        """Add the provider: called by ``qgis_process`` and by :meth:`initGui`."""
        if self.provider is None:
            self.provider = GnssCityGMLProvider()
            QgsApplication.processingRegistry().addProvider(self.provider)

    def initGui(self):  # noqa: N802 (the name QGIS calls)
        self.initProcessing()
        problem = unavailable()
        own = private()
        if problem is None and own.status == "broken" and needs_set_up():
            # the jobs run with QGIS's own library meanwhile
            problem = repair(
                f"the environment of gnss-citygml in {own.folder} is broken ({own.problem})"
            )
        if problem is not None:
            QgsMessageLog.logMessage(problem, TITLE, Qgis.Warning)
            if self.iface is not None:
                self._say(problem)

    def _say(self, problem):
        """The problem in the message bar, with a "Set up" button when set-up is the fix."""
        bar = self.iface.messageBar()
        if not needs_set_up():
            bar.pushWarning(TITLE, problem)
            return
        from qgis.PyQt.QtWidgets import QPushButton

        self.message = bar.createMessage(TITLE, problem)
        button = QPushButton("Set up", self.message)
        button.setToolTip("Open “Set up gnss-citygml”: it installs the library for the jobs")
        button.clicked.connect(self.open_set_up)
        self.message.layout().addWidget(button)
        bar.pushWidget(self.message, Qgis.Warning)
        set_up.READY.append(self._ready)

    def open_set_up(self):
        """Open the set-up algorithm's dialog."""
        import processing

        processing.execAlgorithmDialog(SET_UP, {})

    def _ready(self):
        """Set-up has made the library usable: the message goes."""
        if unavailable() is None and private().status != "broken":
            self._unsay()

    def _unsay(self):
        """Take the message away."""
        if self.message is not None:
            try:
                self.iface.messageBar().popWidget(self.message)
            except RuntimeError:  # the user closed it: Qt has deleted it
                pass
            self.message = None

    def unload(self):
        self._unsay()
        if self._ready in set_up.READY:
            set_up.READY.remove(self._ready)
        if self.provider is not None:
            QgsApplication.processingRegistry().removeProvider(self.provider)
            self.provider = None
