"""The project's own contracts: JSON Schemas of its tables and its CityJSON Extension.

The files live in ``gnss_citygml/schemas/`` (the repository's top-level ``schemas/`` links to
that folder, and the wheel carries it), so that the readers and an installed package find them
offline; their README says what each file is. The code takes from them what it checks, so that
the published contract and the checks cannot drift apart:

- :data:`OBSERVATIONS`, a row of the observations table:
  :func:`~gnss_citygml.observations.check_observations` takes its columns, required columns,
  types, constellation letters and ranges from it;
- :data:`HEIGHTS`, a row of the heights table: the export's join
  (:func:`~gnss_citygml.export.heights.footprints_with_heights`) takes its required columns from it;
- :data:`EXTENSION`, the CityJSON Extension typing the toolkit's attributes (``+height``, ...):
  the CityJSON writers' ``typed_attributes`` option writes them, and the validator checks a file
  that declares it (:mod:`gnss_citygml.validate.extensions`).

The ``$id`` and ``url`` of each file (``https://gnss-citygml.org/schemas/1.1/...``) name it;
nothing is fetched from them.
"""

from __future__ import annotations

import json
from functools import cache
from pathlib import Path

__all__ = [
    "EXTENSION",
    "HEIGHTS",
    "OBSERVATIONS",
    "SCHEMA_FOLDER",
    "load",
    "types",
]

#: The folder of the contracts, inside the package.
SCHEMA_FOLDER = Path(__file__).resolve().parent / "schemas"
#: JSON Schema (draft 2020-12) of a row of the observations table.
OBSERVATIONS = "observations.schema.json"
#: JSON Schema (draft 2020-12) of a row of the heights table.
HEIGHTS = "heights.schema.json"
#: CityJSON 2.0 Extension of the toolkit's Building attributes.
EXTENSION = "gnss_citygml.ext.json"


@cache
def load(name: str) -> dict:
    """The contract ``name`` (one of the file names above), read once.

    Examples
    --------
    >>> load(OBSERVATIONS)["properties"]["cn0"]["maximum"]
    100
    """
    return json.loads((SCHEMA_FOLDER / name).read_text(encoding="utf-8"))


def types(spec: dict) -> set[str]:
    """The JSON types a property of a schema allows (its ``type``, one name or a list).

    Examples
    --------
    >>> sorted(types({"type": ["number", "null"]}))
    ['null', 'number']
    """
    kind = spec.get("type", [])
    return {kind} if isinstance(kind, str) else set(kind)
