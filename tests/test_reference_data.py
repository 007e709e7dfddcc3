"""The tests' reference data: ``tests/data`` is what its README lists, and a test that needs
the shared data folder is skipped without it (one line at the end says how many and why), or
under CI fails, as is a file missing from the folder (tests/conftest.py)."""

import hashlib
import re
from pathlib import Path

import pytest

pytest_plugins = ["pytester"]

HERE = Path(__file__).resolve().parent
DATA = HERE / "data"
#: Files of tests/data that are not reference data: the README, the licence texts, and the
#: attributes that keep every file byte for byte.
NOT_DATA = {"README.md", ".gitattributes", "LICENSES/Apache-2.0.txt"}


def test_every_file_is_listed_with_its_size_and_checksum():
    rows = re.findall(
        r"^\| `([^`]+)` \|.* \| (\d+) \| `([0-9a-f]{64})` \|$",
        (DATA / "README.md").read_text(encoding="utf-8"),
        re.M,
    )
    listed = {name: (int(size), sha256) for name, size, sha256 in rows}
    files = {p.relative_to(DATA).as_posix() for p in DATA.rglob("*") if p.is_file()}
    assert files - NOT_DATA == set(listed)
    for name, (size, sha256) in listed.items():
        data = (DATA / name).read_bytes()
        assert (len(data), hashlib.sha256(data).hexdigest()) == (size, sha256), name


def test_no_os_mastermap_in_the_repository():
    """OS MasterMap is licensed data: not a file of it, not a feature cut from it."""
    for path in DATA.rglob("*"):
        if path.is_file():
            assert b"ordnancesurvey.co.uk/xml/namespaces/osgb" not in path.read_bytes(), path


#: Tests run by :func:`run`: one reads a file of the shared folder, one a file missing from
#: it, one is marked, one needs nothing, and one is parametrized over both places.
PROBE = """
import pytest

def test_reads_a_shared_file(shared_data):
    assert (shared_data / "gnss" / "log.txt").read_text() == "x"

def test_reads_a_missing_file(shared_data):
    (shared_data / "gnss" / "gone.txt").read_text()

@pytest.mark.shared_data
def test_marked():
    pass

def test_needs_nothing():
    pass

@pytest.mark.parametrize("where", [pytest.param("shared", marks=pytest.mark.shared_data), "data"])
def test_reference_data(reference_data, where):
    assert reference_data.name == where
"""


def run(pytester, monkeypatch, shared: Path, ci: bool):
    """Run :data:`PROBE` with this project's conftest, ``shared`` as the shared data folder
    and ``$CI`` set or not."""
    monkeypatch.setenv("GNSS_CITYGML_SHARED_DATA", str(shared))
    if ci:
        monkeypatch.setenv("CI", "true")
    else:
        monkeypatch.delenv("CI", raising=False)
    pytester.makeconftest((HERE / "conftest.py").read_text(encoding="utf-8"))
    pytester.makeini("[pytest]\nmarkers =\n    shared_data: needs the shared data\n")
    pytester.makepyfile(test_probe=PROBE)
    return pytester.runpytest_subprocess("-rs", "-p", "no:cacheprovider")


def test_without_the_folder_its_tests_skip_and_one_line_says_so(pytester, monkeypatch):
    shared = pytester.path / "nowhere"
    result = run(pytester, monkeypatch, shared, ci=False)
    result.assert_outcomes(passed=2, skipped=4)
    assert result.ret == 0
    lines = [line for line in result.outlines if "DID NOT RUN" in line]
    assert len(lines) == 1
    assert f"4 TESTS DID NOT RUN FOR LACK OF THE SHARED DATA (no folder {shared})" in lines[0]
    assert "../shared/data" in lines[0] and "$GNSS_CITYGML_SHARED_DATA" in lines[0]
    assert result.outlines[-1].startswith("=") and "2 passed, 4 skipped" in result.outlines[-1]


def test_without_the_folder_under_ci_the_run_stops_before_any_test(pytester, monkeypatch):
    shared = pytester.path / "nowhere"
    result = run(pytester, monkeypatch, shared, ci=True)
    assert result.ret == pytest.ExitCode.USAGE_ERROR
    result.assert_outcomes()  # nothing ran
    output = result.stdout.str() + result.stderr.str()
    assert f"4 tests need the shared data folder {shared}, which does not exist" in output
    assert "with $CI set they must run, not skip" in output
    assert "DID NOT RUN" not in output


def test_a_file_missing_from_the_folder_skips_its_test(pytester, monkeypatch):
    shared = pytester.mkdir("shared")
    (shared / "gnss").mkdir()
    (shared / "gnss" / "log.txt").write_text("x")
    result = run(pytester, monkeypatch, shared, ci=False)
    result.assert_outcomes(passed=5, skipped=1)
    line = next(line for line in result.outlines if "DID NOT RUN" in line)
    assert f"1 TEST DID NOT RUN FOR LACK OF THE SHARED DATA ({shared}/gnss/gone.txt" in line


def test_a_file_missing_from_the_folder_under_ci_fails_its_test(pytester, monkeypatch):
    shared = pytester.mkdir("shared")
    (shared / "gnss").mkdir()
    (shared / "gnss" / "log.txt").write_text("x")
    result = run(pytester, monkeypatch, shared, ci=True)
    result.assert_outcomes(passed=5, failed=1)
    result.stdout.fnmatch_lines(
        [f"*needs the shared data: {shared}/gnss/gone.txt is missing; with $CI set this is a*"]
    )
