"""One exception hierarchy for the whole toolkit.

Every error a user can cause is a :class:`GnssCityGMLError`. Its message says *what* went
wrong, *where* (file, line, column, feature id) and *how to fix it*, so that the command line
can print it as one line (``error: <what> (<where>): <how to fix>``) without a traceback.
:func:`listing` (the first items and how many more), :func:`first_line` (what a library's own
error says, in one line), :func:`escape_controls` (one line whatever the data holds) and
:func:`user_text` (one value from the user's files: escaped and cut to a readable length) shape
the messages, the same way in every module. Every text from the user's files that goes into a
message (ids, receiver names, layer and file names, field values) goes through :func:`user_text`
(or :func:`listing`, which uses it): a newline in an id cannot forge an ``error:`` line, an ANSI
escape cannot recolour the terminal, a bidi override cannot reorder what is read.
"""

from __future__ import annotations

import re
import sys
from collections.abc import Iterable

__all__ = [
    "GnssCityGMLError",
    "InputError",
    "MissingColumnError",
    "ModelError",
    "broken_install",
    "escape_controls",
    "first_line",
    "internal_error",
    "listing",
    "user_text",
]

#: What a message must not hold as is: C0/C1 controls (line ends, ESC of ANSI sequences), the
#: Unicode line and paragraph separators, the bidi controls and invisible format characters
#: (U+202E reverses what follows), lone surrogates (not encodable) and the BOM.
_CONTROL = re.compile(
    "[\x00-\x1f\x7f-\x9f\u061c\u200b-\u200f\u2028-\u202e\u2060-\u2069\ufeff\ud800-\udfff]"
)

#: The longest value :func:`user_text` gives whole (characters, after escaping).
TEXT_LENGTH = 60
#: The longest item :func:`listing` gives whole: an item may be made by the code around a user
#: value (``receiver phone2 at 2020-06-01 10:00:01 (lat 48.000000, lon -3.000000)``).
ITEM_LENGTH = 120


def escape_controls(text: str) -> str:
    r"""``text`` with its control, bidi and invisible characters (line ends too) escaped as
    ``repr`` does: one line that reads as it is stored.

    >>> print(escape_controls("a" + chr(10) + "error: b" + chr(0x202E)))
    a\nerror: b\u202e
    """
    return _CONTROL.sub(lambda m: repr(m.group())[1:-1], text)


def user_text(value: object, length: int = TEXT_LENGTH) -> str:
    r"""One value from the user's files as a message shows it: escaped (:func:`escape_controls`)
    and, past ``length`` characters, cut with how long it was.

    >>> print(user_text("osgb1" + chr(27) + "[31m"))
    osgb1\x1b[31m
    >>> user_text("x" * 100, 10)
    'xxxxxxxxxx... (100 characters)'
    """
    text = str(value)
    escaped = escape_controls(text)
    if len(escaped) <= length:
        return escaped
    return f"{escaped[:length]}... ({len(text)} characters)"


def listing(items: Iterable, shown: int = 10, *, total: int | None = None) -> str:
    """The items for a message, comma-separated (each :func:`user_text`, cut past
    :data:`ITEM_LENGTH`); past the first
    ``shown``, how many more.

    ``total`` is how many there are in all when ``items`` holds only the first few (to spare
    formatting thousands of items a message will not show).

    >>> listing(range(3))
    '0, 1, 2'
    >>> listing(range(14))
    '0, 1, 2, 3, 4, 5, 6, 7, 8, 9 and 4 more'
    >>> listing(["a", "b"], 2, total=5)
    'a, b and 3 more'
    """
    items = list(items)
    total = len(items) if total is None else total
    text = ", ".join(user_text(item, ITEM_LENGTH) for item in items[:shown])
    return text + (f" and {total - shown} more" if total > shown else "")


def internal_error(exc: BaseException) -> str:
    """One line for an error that is not the user's (a bug): its type and the start of its
    message, for the command line and the QGIS plugin to print the same way.

    >>> internal_error(ZeroDivisionError("division by zero"))
    'internal error, ZeroDivisionError: division by zero: please report it'
    """
    return (
        f"internal error, {type(exc).__name__}: {escape_controls(str(exc))[:200]}: please report it"
    )


def broken_install(exc: BaseException) -> InputError | None:
    """The one-line error for a library that cannot be imported while a job runs (an install
    half done or half removed, a dependency missing or built for another Python): the user's
    installation, not a bug of the toolkit. None for any other exception.

    >>> error = ModuleNotFoundError("No module named 'pyarrow'", name="pyarrow")
    >>> broken_install(error).what
    "the installation is broken: importing pyarrow fails (No module named 'pyarrow')"
    """
    if not isinstance(exc, ImportError):
        return None
    return InputError(
        f"the installation is broken: importing {user_text(exc.name or 'a module')} fails"
        f" ({user_text(first_line(exc), 120)})",
        where=sys.executable,
        fix="install it again in this Python: python -m pip install --force-reinstall "
        "gnss-citygml (or the package named)",
    )


def first_line(exc: BaseException) -> str:
    """The first line of an exception's message (GDAL's and lxml's run over several), or the
    name of its type when it has none: the part of a library's error worth quoting in ours.

    >>> first_line(ValueError("bad header" + chr(10) + "  at byte 12"))
    'bad header'
    >>> first_line(KeyError())
    'KeyError'
    """
    lines = str(exc).splitlines()
    return lines[0] if lines else type(exc).__name__


class GnssCityGMLError(Exception):
    """Base class of every error the toolkit raises on purpose.

    Parameters
    ----------
    what
        What went wrong, in one short clause.
    where
        Where it went wrong: a file, line, column or feature id (optional).
    fix
        How the user can fix it (optional).
    """

    exit_code = 2

    def __init__(self, what: str, *, where: str | None = None, fix: str | None = None):
        self.what = what
        self.where = where
        self.fix = fix
        super().__init__(self.one_line())

    def one_line(self) -> str:
        r"""The message as the CLI prints it: ``what (where): fix``, on one line whatever the
        data quoted in it holds (control characters are escaped, as ``repr`` does).

        >>> InputError("bad id " + chr(10), where="f.csv").one_line()
        'bad id \\n (f.csv)'
        """
        text = self.what
        if self.where:
            text += f" ({self.where})"
        if self.fix:
            text += f": {self.fix}"
        return escape_controls(text)


class InputError(GnssCityGMLError):
    """The user's data or arguments are not usable as given."""


class MissingColumnError(InputError):
    """A table lacks columns a stage needs."""

    def __init__(self, missing: list[str], *, where: str, have: list[str] | None = None):
        names = ", ".join(repr(m) for m in missing)
        fix = "add the column(s)"
        if have is not None:
            fix += " (the table has: " + ", ".join(map(str, have)) + ")"
        super().__init__(f"missing column(s) {names}", where=where, fix=fix)
        self.missing = missing


class ModelError(GnssCityGMLError):
    """A model was asked for something it cannot do (e.g. an unknown method)."""
