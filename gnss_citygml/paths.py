"""Checks on the files a user names, shared by every reader.

A missing file, a folder where a file is meant, or a file that cannot be opened each get their
own one-line error, named the same way everywhere."""

from __future__ import annotations

import os
from pathlib import Path

from .errors import InputError

__all__ = ["input_file"]


def input_file(path, what: str = "file") -> Path:
    """``path`` as a :class:`~pathlib.Path` if it is a readable file, else an :class:`InputError`.

    ``what`` names the file in the message (``"orbit file"``, ``"footprint file"``...).

    >>> input_file(".", "orbit file")
    Traceback (most recent call last):
    ...
    gnss_citygml.errors.InputError: orbit file is a folder, not a file (.): give the file's path
    """
    path = Path(path)
    if path.is_dir():
        raise InputError(
            f"{what} is a folder, not a file", where=str(path), fix="give the file's path"
        )
    if not path.exists():
        raise InputError(f"{what} not found", where=str(path), fix="check the path")
    if not os.access(path, os.R_OK):
        raise InputError(f"{what} is not readable", where=str(path), fix="check its permissions")
    return path
