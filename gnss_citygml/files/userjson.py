"""JSON taken from a user's file, read one safe way by every reader (a city model, a tileset,
a provenance record, a partition's index, GeoParquet's ``geo`` metadata, a map's evidence).

:func:`parse_json` refuses, as a :class:`NotJSON` (a ``ValueError``, so a reader's own
``except ValueError`` still catches it), what :func:`json.loads` would take or choke on:
text that is not UTF-8, ``NaN`` and ``Infinity`` (not JSON; allowed on request for metadata
that other libraries write with them), and arrays and objects nested deeper than
:data:`MAX_DEPTH`. Python's parser raises a ``RecursionError`` some thousand levels down, and
every reader that walks a document (a JSON Schema check, ``json.dumps``) fails well before:
so the depth is checked on every document, by a scan of its brackets outside strings, linear
in the size of the text.
"""

from __future__ import annotations

import contextlib
import gc
import json
from collections.abc import Iterator
from typing import Any

import numpy as np

__all__ = ["MAX_DEPTH", "TOO_DEEP", "NotJSON", "parse_json"]

#: The deepest nesting of arrays and objects read: CityJSON needs fewer than 10 levels, a
#: JSON Schema check goes some 200 deep before Python's recursion limit.
MAX_DEPTH = 128

#: What :func:`_depth` keeps of a text: the brackets and the quotes.
_NOT_STRUCTURE = bytes(sorted(set(range(256)) - set(b'[]{}"')))


class NotJSON(ValueError):
    """Bytes that are not a JSON document this toolkit reads: the rule (``json-syntax`` or
    ``json-nesting``), the reason, and where (line and column, 0: not known)."""

    def __init__(self, rule: str, reason: str, line: int = 0, column: int = 0):
        super().__init__(reason)
        self.rule, self.reason, self.line, self.column = rule, reason, line, column


TOO_DEEP = (
    f"arrays and objects nested deeper than {MAX_DEPTH} levels (CityJSON needs fewer than 10)"
)


def parse_json(data: bytes | str, *, allow_nan: bool = False) -> Any:
    """The JSON document in ``data`` (UTF-8, a BOM allowed); :class:`NotJSON` if there is none
    or it is nested deeper than :data:`MAX_DEPTH`.

    Stricter than :func:`json.loads`: ``NaN`` and ``Infinity`` are not JSON (unless
    ``allow_nan``).

    >>> parse_json(b'{"a": [1, "]]"]}')
    {'a': [1, ']]']}
    >>> try:
    ...     parse_json("[" * 200 + "]" * 200)
    ... except NotJSON as exc:
    ...     print(exc.rule)
    json-nesting
    """
    if isinstance(data, str):
        text, data = data, data.encode("utf-8", "surrogatepass")
    else:
        try:
            text = data.decode("utf-8-sig")
        except UnicodeDecodeError as exc:
            line = data.count(b"\n", 0, exc.start) + 1
            column = exc.start - data.rfind(b"\n", 0, exc.start)
            raise NotJSON("json-syntax", "not UTF-8 text", line, column) from None
    constant = None if allow_nan else _not_a_number
    try:
        with _collector_paused():
            doc = json.loads(text, parse_constant=constant)
    except json.JSONDecodeError as exc:
        raise NotJSON("json-syntax", f"not valid JSON: {exc.msg}", exc.lineno, exc.colno) from None
    except RecursionError:
        raise NotJSON("json-nesting", TOO_DEEP) from None
    except ValueError as exc:  # NaN, Infinity; an integer of more than 4300 digits
        raise NotJSON("json-syntax", f"not valid JSON: {str(exc).split(';')[0]}") from None
    if isinstance(doc, list | dict) and _depth(data) > MAX_DEPTH:
        raise NotJSON("json-nesting", TOO_DEEP)
    return doc


def _depth(data: bytes) -> int:
    """How deep arrays and objects nest in ``data``, a valid JSON document: its escapes taken
    out (in valid JSON a backslash only starts one; runs of them pair from their start, as
    ``replace`` pairs them), the brackets outside strings counted."""
    kept = data.replace(b"\\\\", b"").replace(b'\\"', b"").translate(None, _NOT_STRUCTURE)
    chars = np.frombuffer(kept, np.uint8)
    quotes = np.cumsum(chars == ord('"'), dtype=np.int32)  # (its parity survives an overflow)
    inside = (quotes & 1).astype(bool)
    opens = (chars == ord("[")) | (chars == ord("{"))
    step = opens.astype(np.int32) - ((chars == ord("]")) | (chars == ord("}")))
    step[inside] = 0
    return int(np.cumsum(step).max(initial=0))


def _not_a_number(name: str):
    raise ValueError(f"{name} is not a JSON number")


@contextlib.contextmanager
def _collector_paused() -> Iterator[None]:
    """Pause Python's cyclic garbage collector, which slows json.loads of millions of lists
    fourfold (it scans them again and again while they are built)."""
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if enabled:
            gc.enable()
