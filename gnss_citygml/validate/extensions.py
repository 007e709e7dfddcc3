"""CityJSON Extensions checked offline: the attributes of the toolkit's own Extension.

A CityJSON file names the Extensions it uses in its ``extensions`` member (name, URL,
version). Nothing is fetched: the only Extension known is the toolkit's own, which ships in the
package (:data:`gnss_citygml.contracts.EXTENSION`) and is recognised by its URL and version.
For a file that declares it, each ``+`` attribute of a CityObject is checked against the
schema the Extension gives it for that CityObject's type (rule ``extension``), and a ``+``
attribute that no declared Extension defines is an error too. Another Extension is noted as
not checked, and while a file declares one, ``+`` attributes the toolkit's does not define are
left to it.
"""

from __future__ import annotations

from typing import Any

from ..contracts import EXTENSION, load
from .report import Issue, Report

__all__ = ["Extensions"]


class Extensions:
    """The ``+`` attributes of the Extensions a file declares, as far as they are known."""

    def __init__(self, declared: dict, report: Report):
        """``declared``: the file's ``extensions`` member; notes on what is not checked go to
        ``report``."""
        #: per CityObject type, a validator of its attributes and the ``+`` names it defines
        self.by_type: dict[str, tuple[Any, set[str]]] = {}
        self.complete = True  # every declared Extension is known
        own = load(EXTENSION)
        for name, ref in declared.items():
            url = ref.get("url") if isinstance(ref, dict) else None
            version = ref.get("version") if isinstance(ref, dict) else None
            if url != own["url"] or version != own["version"]:
                self.complete = False
                report.notes.append(
                    f"Extension {name!r} not checked: only the toolkit's own "
                    f"({own['url']}, version {own['version']}) is known offline"
                )
                continue
            import jsonschema

            for kind, attributes in own["extraAttributes"].items():
                schema = {"type": "object", "properties": attributes}  # one call per object
                self.by_type[kind] = (jsonschema.Draft202012Validator(schema), set(attributes))
            if "extension" not in report.checks:
                report.checks.append("extension")

    def errors(self, key: str, obj: dict, where: str) -> list[Issue]:
        """The ``+`` attributes of CityObject ``key`` that break the known Extensions (none
        without a known Extension: a ``+`` attribute of a file that declares no Extension is
        the structural rules' error)."""
        attributes = obj.get("attributes")
        if not self.by_type or not isinstance(attributes, dict):
            return []
        kind = obj.get("type")
        validator, names = (
            self.by_type.get(kind, (None, set())) if isinstance(kind, str) else (None, set())
        )
        issues = []
        if self.complete:
            issues += [
                Issue(
                    key,
                    "extension",
                    where + f"attribute {name!r} of a {kind} is defined by none of the file's "
                    "Extensions",
                )
                for name in attributes
                if name.startswith("+") and name not in names
            ]
        if validator is not None:
            issues += [
                Issue(
                    key,
                    "extension",
                    where + f"attribute {error.path[0]!r}: {_message(error)}",
                )
                for error in validator.iter_errors(attributes)
            ]
        return issues


def _message(error) -> str:
    return error.message if len(error.message) <= 200 else error.message[:200] + "..."
