"""Fuzzing the readers behind ``gnss-citygml info``: the provenance record of a GeoPackage, a
CityJSON, a CityJSONSeq, a CityGML model, a 3D Tiles tileset and a report page.

Each case stores a record in a real file of one kind (:func:`~.records.holding`): the bytes of
a record as the toolkit writes it, mutated (:func:`mutated`); records of any shape (each field
of its type or any JSON value: null, a list, NaN, 1e999, text with line ends and terminal
escapes); records nested up to 100,000 deep. Then ``info`` and ``info --json`` run on it: each
ends as a one-line error, or prints one line per value with no control character, and
``--json`` prints strict JSON.
"""

from __future__ import annotations

import json
import re

import pytest
from click.testing import CliRunner
from hypothesis import event, given
from hypothesis import strategies as st

from gnss_citygml.cli.citymodel import info
from gnss_citygml.errors import GnssCityGMLError

from .conftest import mutated
from .records import CONTAINERS, holding

GOOD = {
    "software": "gnss-citygml 1.0",
    "created": "2026-11-27T12:00:00Z",
    "command": "estimate",
    "settings": {"estimator": {"method": "4PL-B"}, "rays": {"min_elevation": 10.0}},
    "inputs": [{"role": "observations", "name": "o.parquet", "bytes": 12, "sha256": "ab" * 32}],
}
#: Values a field may hold instead of its own: any JSON, NaN and infinities included.
ANY_JSON = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=8),
    lambda children: (
        st.lists(children, max_size=3) | st.dictionaries(st.text(max_size=6), children, max_size=3)
    ),
    max_leaves=8,
)
TEXT = st.text(max_size=70) | st.sampled_from(
    ["\n error: forged", "\x1b[31m", "a\rb", "\u202e", "\u2028", "x" * 5000, "\ud800"]
)


def _field(own):
    return own | ANY_JSON


INPUT = st.fixed_dictionaries(
    {},
    optional={
        "role": _field(TEXT),
        "name": _field(TEXT),
        "sha256": _field(TEXT),
        "bytes": _field(st.integers(-(2**70), 2**70)),
    },
)
RECORD = st.fixed_dictionaries(
    {},
    optional={
        "software": _field(TEXT),
        "created": _field(TEXT),
        "command": _field(TEXT),
        "settings": _field(st.dictionaries(TEXT, ANY_JSON, max_size=3)),
        "inputs": _field(st.lists(INPUT | ANY_JSON, max_size=3)),
    },
)


@st.composite
def record_texts(draw) -> str:
    """The JSON text of a record: mutated bytes, any shape, or nested deep."""
    kind = draw(st.sampled_from(["mutated", "shape", "deep"]))
    if kind == "mutated":
        data = draw(mutated(json.dumps(GOOD, indent=1).encode()))
        return data.decode("utf-8", "replace")
    if kind == "shape":
        return json.dumps(draw(RECORD | ANY_JSON))  # (NaN and Infinity as Python writes them)
    depth = draw(st.sampled_from([127, 128, 129, 1000, 100_000]))
    return json.dumps({**GOOD, "settings": {"x": None}}).replace(
        "null", "[" * depth + "1" + "]" * depth
    )


#: What no line ``info`` prints may hold: controls (but the line end), bidi and line separators.
_UNSAFE = re.compile("[\x00-\x09\x0b-\x1f\x7f-\x9f\u2028\u2029\u202a-\u202e\u2066-\u2069]")


@pytest.mark.parametrize("name", CONTAINERS)
@given(text=record_texts())
def test_info(name, text, module_folder):
    path = module_folder / name
    path.unlink(missing_ok=True)
    holding(module_folder, name, text)
    printed = CliRunner().invoke(info, [str(path)])
    as_json = CliRunner().invoke(info, [str(path), "--json"])
    if printed.exception is not None:
        assert isinstance(printed.exception, GnssCityGMLError), repr(printed.exception)
        assert isinstance(as_json.exception, GnssCityGMLError), repr(as_json.exception)
        assert "\n" not in printed.exception.one_line()
        event(f"error: {printed.exception.what[:24]}")
        return
    assert as_json.exception is None, repr(as_json.exception)
    assert not _UNSAFE.search(printed.output), printed.output
    assert not any(line.startswith("error") for line in printed.output.splitlines())

    def refuse(constant):
        raise AssertionError(f"--json printed {constant}")

    assert isinstance(json.loads(as_json.output, parse_constant=refuse), dict)
    event("printed")
