"""Is the gnss-citygml library usable from QGIS's Python, and if not, what to install and how.

QGIS runs its own Python (Debian's ``/usr/bin/python3``, OSGeo4W's, the macOS bundle's), which
has no gnss-citygml until the user installs it there. The plugin must still load then, and say
exactly what is missing and the command that installs it into *that* Python. This module uses
nothing newer than Python 3.7, so that even a QGIS on an old Python gets the message.
"""

import os
import re
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

    Reads the installed distributions' metadata only (no compiled module is loaded into
    QGIS): Python's version, gnss-citygml and each of its requirements at its minimum version.
    A broken install that still fails is reported when a job runs, with the child's message.
    """
    if sys.version_info[:2] < PYTHON:
        return (
            "{} needs Python {}.{} or newer; this QGIS runs Python {}.{}: use a QGIS built "
            "with a newer Python (QGIS 3.22 on Debian 12, or any QGIS 3.34 or newer)".format(
                TITLE, *PYTHON, *sys.version_info[:2]
            )
        )
    missing = _missing_requirements()
    if missing:
        return install(f"{missing} missing from QGIS's Python")
    return None


def _missing_requirements():
    """The library, or the first of its requirements missing or older than it needs, as text."""
    try:
        requires = metadata.requires(DISTRIBUTION) or []
    except metadata.PackageNotFoundError:
        return "the gnss-citygml library is"
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


def install(what):
    """The message: what is wrong, and the command that installs the library into this Python."""
    command = f'"{interpreter()}" -m pip install --user --upgrade gnss-citygml'
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
    return f"{what}. Install it there, then restart QGIS: {command} (more in {README})"


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
