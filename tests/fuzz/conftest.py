"""Fuzzing the readers with hypothesis: every input ends as a result or a one-line error.

Two profiles: ``quick`` (the default, a short run inside ``make test``) and ``fuzz`` (``make
fuzz``: at least 10,000 cases per reader, a deadline per case so a hang fails, and an address
space cap so unbounded memory fails). Choose one with ``--hypothesis-profile``.

Inputs are mutations of a valid file (:func:`mutated`): the bytes a user could hand a reader
after a cut download, a hand edit or a wrong export, rather than uniformly random noise that
every parser rejects at its first byte.
"""

from __future__ import annotations

import resource
from datetime import timedelta

import pytest
from hypothesis import HealthCheck, settings
from hypothesis import strategies as st

from gnss_citygml.errors import GnssCityGMLError

settings.register_profile(
    "quick",
    max_examples=100,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
    database=None,
    derandomize=True,
)
settings.register_profile(
    "fuzz",
    max_examples=10_000,
    deadline=timedelta(seconds=10),
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
    database=None,
)
settings.load_profile("quick")

ADDRESS_SPACE_CAP = 8 * 2**30  # bytes: far above any reader's need on a fuzz case


def pytest_sessionstart(session):
    if settings.get_current_profile_name() == "fuzz":
        _, hard = resource.getrlimit(resource.RLIMIT_AS)
        cap = ADDRESS_SPACE_CAP if hard == resource.RLIM_INFINITY else min(hard, ADDRESS_SPACE_CAP)
        resource.setrlimit(resource.RLIMIT_AS, (cap, hard))


def one_line_or_result(call, *args, **kwargs):
    """Run a reader: return its result, or None after a clean one-line toolkit error.

    Anything else (a traceback-worthy exception, a multi-line message) fails the test."""
    try:
        return call(*args, **kwargs)
    except GnssCityGMLError as exc:
        message = exc.one_line()
        assert message and "\n" not in message, f"not one line: {message!r}"
        return None


@pytest.fixture(scope="module")
def module_folder(tmp_path_factory):
    """One folder for the fuzz cases of a module (hypothesis reuses it across examples)."""
    return tmp_path_factory.mktemp("fuzz")


@pytest.fixture
def clean():
    """:func:`one_line_or_result` as a fixture."""
    return one_line_or_result


TOKENS = [
    b"",
    b"0",
    b"-1",
    b"1e308",
    b"-1e308",
    b"nan",
    b"NaN",
    b"inf",
    b"-inf",
    b"99999999999999999999999",
    b"0.000000000000000000001",
    b"abc",
    b"\x00",
    b"\xff\xfe",
    b"\xc3(",
    b'"',
    b"'",
    b",",
    b";",
    b"#",
    b"<",
    b"]]>",
    b"&amp;",
    b"{",
    b"[",
    b"null",
    b"true",
    b"x" * 5000,
    b"1" * 400,
    b"2020-13-45T25:61:61Z",
]


@st.composite
def mutated(draw, seed: bytes, max_ops: int = 6):
    """A strategy of byte strings made from ``seed`` by 1..max_ops random edits.

    Edits: cut the file anywhere, delete / duplicate / swap / insert lines or byte ranges,
    overwrite bytes, and replace one field (comma, whitespace or quote separated) of a line
    by an awkward token (empty, NaN, 1e308, invalid UTF-8, a 5,000-byte word...)."""
    data = bytes(seed)
    for _ in range(draw(st.integers(1, max_ops))):
        op = draw(
            st.sampled_from(
                ["cut", "delete", "insert", "overwrite", "dup_line", "drop_line", "swap", "field"]
            )
        )
        n = len(data)
        if op == "cut":
            data = data[: draw(st.integers(0, n))]
        elif op == "delete" and n:
            i = draw(st.integers(0, n - 1))
            data = data[:i] + data[i + draw(st.integers(1, 64)) :]
        elif op == "insert":
            i = draw(st.integers(0, n))
            data = (
                data[:i]
                + draw(st.binary(min_size=1, max_size=32) | st.sampled_from(TOKENS))
                + data[i:]
            )
        elif op == "overwrite" and n:
            i = draw(st.integers(0, n - 1))
            chunk = draw(st.binary(min_size=1, max_size=8))
            data = data[:i] + chunk + data[i + len(chunk) :]
        elif op in ("dup_line", "drop_line", "swap", "field"):
            lines = data.split(b"\n")
            k = draw(st.integers(0, len(lines) - 1))
            if op == "dup_line":
                lines.insert(k, lines[k])
            elif op == "drop_line":
                del lines[k]
            elif op == "swap":
                j = draw(st.integers(0, len(lines) - 1))
                lines[k], lines[j] = lines[j], lines[k]
            else:
                lines[k] = _replace_field(draw, lines[k])
            data = b"\n".join(lines)
    return data


def _replace_field(draw, line: bytes) -> bytes:
    sep = draw(st.sampled_from([b",", b" ", b'"']))
    fields = line.split(sep)
    i = draw(st.integers(0, len(fields) - 1))
    fields[i] = draw(st.sampled_from(TOKENS))
    return sep.join(fields)
