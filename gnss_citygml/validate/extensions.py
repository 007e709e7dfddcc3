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

from ..contracts import EXTENSION, load
from .report import Issue, Report

__all__ = ["Extensions"]


class Extensions:
    """The ``+`` attributes of the Extensions a file declares, as far as they are known."""

    def __init__(self, declared: dict, report: Report):
        """``declared``: the file's ``extensions`` member; notes on what is not checked go to
        ``report``."""
        self.attributes: dict[str, dict] = {}  # CityObject type: {"+name": validator}
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
                checkers = self.attributes.setdefault(kind, {})
                for attribute, schema in attributes.items():
                    checkers[attribute] = jsonschema.Draft202012Validator(schema)
            if "extension" not in report.checks:
                report.checks.append("extension")
        # nothing to check without a known Extension: an undeclared '+' is the rules' error
        self.active = bool(self.attributes)

    def errors(self, key: str, obj: dict, where: str) -> list[Issue]:
        """The ``+`` attributes of CityObject ``key`` that break the known Extensions."""
        attributes = obj.get("attributes")
        if not self.active or not isinstance(attributes, dict):
            return []
        kind = obj.get("type")
        known = self.attributes.get(kind, {}) if isinstance(kind, str) else {}
        issues = []
        for name, value in attributes.items():
            if not name.startswith("+"):
                continue
            checker = known.get(name)
            if checker is None:
                if self.complete:
                    issues.append(
                        Issue(
                            key,
                            "extension",
                            where + f"attribute {name!r} of a {kind} is defined by none of the "
                            "file's Extensions",
                        )
                    )
                continue
            issues.extend(
                Issue(key, "extension", where + f"attribute {name!r}: {_message(error)}")
                for error in checker.iter_errors(value)
            )
        return issues


def _message(error) -> str:
    return error.message if len(error.message) <= 200 else error.message[:200] + "..."
