"""File names the C libraries cannot take: GDAL, Arrow and libxml2 take a file's name as UTF-8
text, while the OS takes any bytes. A file named in Latin-1 (``café.gpkg`` written by an old
tool or copied from an old disk) is fine for the OS and for Python, which holds its byte that
is not UTF-8 as a surrogate escape (``\\udce9``); handed to those libraries, that name fails
with a UnicodeEncodeError. Inputs are read through a link with a UTF-8 name
(:func:`native_name`), outputs that those libraries write must be named in UTF-8
(:func:`check_utf8_name`), and a record of a name (provenance) keeps it as text
(:func:`os_text`).
"""

from __future__ import annotations

import atexit
import os
import shutil
import tempfile
import threading
from pathlib import Path

from ..errors import InputError

__all__ = ["check_utf8_name", "given_name", "native_name", "os_text"]


def os_text(name: str) -> str:
    r"""A name the OS gave (a file name, a command-line argument) as text UTF-8 can hold: a
    byte that is not UTF-8 (a Latin-1 ``é`` in a file name, which Python holds as the
    surrogate escape ``\udce9``) written as ``\xe9``, as a record of the name (provenance)
    can keep it.

    >>> os_text("caf" + chr(0xDCE9) + ".gpkg")
    'caf\\xe9.gpkg'
    """
    try:
        raw = name.encode("utf-8", "surrogateescape")
    except UnicodeEncodeError:  # (a lone surrogate that no OS gave: \ud800)
        return name.encode("utf-8", "backslashreplace").decode("utf-8")
    return raw.decode("utf-8", "backslashreplace")


def _is_utf8(name: str) -> bool:
    try:
        name.encode("utf-8")
    except UnicodeEncodeError:
        return False
    return True


#: The symbolic links :func:`native_name` made, by the name they stand for, and their folder.
_LINKS: dict[str, str] = {}
_FOLDER: list[str] = []
_LOCK = threading.Lock()


def native_name(path: os.PathLike[str] | str) -> str:
    """``path`` as a name the C libraries that read the inputs (GDAL, Arrow, libxml2) can
    open. They take file names as UTF-8 text, and fail on a name with a byte that is not
    UTF-8 (a file named in Latin-1: fine for the OS and for Python). Such a file or folder is
    opened through a symbolic link with a UTF-8 name to it (same suffix, for GDAL's drivers),
    in a temporary folder of this process removed at its exit. For reading only: a writer
    would replace the link, not the file."""
    name = os.fspath(path)
    if _is_utf8(name):
        return name
    with _LOCK:
        if name not in _LINKS:
            if not _FOLDER:
                _FOLDER.append(tempfile.mkdtemp(prefix="gnss-citygml-names-"))
                atexit.register(shutil.rmtree, _FOLDER[0], ignore_errors=True)
            suffix = Path(name).suffix if _is_utf8(Path(name).suffix) else ""
            link = os.path.join(_FOLDER[0], f"{len(_LINKS)}{suffix}")
            os.symlink(os.path.abspath(name), link)
            _LINKS[name] = link
        return _LINKS[name]


def given_name(name: str) -> str:
    """The name a link of :func:`native_name` stands for (``name`` itself if it is none),
    for messages about a file a library opened through it."""
    with _LOCK:
        return next((given for given, link in _LINKS.items() if link == name), name)


def check_utf8_name(path: os.PathLike[str] | str, what: str) -> None:
    """Refuse an output whose name is not UTF-8 text where a C library writes it (GDAL,
    Arrow: :func:`native_name` serves only readers)."""
    name = os.fspath(path)
    if not _is_utf8(name):
        raise InputError(
            f"the {what}'s name is not UTF-8 text (GDAL and Arrow, which write it, take UTF-8 "
            "names only)",
            where=os_text(name),
            fix=f"give the {what} a UTF-8 name (inputs that are only read may keep theirs)",
        )
