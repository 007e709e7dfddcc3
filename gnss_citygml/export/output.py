"""What a writer hands back: the result of an export and the check of the file written.

Each writer writes a temporary file beside the output, validates it
(:func:`validated_output`, with :func:`gnss_citygml.validate.validate_file`) and only then
renames it into place; a file that fails its own validation is a bug
(:class:`InvalidOutputError`) and is not kept. The :class:`ExportResult` says what was written,
what was skipped and why (from :meth:`gnss_citygml.export.plan.Plan.result`), and the report;
a writer tells the caller's :data:`Progress` callback as it goes.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import pandas as pd

from ..errors import GnssCityGMLError, InputError
from ..files.names import os_text
from ..files.paths import StrPath
from ..validate import Report, validate_file

__all__ = [
    "ExportResult",
    "InvalidOutputError",
    "Progress",
    "check_title",
    "checked",
    "validated_output",
]


class InvalidOutputError(GnssCityGMLError):
    """A file the toolkit wrote failed its own validation (a bug: the file is not kept)."""


@dataclass
class ExportResult:
    """What a writer did.

    Attributes
    ----------
    path
        The file written.
    written
        Number of buildings written.
    skipped
        The buildings left out: ``id`` and ``reason``.
    report
        The validation report of the file (None with ``validate=False``).
    """

    path: str
    written: int
    skipped: pd.DataFrame
    report: Report | None = None

    def summary(self, to: str | None = None) -> str:
        """One line: how many buildings went to ``to`` (default: the path), how many were
        skipped, and the checks the file passed."""
        checked = "" if self.report is None else ", valid (" + ", ".join(self.report.checks) + ")"
        return (
            f"{self.written} buildings, {len(self.skipped)} skipped -> {to or self.path}{checked}"
        )


def validated_output(
    tmp: StrPath, path: StrPath, validate: bool, schema_dir: StrPath | None
) -> Report | None:
    """The validation report of a file just written to ``tmp``; raise if it is invalid."""
    if not validate:
        return None
    report = validate_file(tmp, schema_dir=schema_dir, bundled_schemas=False)
    return checked(report, path, "file")


def checked(report: Report, path: StrPath, what: str) -> Report:
    """The ``report`` of an output just written (a ``what``: file, tileset), with the path it
    is to have; an :class:`InvalidOutputError` naming the first error if it is invalid."""
    if not report.valid:
        first = report.errors[0]
        raise InvalidOutputError(
            f"the {what} written is not valid: {len(report.errors)} error(s), the first "
            f"{first.rule} ({first.object_id}): {first.message}",
            where=str(path),
            fix=f"please report this bug with the input; the {what} was not kept",
        )
    report.path = str(path)
    return report


#: A callback told how many more buildings were written.
Progress = Callable[[int], object]  # what it returns is ignored


def check_title(title: str | None) -> None:
    """Refuse a model's title that UTF-8 cannot hold: a lone surrogate, as Python holds a
    byte of another encoding (a Latin-1 ``é`` read from a command line or a file name). The
    command line refuses it already (naming ``--title``)."""
    if title is not None and os_text(title) != title:
        raise InputError(
            f"the title '{os_text(title)}' is not UTF-8 text (a byte of another encoding)",
            where="title",
            fix="give the title in UTF-8",
        )
