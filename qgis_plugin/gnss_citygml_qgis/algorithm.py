"""What the algorithms share: group, icon, help link, the library check, and running the
library's job in a child Python with its progress, warnings, Cancel and one-line errors."""

import functools
import json
import os
import signal
import subprocess
import sys
import tempfile

from qgis.core import (
    QgsProcessingAlgorithm,
    QgsProcessingException,
    QgsProcessingParameterBoolean,
    QgsProcessingParameterDefinition,
    QgsProcessingParameterEnum,
    QgsProcessingParameterField,
    QgsProcessingParameterFile,
    QgsProcessingParameterNumber,
)
from qgis.PyQt.QtGui import QIcon

from .library import README, install, job_command, repair, unavailable

ICON = os.path.join(os.path.dirname(__file__), "icon.svg")


def icon():
    return QIcon(ICON)


#: The child's error when Cancel stopped it (gnss_citygml.worker.CANCELLED).
CANCELLED = "cancelled"

#: The child in a process group of its own on Windows, where Cancel sends it CTRL_BREAK.
_GROUP = {"creationflags": subprocess.CREATE_NEW_PROCESS_GROUP} if sys.platform == "win32" else {}


def _interrupt(child):
    """Ask the child to stop as Ctrl-C does: it cleans up what it was writing."""
    if child.poll() is None:
        child.send_signal(signal.CTRL_BREAK_EVENT if sys.platform == "win32" else signal.SIGINT)


class Grouped(QgsProcessingAlgorithm):
    """An algorithm of the toolkit's group, with its icon and a Help button that opens its
    section of the README (:attr:`section`)."""

    #: The anchor of the README's section on the job: the Help button opens it.
    section = "qgis"

    def helpUrl(self):  # noqa: N802 (the name QGIS calls)
        return f"{README.split('#')[0]}#{self.section}"

    def group(self):
        return "GNSS 3D mapping"

    def groupId(self):  # noqa: N802 (the name QGIS calls)
        return "gnss3dmapping"

    def icon(self):
        return icon()

    def createInstance(self):  # noqa: N802 (the name QGIS calls)
        return type(self)()


class Algorithm(Grouped):
    """A Processing algorithm that runs one job of the library.

    Subclasses define :meth:`define` (the parameters, with the library's own defaults) and
    :meth:`job` (parse the parameters, :meth:`run_job`, the outputs), and :attr:`section`.
    Everything else is here, once.
    """

    def canExecute(self):  # noqa: N802 (the name QGIS calls)
        problem = unavailable()
        return problem is None, problem or ""

    def checkParameterValues(self, parameters, context):  # noqa: N802 (the name QGIS calls)
        problem = unavailable()
        if problem is not None:
            return False, problem
        return super().checkParameterValues(parameters, context)

    def initAlgorithm(self, config=None):  # noqa: N802 (the name QGIS calls)
        if unavailable() is None:
            self.define()

    def define(self):
        """Add the parameters and outputs (the library is installed)."""
        raise NotImplementedError

    def processAlgorithm(self, parameters, context, feedback):  # noqa: N802 (the name QGIS calls)
        problem = unavailable()
        if problem is not None:
            raise QgsProcessingException(problem)
        return self.job(parameters, context, feedback)

    def job(self, parameters, context, feedback):
        """Parse the parameters, run the job (:meth:`run_job`), return the outputs."""
        raise NotImplementedError

    def run_job(self, job, args, feedback):
        """Run the library's ``job`` with ``args`` in a child Python (``gnss_citygml.worker``,
        whose docstring says why not in QGIS's process): its progress and warnings go to
        QGIS, Cancel interrupts it (it then removes what it was writing), and its error is
        the command line's one-line message. Returns the job's result."""
        command, env = job_command()
        python = command[0]
        # the jobs' own environment, when they run there (job_command): repaired by set-up
        fix = install if env is None else repair
        with tempfile.TemporaryFile("w+", encoding="utf-8", errors="replace") as stderr:
            try:
                child = subprocess.Popen(
                    [*command, "-m", "gnss_citygml.worker"],
                    stdin=subprocess.PIPE,
                    stdout=subprocess.PIPE,
                    stderr=stderr,
                    text=True,
                    encoding="utf-8",
                    env=env,
                    **_GROUP,
                )
            except OSError as exc:
                raise QgsProcessingException(fix(f"cannot start {python} ({exc})")) from None
            interrupt = functools.partial(_interrupt, child)
            feedback.canceled.connect(interrupt)
            try:
                with child:
                    child.stdin.write(json.dumps({"job": job, "args": args}))
                    child.stdin.close()
                    if feedback.isCanceled():
                        interrupt()
                    outcome = self._follow(child, feedback)
            finally:
                feedback.canceled.disconnect(interrupt)
            stderr.seek(0)
            printed = stderr.read().strip()
        if printed:
            feedback.pushDebugInfo(printed)
        if "result" in outcome:
            return outcome["result"]
        if outcome.get("error") == CANCELLED:
            raise QgsProcessingException("cancelled: nothing was written")
        if "error" in outcome:
            raise QgsProcessingException(outcome["error"])
        last = printed.splitlines()[-1] if printed else f"exit status {child.returncode}"
        raise QgsProcessingException(fix(f"{python} cannot run gnss-citygml ({last})"))

    @staticmethod
    def _follow(child, feedback):
        """Pass the child's progress and warnings on to QGIS; return its last word."""
        for line in child.stdout:
            message = json.loads(line)
            if "progress" in message:
                what, done = message["progress"]
                feedback.setProgressText(what)
                feedback.setProgress(100.0 * done)
            elif "warning" in message:
                feedback.pushWarning("warning: " + message["warning"])
            else:
                return message
        return {}

    def optional_number(self, parameters, name, context):
        """An optional number parameter: None when not given (not 0)."""
        if parameters.get(name) in (None, ""):
            return None
        return self.parameterAsDouble(parameters, name, context)

    def optional_text(self, parameters, name, context):
        """An optional string, field or folder parameter: None when empty."""
        return self.parameterAsString(parameters, name, context) or None

    def chosen(self, parameters, name, options, context):
        """The one of ``options`` that a choice parameter chose."""
        return options[self.parameterAsEnum(parameters, name, context)]

    def settings(self, parameters, names, context):
        """The settings objects' arguments (``{"rays": {...}, "estimator": {...}}``) from the
        parameters of the library's options ``names`` (:func:`option`)."""
        from gnss_citygml.options import OPTIONS, settings_arguments

        values = {}
        for name in names:
            spec = OPTIONS[name]
            if spec.kind == "switch":
                values[name] = self.parameterAsBoolean(parameters, name, context)
            elif spec.kind == "choice":
                values[name] = self.chosen(parameters, name, spec.choices, context)
            elif spec.kind == "field":
                values[name] = self.optional_text(parameters, name, context)
            elif spec.kind == "count":
                values[name] = self.parameterAsInt(parameters, name, context)
            elif spec.optional:
                values[name] = self.optional_number(parameters, name, context)
            else:
                values[name] = self.parameterAsDouble(parameters, name, context)
        return settings_arguments(values, names)


def advanced(parameter):
    """``parameter`` shown under "Advanced parameters"."""
    parameter.setFlags(parameter.flags() | QgsProcessingParameterDefinition.FlagAdvanced)
    return parameter


#: The sentence of the algorithms' help on the signal model (estimate, update).
SIGNAL_MODEL_HELP = (
    "The signal model (advanced) is how 4PL-B tells open signals from closed ones: the "
    "paper's C/N0 threshold trained on the map's labels, or a mixture of open and closed "
    "signals' C/N0 by elevation learnt by EM. Each phone's C/N0 is first put on one level, "
    "learnt from its signals that cross no footprint (phones differ by a few dB-Hz)."
)


def option(name):
    """The parameter of the library's option ``name`` (``gnss_citygml.options.OPTIONS``: the
    command line's option made from the same declaration): its label, default, range and
    choices."""
    from gnss_citygml.options import OPTIONS

    spec = OPTIONS[name]
    if spec.kind == "switch":
        return QgsProcessingParameterBoolean(name, spec.label, defaultValue=spec.default)
    if spec.kind == "choice":
        return QgsProcessingParameterEnum(
            name,
            spec.label,
            options=list(spec.words or spec.choices),
            defaultValue=spec.choices.index(spec.default),
        )
    if spec.kind == "field":
        return QgsProcessingParameterField(
            name,
            spec.label,
            parentLayerParameterName="FOOTPRINTS",
            type=QgsProcessingParameterField.Numeric,
            optional=True,
        )
    low, high = spec.bounds
    whole = spec.kind == "count"
    return QgsProcessingParameterNumber(
        name,
        spec.label,
        QgsProcessingParameterNumber.Integer if whole else QgsProcessingParameterNumber.Double,
        spec.default,
        optional=spec.optional,
        minValue=low,
        maxValue=high,
    )


def folder(name, description):
    """An optional folder parameter (advanced)."""
    return advanced(
        QgsProcessingParameterFile(
            name, description, behavior=QgsProcessingParameterFile.Folder, optional=True
        )
    )
