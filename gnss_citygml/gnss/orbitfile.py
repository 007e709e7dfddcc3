"""The text of orbit files: what the SP3 and RINEX navigation readers share.

Both formats are fixed-column ASCII, often gzipped, with Fortran numbers (``D`` or ``E``
exponents) and record epochs written as year, month, day, hour, minute, seconds. This module
reads their lines, those numbers and epochs, and builds the error for a garbled line (naming
the file and line, and saying to download the file again), so that :mod:`.sp3`,
:mod:`.navigation` and :func:`~gnss_citygml.gnss.orbits.load_orbits` (which looks at a file's
first line to tell the two kinds apart) read them one way.
"""

from __future__ import annotations

import contextlib
import datetime
import io
import zlib
from pathlib import Path
from typing import Literal, overload

import numpy as np

from gnss_citygml.errors import InputError
from gnss_citygml.files.paths import StrPath, gunzipped, input_file
from gnss_citygml.gnss.gpstime import NS_PER_S

__all__ = ["fortran_float", "garbled", "location", "read_lines", "record_epoch"]


def location(path: StrPath, line_no: int | None = None) -> str:
    """The ``where`` of an error: the file, and the line when there is one."""
    return str(path) if line_no is None else f"{path}, line {line_no}"


def garbled(path: StrPath, line_no: int, text: str, why: str) -> InputError:
    """The error for a garbled line of an orbit file."""
    return InputError(
        f"{why}: {text.rstrip()[:80]!r}",
        where=location(path, line_no),
        fix="the file is garbled or truncated: download it again",
    )


def _is_gzip(path: Path) -> bool:
    """Whether the file is gzipped, by its first bytes (gzip's magic number), whatever its name
    says (``.gz``, ``.GZ``, ``.gzip``, or none: a download renamed)."""
    with open(path, "rb") as f:
        return f.read(2) == b"\x1f\x8b"


@overload
def read_lines(path: StrPath, first_only: Literal[False] = False) -> list[str]: ...
@overload
def read_lines(path: StrPath, first_only: Literal[True]) -> str: ...
def read_lines(path: StrPath, first_only: bool = False) -> str | list[str]:
    """The lines of a text file (gzip too), or only its first line."""
    path = input_file(path, "orbit file")
    if path.suffix == ".Z":
        raise InputError(
            "Unix-compressed (.Z) files are not read", where=str(path), fix="run `gzip -d` first"
        )
    try:
        with contextlib.ExitStack() as stack:
            raw = stack.enter_context(
                gunzipped(path, "orbit file") if _is_gzip(path) else open(path, "rb")
            )
            f = stack.enter_context(io.TextIOWrapper(raw, encoding="ascii", errors="replace"))
            return f.readline() if first_only else f.read().splitlines()
    except (OSError, EOFError, zlib.error) as exc:
        raise InputError(f"cannot read the file ({exc})", where=str(path)) from exc


def fortran_float(text: str, path: StrPath, line_no: int) -> float:
    """A Fortran number (``D`` or ``E`` exponent); blank is NaN. No file writes "nan" or
    "inf": they are garbled numbers, as any other word."""
    text = text.strip()
    if not text:
        return np.nan
    try:
        value = float(text.replace("D", "E").replace("d", "e"))
    except ValueError:
        value = np.nan
    if not np.isfinite(value):
        raise garbled(path, line_no, text, "unreadable number")
    return value


def record_epoch(
    text: str, path: StrPath, line_no: int, line: str, two_digit_year: bool = False
) -> np.datetime64:
    """The epoch of a record (year, month, day, hour, minute as integers, then seconds), as
    ``datetime64[ns]``; a date that does not exist or lies outside 1980-2099 is garbled."""
    parts = text.split()
    try:
        y, mo, d, h, mi = (int(p) for p in parts[:5])
        sec = float(parts[5])
        if len(parts) != 6:
            raise ValueError
        if two_digit_year:
            y += 2000 if y < 80 else 1900
        day = datetime.date(y, mo, d)
    except (ValueError, IndexError, OverflowError):
        raise garbled(path, line_no, line, "unreadable epoch") from None
    if not (1980 <= y < 2100 and 0 <= h <= 24 and 0 <= mi < 60 and 0 <= sec < 61):
        raise garbled(path, line_no, line, "impossible epoch")
    seconds = h * 3600 + mi * 60 + sec
    return np.datetime64(day, "ns") + np.timedelta64(round(seconds * NS_PER_S), "ns")
