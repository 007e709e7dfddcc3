"""``gnsscitygml:setup``, "Set up gnss-citygml": makes the jobs an environment of their own.

A virtual environment in the QGIS profile's folder (``gnss-citygml/venv``), of a Python found
on this computer (:func:`.environment.find_python`), with the library installed: the wheel
shipped inside the plugin (``wheels/``, put there by ``make plugin``), its requirements from
the package index, or from a folder of wheels when offline. Re-running it upgrades the
environment in place; a broken one (:func:`.environment.state`) is made anew. A new environment
is removed again when set-up fails or is cancelled; one being upgraded is marked incomplete
until set-up has checked it, so that a half-upgraded environment is never used.
"""

import glob
import json
import os
import shutil
import time

from qgis.core import (
    QgsApplication,
    QgsProcessingException,
    QgsProcessingOutputFolder,
    QgsProcessingOutputString,
    QgsProcessingParameterBoolean,
    QgsProcessingParameterFile,
)

from . import environment, library
from .algorithm import Grouped, advanced
from .environment import (
    INCOMPLETE,
    MARKER,
    Cancelled,
    NoPython,
    PipProgress,
    clean_environ,
    follow,
    python_of,
    read_marker,
    wheel_digest,
)

#: Where ``make plugin`` puts the library's wheel inside the plugin.
WHEELS = os.path.join(os.path.dirname(__file__), "wheels")

#: Called (in QGIS's main thread) once set-up has made a sound environment: the plugin takes
#: its "Set up" message away.
READY = []

#: Imports the library and every module its jobs need in the new environment, and prints
#: what is there.
VERIFY = """import json, sys
from importlib import metadata
import gnss_citygml.jobs, gnss_citygml.worker
print(json.dumps({
    "version": metadata.version("gnss-citygml"),
    "python": "%d.%d.%d" % sys.version_info[:3],
    "packages": len({(d.metadata["Name"] or "").lower() for d in metadata.distributions()}
                    - {"pip", "setuptools", "wheel"}),
}))"""

HELP = """Makes the jobs of gnss-citygml an environment of their own, so that nothing needs \
installing into QGIS's Python: a Python virtual environment in the QGIS profile's folder \
(gnss-citygml/venv), made with a Python 3.11 or newer found on this computer (QGIS's own \
where it is the only one), with the gnss-citygml library installed: the wheel inside this \
plugin, and its requirements (numpy, pandas, GDAL's and PROJ's wheels: about 200 MB) from \
the package index.

Run it again to upgrade the environment in place; an environment that is broken (its Python \
gone, the library not importing, another version than this plugin's) is made anew. Cancel \
leaves no half environment.

<b>Folder of wheels</b> (advanced, offline): install the requirements from this folder only, \
made where there is a network, by the same Python version on the same system, with \
<tt>pip download --dest wheels gnss_citygml-VERSION-py3-none-any.whl</tt> (the wheel in this \
plugin's folder, under wheels/).
<b>Make the environment anew</b> (advanced): remove it first, and make it from scratch."""


def shipped_wheel(version):
    """The library's wheel inside the plugin, at ``version``, or None."""
    found = sorted(glob.glob(os.path.join(WHEELS, f"gnss_citygml-{version}-*.whl")))
    return found[-1] if found else None


class Failed(Exception):
    """Set-up failed: the one-line message says what to do."""


class SetUpAlgorithm(Grouped):
    """The algorithm: it can always run (it is what makes the others runnable)."""

    section = "install-the-plugin-then-set-up-gnss-citygml"

    def name(self):
        return "setup"

    def displayName(self):  # noqa: N802 (the name QGIS calls)
        return library.SET_UP

    def shortHelpString(self):  # noqa: N802 (the name QGIS calls)
        return HELP

    def canExecute(self):  # noqa: N802 (the name QGIS calls)
        return True, ""

    def initAlgorithm(self, config=None):  # noqa: N802 (the name QGIS calls)
        self.addParameter(
            advanced(
                QgsProcessingParameterFile(
                    "WHEELS",
                    "Folder of wheels (offline: the requirements from there only)",
                    behavior=QgsProcessingParameterFile.Folder,
                    optional=True,
                )
            )
        )
        self.addParameter(
            advanced(QgsProcessingParameterBoolean("RECREATE", "Make the environment anew", False))
        )
        self.addOutput(QgsProcessingOutputFolder("FOLDER", "The environment"))
        self.addOutput(QgsProcessingOutputString("PYTHON", "The jobs' Python"))
        self.addOutput(QgsProcessingOutputString("VERSION", "gnss-citygml's version"))
        self.addOutput(QgsProcessingOutputString("BASE_PYTHON", "The Python it was made from"))
        self.addOutput(QgsProcessingOutputString("ACTION", "made, upgraded or remade"))

    def processAlgorithm(self, parameters, context, feedback):  # noqa: N802 (the name QGIS calls)
        self.ready = False
        job = SetUp(
            feedback,
            wheels=self.parameterAsFile(parameters, "WHEELS", context) or None,
            recreate=self.parameterAsBoolean(parameters, "RECREATE", context),
        )
        try:
            done = job.run()
        except (Failed, NoPython) as exc:
            raise QgsProcessingException(str(exc)) from None
        self.ready = True
        return done

    def postProcessAlgorithm(self, context, feedback):  # noqa: N802 (the name QGIS calls)
        """In QGIS's main thread: the other algorithms get their parameters (the library is
        there now), and the plugin's "Set up" message goes."""
        if getattr(self, "ready", False):
            provider = QgsApplication.processingRegistry().providerById("gnsscitygml")
            if provider is not None:
                provider.refreshAlgorithms()
            for ready in list(READY):
                ready()
        return {}


class SetUp:
    """One run of set-up, reporting to a Processing ``feedback``; :meth:`run` does it."""

    def __init__(self, feedback, folder=None, wheels=None, recreate=False):
        self.feedback = feedback
        self.folder = folder or environment.location()
        self.version = library.plugin_version()
        self.wheel = shipped_wheel(self.version)
        self.wheels = wheels
        self.recreate = recreate
        self.base = None

    def run(self):
        """Make, upgrade or remake the environment; its outputs (see the algorithm's)."""
        if not self.folder:
            raise Failed("QGIS names no profile folder to make gnss-citygml's environment in")
        if self.wheels and not os.path.isdir(self.wheels):
            raise Failed(f"the folder of wheels {self.wheels} is not a folder: name the folder")
        current = environment.state(self.folder, self.version)
        action, before = "upgraded", read_marker(self.folder)
        if current.status == "broken" or (self.recreate and current.status == "sound"):
            why = f"is broken ({current.problem})" if current.problem else "is to be made anew"
            self.info(f"the environment {self.folder} {why}: removing it")
            self._remove()
            action, before = "remade", {}
        fresh = action == "remade" or current.status == "absent"
        if fresh:
            action = "made" if action == "upgraded" else action
            try:
                base = self.base = self._make()
            except Cancelled:
                raise Failed("cancelled: no environment was made") from None
        else:
            made_with = before.get("python") or environment.home(self.folder) or "?"
            base = self.base = environment.Python(made_with, before.get("base", "?"), False)
            self.info(f"upgrading the environment {self.folder} in place")
            self._mark(True)
        try:
            installed = self._install(fresh, before)
        except BaseException as exc:
            outcome = self._undo(fresh)
            if isinstance(exc, Cancelled):
                raise Failed(f"cancelled: {outcome}") from None
            self.info(outcome)
            raise
        marker = {
            "version": installed["version"],
            "wheel": wheel_digest(self.wheel) if self.wheel else None,
            "python": base.path,
            "base": base.version,
            "packages": installed["packages"],
            "made": before.get("made") or _now(),
            "updated": _now(),
        }
        with open(os.path.join(self.folder, MARKER), "w", encoding="utf-8") as file:
            json.dump(marker, file, indent=1)
        self._mark(False)
        return self._report(action, base, installed)

    def _make(self):
        """Find a Python and make a new virtual environment with it (removed again if that
        fails or is cancelled)."""
        self.progress("looking for Python 3.11 or newer", 0)
        base = environment.find_python(library.qgis_python())
        self.info(f"Python used: {base.path} (Python {base.version})")
        os.makedirs(self.folder)
        try:
            self._mark(True)
            self.progress(f"making a virtual environment in {self.folder}", 0.02)
            command = [base.path, "-m", "venv", self.folder]
            env = clean_environ(keep_home=base.own)
            code, lines = follow(command, self.console, self.feedback.isCanceled, env=env)
            if code != 0:
                last = lines[-1] if lines else f"exit status {code}"
                raise Failed(f"{base.path} could not make a virtual environment ({last})")
        except BaseException:
            shutil.rmtree(self.folder, ignore_errors=True)
            raise
        return base

    def _install(self, fresh, before):
        """pip: the library and its requirements, then check that it imports."""
        python = python_of(self.folder)
        requirement = self.wheel or f"gnss-citygml=={self.version}"
        pip = [python, "-I", "-u", "-m", "pip", "install", "--upgrade", "--no-input"]
        pip += ["--disable-pip-version-check", "--progress-bar", "off"]
        # retried, pip says why the index did not answer (pip_failure tells no network so)
        pip += ["--no-warn-script-location", "--retries", "3"]
        if self.wheels:
            pip += ["--no-index", "--find-links", self.wheels]
        expected = before.get("packages") or environment.EXPECTED_PACKAGES
        self._pip(pip + [requirement], expected, 0.1, 0.85)
        digest = wheel_digest(self.wheel) if self.wheel else None
        if not fresh and digest and before.get("wheel") != digest:
            # the same version, built anew: pip would keep the installed one
            self._pip(pip + ["--force-reinstall", "--no-deps", requirement], 1, 0.85, 0.9)
        self.progress("checking that the library imports there", 0.9)
        found = environment.ask(python, VERIFY, timeout=300)
        if "error" in found:
            raise Failed(f"the library does not import in the new environment ({found['error']})")
        if found["version"] != self.version:
            raise Failed(
                f"pip installed gnss-citygml {found['version']}, not this plugin's {self.version}"
            )
        return found

    def _pip(self, command, expected, start, end):
        """Run pip, its output as progress from ``start`` to ``end``; its failure in one line."""
        progress = PipProgress(expected)

        def line(text):
            self.console(text)
            said, share = progress.feed(text)
            if said:
                self.feedback.setProgressText(said)
            if share is not None:
                self.feedback.setProgress(100.0 * (start + (end - start) * share))

        code, lines = follow(command, line, self.feedback.isCanceled, env=clean_environ())
        if code != 0:
            known = self.base.version[:1].isdigit()  # not known of an old environment
            python = ".".join(self.base.version.split(".")[:2]) if known else None
            requirement = self.wheel or f"gnss-citygml=={self.version}"
            raise Failed(environment.pip_failure(lines, requirement, self.wheels, python))

    def _undo(self, fresh):
        """After a failure or Cancel: a new environment removed, one being upgraded left
        marked incomplete unless it is still sound. What became of it, in words."""
        if fresh:
            shutil.rmtree(self.folder, ignore_errors=True)
            return "no environment was made"
        self._mark(False)
        if environment.state(self.folder, self.version).status == "sound":
            return f"the environment {self.folder} is as it was"
        self._mark(True)
        return (
            f"the environment {self.folder} was left half upgraded: run {library.SET_UP} "
            "again to repair it"
        )

    def _remove(self):
        """Remove the environment, if set-up made it (never another folder)."""
        ours = any(
            os.path.exists(os.path.join(self.folder, name))
            for name in ("pyvenv.cfg", MARKER, INCOMPLETE)
        )
        if not ours:
            raise Failed(
                f"{self.folder} is not an environment that {library.SET_UP} made: move it "
                "away and run it again"
            )
        try:
            shutil.rmtree(self.folder)
        except OSError as exc:
            raise Failed(
                f"cannot remove the environment {self.folder} ({exc}): remove that folder, "
                f"and run {library.SET_UP} again"
            ) from None

    def _mark(self, incomplete):
        """Mark the environment incomplete (while set-up changes it), or not."""
        path = os.path.join(self.folder, INCOMPLETE)
        if incomplete:
            with open(path, "w", encoding="utf-8") as file:
                file.write(f"{library.SET_UP} is changing this environment (since {_now()})\n")
        elif os.path.exists(path):
            os.remove(path)

    def _report(self, action, base, installed):
        """Say what was done; the outputs."""
        python = python_of(self.folder)
        source = os.path.basename(self.wheel) if self.wheel else "the package index"
        requirements = f"the folder {self.wheels}" if self.wheels else "the package index"
        made = {
            "made": f"made the environment {self.folder} with {base.path}",
            "remade": f"made the environment {self.folder} anew with {base.path}",
            "upgraded": f"upgraded the environment {self.folder} in place (made with {base.path})",
        }[action]
        self.info(f"{made}: Python {installed['python']}")
        self.info(
            f"installed gnss-citygml {installed['version']} from {source} and its "
            f"{installed['packages'] - 1} requirements from {requirements}"
        )
        if os.environ.get(library.PYTHON_VARIABLE):
            self.feedback.pushWarning(
                f"{library.PYTHON_VARIABLE} is set: the jobs run with "
                f"{os.environ[library.PYTHON_VARIABLE]}, not this environment, until it is unset"
            )
        else:
            self.info(f"the jobs now run with {python}")
        self.progress("done", 1)
        return {
            "FOLDER": self.folder,
            "PYTHON": python,
            "VERSION": installed["version"],
            "BASE_PYTHON": base.path,
            "ACTION": action,
        }

    def progress(self, text, share):
        self.feedback.setProgressText(text)
        self.feedback.setProgress(100.0 * share)

    def info(self, text):
        self.feedback.pushInfo(text)

    def console(self, text):
        self.feedback.pushConsoleInfo(text)


def _now():
    return time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
