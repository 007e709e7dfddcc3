"""Is the gnss-citygml library usable from QGIS, which Python runs the jobs, and if none can,
what to do.

QGIS runs its own Python (Debian's ``/usr/bin/python3``, OSGeo4W's, the macOS bundle's), which
has no gnss-citygml until the user installs it there, or until "Set up gnss-citygml" makes the
jobs an environment of their own in the QGIS profile's folder (:mod:`.environment`). The jobs'
Python is ``$GNSS_CITYGML_PYTHON`` if set, else that environment's if it is sound, else QGIS's
own. The plugin must still load when none has the library, and say exactly what is missing and
what to do. This module uses nothing newer than Python 3.7, so that even a QGIS on an old
Python gets the message.
"""

import configparser
import importlib
import importlib.machinery
import importlib.util
import os
import re
import shutil
import sys
from importlib import metadata

from . import environment

TITLE = "gnss-citygml"
DISTRIBUTION = "gnss-citygml"
README = "https://github.com/gnss-citygml/gnss-citygml#qgis"
PYTHON = (3, 11)

#: The Python that runs the jobs, when not QGIS's own (e.g. a virtual environment's).
PYTHON_VARIABLE = "GNSS_CITYGML_PYTHON"


#: The name of the algorithm that makes the jobs' environment, as a user finds it.
SET_UP = "Set up gnss-citygml"


def version():
    """The version of the library the jobs run, or "not installed"."""
    if not os.environ.get(PYTHON_VARIABLE):
        own = private()
        if own.status == "sound":
            return own.version
    try:
        return metadata.version(DISTRIBUTION)
    except metadata.PackageNotFoundError:
        return "(library not installed)"


def private():
    """The state of the jobs' own environment in the QGIS profile (:func:`environment.state`)."""
    return environment.state(environment.location(), plugin_version())


def unavailable():
    """Why the algorithms cannot run in this QGIS, with what to do; None when they can.

    Python's version; the Python that runs the jobs, when one is configured; the installed
    distributions' metadata (gnss-citygml, at this plugin's version, and each of its
    requirements at its minimum version); and the library's pure-Python modules that the
    algorithms' parameters read (:data:`MODULES`), imported: a half-installed library (its
    metadata without its modules, or modules that fail to import) must not stop QGIS loading
    the plugin. No compiled module is loaded into QGIS; a broken one is reported when a job
    runs, with the child's message.

    Without ``$GNSS_CITYGML_PYTHON``, a sound environment of the jobs' own (made by
    :data:`SET_UP`) comes first: its ``gnss_citygml`` package, and only that, is then imported
    into QGIS from there (:class:`_Library`). When it is broken and QGIS's Python has no usable
    library either, the message says to run :data:`SET_UP` again.
    """
    if sys.version_info[:2] < PYTHON:
        return (
            "{} needs Python {}.{} or newer; this QGIS runs Python {}.{}: use a QGIS built "
            "with a newer Python (QGIS 3.22 on Debian 12, or any QGIS 3.34 or newer)".format(
                TITLE, *PYTHON, *sys.version_info[:2]
            )
        )
    if os.environ.get(PYTHON_VARIABLE):
        return _configured_python() or _installed() or _not_importable()
    own = private()
    _Library.use(own.site if own.status == "sound" else None)
    if own.status == "sound":
        return _not_importable(own.folder)
    problem = _installed() or _not_importable()
    if problem is not None and own.status == "broken":
        return repair(f"the environment of gnss-citygml in {own.folder} is broken ({own.problem})")
    return problem


def needs_set_up():
    """Whether :data:`SET_UP` is what makes the library usable (not a Python too old, nor
    ``$GNSS_CITYGML_PYTHON``, which the jobs would run with whatever it makes)."""
    return sys.version_info[:2] >= PYTHON and not os.environ.get(PYTHON_VARIABLE)


def repair(what):
    """The message: what is wrong with the jobs' own environment, and how to repair it."""
    return f"{what}: run {SET_UP} (Processing Toolbox, GNSS 3D mapping) to make it anew"


class _Library:
    """Finds the package ``gnss_citygml`` (and nothing else) in the jobs' own environment, for
    the modules the algorithms import into QGIS (:data:`MODULES`, pure Python): the rest of
    that environment's site-packages (numpy, ...) is never on QGIS's path, where it would clash
    with QGIS's own. First on ``sys.meta_path``, so that QGIS shows the defaults of the library
    that runs the jobs."""

    site = None

    @classmethod
    def use(cls, site):
        """Find ``gnss_citygml`` in the folder ``site`` from now on (None: stop)."""
        if site != cls.site:
            importlib.invalidate_caches()
        cls.site = site
        if site is not None and cls not in sys.meta_path:
            sys.meta_path.insert(0, cls)

    @classmethod
    def find_spec(cls, name, path=None, target=None):
        if name != "gnss_citygml" or cls.site is None:
            return None
        return importlib.machinery.PathFinder.find_spec(name, [cls.site])


def _configured_python():
    """What is wrong with ``$GNSS_CITYGML_PYTHON``, when it is set: a Python that is not
    there, or not a program."""
    python = os.environ.get(PYTHON_VARIABLE)
    if not python or shutil.which(python):
        return None
    return (
        f"{PYTHON_VARIABLE} names {python}, which {_not_a_program(python)}: set it to a Python "
        "that has gnss-citygml (e.g. a virtual environment's bin/python), or unset it to run "
        "the jobs in QGIS's own Python; then restart QGIS"
    )


def _not_a_program(path):
    """Why ``path`` cannot be run, in words."""
    if not os.path.exists(path):
        return "does not exist"
    if os.path.isdir(path):
        return "is a folder"
    return "is not executable"


def _installed():
    """What is wrong with the installed distributions: the library missing, or installed
    without its metadata, a requirement missing or too old, or a library of another release
    than this plugin's."""
    missing = _missing_requirements()
    if missing == _NO_LIBRARY:
        found = _spec("gnss_citygml")
        if found is not None:
            folder = list(found.submodule_search_locations or []) or [found.origin]
            return install(
                f"QGIS's Python has gnss_citygml ({folder[0]}) without its installed metadata "
                "(a copy, or what an uninstall left): remove that folder, and install the "
                "library properly"
            )
    if missing:
        return install(f"{missing} missing from QGIS's Python")
    library, plugin = version(), plugin_version()
    if plugin and library != plugin:
        return install(
            f"QGIS's Python has gnss-citygml {library} and this plugin is {plugin}, which "
            f"work together only as the same release: update the plugin to {library}, or "
            "install the plugin's release of the library",
            f"gnss-citygml=={plugin}",
        )
    return None


_NO_LIBRARY = "the gnss-citygml library is"

#: The library's modules that the algorithms import in QGIS's own process, for their
#: parameters' options and defaults (pure Python: no compiled module).
MODULES = ("gnss_citygml.model", "gnss_citygml.settings")


def _spec(module):
    """Where ``module`` would be imported from (not importing it), or None."""
    try:
        return importlib.util.find_spec(module)
    except (ImportError, ValueError):
        return None


def _not_importable(folder=None):
    """Why the library's :data:`MODULES` do not import in QGIS's Python (from the jobs' own
    environment ``folder``, when given), or None."""
    for module in MODULES:
        try:
            importlib.import_module(module)
        except Exception as exc:  # a broken install: any error of its import
            lines = str(exc).strip().splitlines() or [""]
            why = f"{type(exc).__name__}: {lines[0]}".rstrip(": ")
            if folder is not None:
                return repair(
                    f"the environment of gnss-citygml in {folder} is broken: import {module} "
                    f"fails in QGIS ({why})"
                )
            return install(
                f"the gnss-citygml library in QGIS's Python is broken: import {module} "
                f"fails ({why})",
                reinstall=True,
            )
    return None


def plugin_version():
    """This plugin's version (its metadata.txt), or None when it does not say."""
    meta = configparser.ConfigParser(interpolation=None)
    meta.read(os.path.join(os.path.dirname(__file__), "metadata.txt"), encoding="utf-8")
    return meta.get("general", "version", fallback=None)


def _missing_requirements():
    """The library, or the first of its requirements missing or older than it needs, as text."""
    try:
        requires = metadata.requires(DISTRIBUTION) or []
    except metadata.PackageNotFoundError:
        return _NO_LIBRARY
    for requirement in requires:
        if "extra ==" in requirement:
            continue
        match = re.match(r"\s*([A-Za-z0-9_.\-]+)\s*(?:>=\s*([0-9.]+))?", requirement)
        name, minimum = match.group(1), match.group(2)
        try:
            installed = metadata.version(name)
        except metadata.PackageNotFoundError:
            return f"{name} (needed by gnss-citygml) is"
        if minimum and _numbers(installed) < _numbers(minimum):
            return f"{name} {installed} is too old (gnss-citygml needs {minimum} or newer) and"
    return None


def _numbers(text):
    """A version's leading numbers, to compare: "1.26.4" -> (1, 26, 4); "2.0rc1" -> (2, 0)."""
    return tuple(int(part) for part in re.findall(r"\d+", text.split("rc")[0].split("+")[0])[:3])


def install(what, requirement=DISTRIBUTION, reinstall=False):
    """The message: what is wrong, and what to do: run :data:`SET_UP` (unless
    ``$GNSS_CITYGML_PYTHON`` is set), or the command that installs the library into the Python
    that runs the jobs (``requirement``, e.g. a release; ``reinstall``: its files and its
    requirements' again)."""
    configured = os.environ.get(PYTHON_VARIABLE)
    command = f'"{configured or qgis_python()}" -m pip install --user --upgrade '
    command += "--force-reinstall " * reinstall + (
        requirement if requirement == DISTRIBUTION else f'"{requirement}"'
    )
    if _numpy_below_2():
        # QGIS's own compiled modules (GDAL's Python bindings) are built for numpy 1
        command += ' "numpy<2"'
    if os.path.exists(
        os.path.join(
            sys.prefix, "lib", "python{}.{}".format(*sys.version_info[:2]), "EXTERNALLY-MANAGED"
        )
    ):
        # Debian/Ubuntu: pip refuses the system Python unless told; --user keeps it in ~/.local
        command += " --break-system-packages"
    verb = "reinstall" if reinstall else "install"
    if configured:
        return (
            f"{what}. {verb.capitalize()} it there, then restart QGIS: {command} (more in {README})"
        )
    return (
        f"{what}: run {SET_UP} (Processing Toolbox, GNSS 3D mapping), which installs it in an "
        f"environment of its own, or {verb} it into QGIS's Python and restart QGIS: {command} "
        f"(more in {README})"
    )


def _numpy_below_2():
    """Whether this Python has numpy 1, which QGIS's own compiled modules were then built for."""
    try:
        return _numbers(metadata.version("numpy")) < (2,)
    except metadata.PackageNotFoundError:
        return False


def interpreter():
    """The Python that runs the jobs: ``$GNSS_CITYGML_PYTHON``, or the jobs' own environment's
    if it is sound, or the one QGIS runs."""
    if os.environ.get(PYTHON_VARIABLE):
        return os.environ[PYTHON_VARIABLE]
    own = private()
    if own.status == "sound":
        return own.python
    return qgis_python()


def job_command():
    """How to start the jobs' Python: the program and its options, and its environment
    variables (None: QGIS's). The jobs' own environment runs isolated from QGIS's Python
    settings (PYTHONPATH, PYTHONHOME) and the user's site folder."""
    python = interpreter()
    own = private()
    if not os.environ.get(PYTHON_VARIABLE) and own.status == "sound" and own.python == python:
        return [python, "-I"], environment.clean_environ()
    return [python], None


def qgis_python():
    """The Python that QGIS runs (QGIS's own executable is not it)."""
    if os.path.basename(sys.executable).lower().startswith("python"):
        return sys.executable
    version = "python{}.{}".format(*sys.version_info[:2])
    candidates = [
        os.path.join(sys.prefix, "python.exe"),  # OSGeo4W, the Windows installers
        os.path.join(sys.prefix, "bin", version),  # Linux, macOS
        os.path.join(sys.prefix, "bin", "python3"),
    ]
    return next((path for path in candidates if os.path.exists(path)), version)
