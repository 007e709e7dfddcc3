"""The outcome of a validation: a :class:`Report` listing every error as an :class:`Issue`."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

from ..errors import escape_controls

__all__ = ["Issue", "Report"]


class Issue(NamedTuple):
    """One error: the object it concerns (None for the whole file), the rule, the details."""

    object_id: str | None
    rule: str
    message: str

    def line(self) -> str:
        """The issue as one line: object id (``-`` for the file), rule and message, tab-separated.

        Control characters, bidi controls and lone surrogates (an id or a quoted value can
        hold them) are escaped (:func:`~gnss_citygml.errors.escape_controls`), so that an
        issue is always one printable line."""
        fields = (self.object_id or "-", self.rule, self.message)
        return "\t".join(map(escape_controls, fields))


@dataclass
class Report:
    """The outcome of :func:`validate_file`.

    Attributes
    ----------
    path
        The file validated.
    format
        ``"CityGML 2.0"``, ``"CityJSON 2.0"``, ``"CityJSONSeq 2.0"``, ``"CityJSONFeature 2.0"``.
    errors
        Every error found, as :class:`Issue` (object id, rule, message).
    checks
        The checks that ran (``xsd``, ``structure``, ``json-schema``, ``geometry``).
    notes
        Checks left out and why.
    n_objects
        City objects read.
    """

    path: str
    format: str
    errors: list[Issue] = field(default_factory=list)
    checks: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    n_objects: int = 0

    @property
    def valid(self) -> bool:
        """Whether no error was found."""
        return not self.errors

    @property
    def exit_code(self) -> int:
        """0 valid, 1 invalid (2, could not validate, is raised as an InputError)."""
        return 0 if self.valid else 1

    def summary(self) -> str:
        """One line: the file, its format, valid or how many errors, the checks run."""
        verdict = "valid" if self.valid else f"INVALID, {len(self.errors)} error(s)"
        return escape_controls(
            f"{self.path}: {self.format}, {self.n_objects} object(s): {verdict} "
            f"(checks: {', '.join(self.checks)})"
        )

    def rule_counts(self) -> dict[str, int]:
        """Number of errors per rule."""
        counts: dict[str, int] = {}
        for issue in self.errors:
            counts[issue.rule] = counts.get(issue.rule, 0) + 1
        return counts
