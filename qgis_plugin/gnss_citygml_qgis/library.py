"""Is the gnss-citygml library usable from QGIS's Python, and if not, what to install and how.

QGIS runs its own Python (Debian's ``/usr/bin/python3``, OSGeo4W's, the macOS bundle's), which
has no gnss-citygml until the user installs it there. The plugin must still load then, and say
exactly what is missing and the command that installs it into *that* Python. This module uses
nothing newer than Python 3.7, so that even a QGIS on an old Python gets the message.
"""

import configparser
import importlib
import importlib.util
import os
import re
import shutil
import sys
from importlib import metadata

TITLE = "gnss-citygml"
DISTRIBUTION = "gnss-citygml"
README = "https://github.com/gnss-citygml/gnss-citygml#qgis"
PYTHON = (3, 11)

#: The Python that runs the jobs, when not QGIS's own (e.g. a virtual environment's).
PYTHON_VARIABLE = "GNSS_CITYGML_PYTHON"


def version():
    """The library's version, or "not installed"."""
    try:
        return metadata.version(DISTRIBUTION)
    except metadata.PackageNotFoundError:
        return "(library not installed)"


def unavailable():
    """Why the algorithms cannot run in this QGIS, with what to do; None when they can.

    Python's version; the Python that runs the jobs, when one is configured; the installed
    distributions' metadata (gnss-citygml, at this plugin's version, and each of its
    requirements at its minimum version); and the library's pure-Python modules that the
    algorithms' parameters read (:data:`MODULES`), imported: a half-installed library (its
    metadata without its modules, or modules that fail to import) must not stop QGIS loading
    the plugin. No compiled module is loaded into QGIS; a broken one is reported when a job
    runs, with the child's message.
    """
    if sys.version_info[:2] < PYTHON:
        return (
            "{} needs Python {}.{} or newer; this QGIS runs Python {}.{}: use a QGIS built "
            "with a newer Python (QGIS 3.22 on Debian 12, or any QGIS 3.34 or newer)".format(
                TITLE, *PYTHON, *sys.version_info[:2]
            )
        )
    return _configured_python() or _installed() or _not_importable()


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


def _not_importable():
    """Why the library's :data:`MODULES` do not import in QGIS's Python, or None."""
    for module in MODULES:
        try:
            importlib.import_module(module)
        except Exception as exc:  # a broken install: any error of its import
            lines = str(exc).strip().splitlines() or [""]
            why = f"{type(exc).__name__}: {lines[0]}".rstrip(": ")
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
    """The message: what is wrong, and the command that installs the library into this Python
    (``requirement``, e.g. a release; ``reinstall``: its files and its requirements' again)."""
    command = f'"{interpreter()}" -m pip install --user --upgrade '
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
    verb = "Reinstall" if reinstall else "Install"
    return f"{what}. {verb} it there, then restart QGIS: {command} (more in {README})"


def _numpy_below_2():
    """Whether this Python has numpy 1, which QGIS's own compiled modules were then built for."""
    try:
        return _numbers(metadata.version("numpy")) < (2,)
    except metadata.PackageNotFoundError:
        return False


def interpreter():
    """The Python that runs the jobs: ``$GNSS_CITYGML_PYTHON``, or the one QGIS runs (QGIS's
    own executable is not it)."""
    if os.environ.get(PYTHON_VARIABLE):
        return os.environ[PYTHON_VARIABLE]
    if os.path.basename(sys.executable).lower().startswith("python"):
        return sys.executable
    version = "python{}.{}".format(*sys.version_info[:2])
    candidates = [
        os.path.join(sys.prefix, "python.exe"),  # OSGeo4W, the Windows installers
        os.path.join(sys.prefix, "bin", version),  # Linux, macOS
        os.path.join(sys.prefix, "bin", "python3"),
    ]
    return next((path for path in candidates if os.path.exists(path)), version)
