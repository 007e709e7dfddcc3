"""Fuzz tests of the readers (a package, so that its conftest does not shadow tests/conftest)."""
