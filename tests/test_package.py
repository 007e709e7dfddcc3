"""The public API: every re-exported name resolves, lazily imported ones included."""

import pytest

import gnss_citygml


@pytest.mark.parametrize("name", gnss_citygml.__all__)
def test_public_names_resolve(name):
    assert getattr(gnss_citygml, name) is not None


def test_unknown_name():
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        gnss_citygml.nope  # noqa: B018
