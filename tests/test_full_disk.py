"""A write that fails on the user's side (a full disk, a limit on file sizes, a standard output
that is full) is one line naming the output and the fix, never "internal error", and an
existing output or map is left as it was, with no temporary file beside it (issue 26)."""

import hashlib
import resource
import subprocess
import sys
from pathlib import Path

import pyogrio
import pytest

CITY = Path(__file__).resolve().parents[1] / "examples" / "city"


def digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def command(args: list, *, limit: int | None = None, stdout=subprocess.PIPE):
    """The CLI in a process of its own; ``limit``: its limit on file sizes (bytes), which
    makes a write past it fail with EFBIG, as a full disk fails with ENOSPC."""

    def limited():
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    return subprocess.run(
        [sys.executable, "-m", "gnss_citygml", *map(str, args)],
        stdout=stdout,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=None if limit is None else limited,
        timeout=600,
    )


def one_line(result, where: str, what: str) -> None:
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: cannot write: "), result.stderr
    assert what in lines[0] and where in lines[0] and "internal error" not in lines[0]


def estimate(output: Path, *extra) -> list:
    return [
        "estimate",
        CITY / "observations.parquet",
        CITY / "footprints.gpkg",
        "--dem",
        CITY / "dem.tif",
        "-o",
        output,
        "-q",
        *extra,
    ]


@pytest.mark.parametrize("name", ["heights.gpkg", "heights.fgb", "heights.parquet"])
def test_an_output_past_the_limit_on_file_sizes(name, grid_args, tmp_path):
    """GDAL's GeoPackage driver loses the cause (it fails later with "no such table"): the
    error still says what happened."""
    output = tmp_path / name
    result = command(estimate(output, *grid_args), limit=8192)
    one_line(result, str(output), "too large")
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_an_existing_geopackage_is_kept_when_its_new_layer_does_not_fit(grid_args, tmp_path):
    target = tmp_path / "map.gpkg"
    pyogrio.write_dataframe(pyogrio.read_dataframe(CITY / "footprints.gpkg"), target)
    before = digest(target)
    result = command(estimate(target, *grid_args), limit=target.stat().st_size + 4096)
    one_line(result, str(target), "too large")
    assert digest(target) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["map.gpkg"]


def test_the_map_is_kept_when_the_update_does_not_fit(grid_args, tmp_path):
    """The copy of the map fits, the evidence written into it does not (SQLite's "disk I/O
    error"): the map is as it was, and neither the copy nor its journal is left."""
    target = tmp_path / "map.gpkg"
    pyogrio.write_dataframe(pyogrio.read_dataframe(CITY / "footprints.gpkg"), target)
    before = digest(target)
    args = ["update", target, "--observations", CITY / "observations.parquet"]
    result = command([*args, "--dem", CITY / "dem.tif", *grid_args, "-q"], limit=200_000)
    one_line(result, str(target), "too large")
    assert digest(target) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["map.gpkg"]


@pytest.mark.parametrize("output", ["-", "{d}/city.city.json"])
def test_a_city_model_into_a_full_stream_or_past_the_limit(output, grid_args, tmp_path):
    heights = tmp_path / "heights.gpkg"
    assert command(estimate(heights, *grid_args)).returncode == 0
    args = ["convert", heights, "-o", output.format(d=tmp_path), "-q"]
    if output == "-":
        with open("/dev/full", "wb") as full:  # writes fail with ENOSPC, as on a full disk
            result = command(args, stdout=full)
        one_line(result, "standard output", "no space left")
    else:
        result = command(args, limit=16384)
        one_line(result, output.format(d=tmp_path), "too large")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["heights.gpkg"]


def test_any_output_on_a_full_standard_output_is_one_line():
    """Not a city model: the messages of a command that prints to standard output."""
    with open("/dev/full", "wb") as full:
        result = command(["--help"], stdout=full)
    one_line(result, "standard output", "no space left")


def test_a_report_and_a_partition_past_the_limit(grid_args, tmp_path):
    report = command(
        ["report", CITY / "observations.parquet", CITY / "footprints.gpkg", "--dem",
         CITY / "dem.tif", "-o", tmp_path / "report", *grid_args, "-q"],
        limit=8192,
    )  # fmt: skip
    one_line(report, str(tmp_path / "report"), "too large")
    part = command(
        ["partition", CITY / "observations.parquet", "--dem", CITY / "dem.tif", "-o",
         tmp_path / "part", *grid_args, "-q"],
        limit=8192,
    )  # fmt: skip
    one_line(part, str(tmp_path / "part"), "too large")
    assert not (tmp_path / "part").exists()
    assert not [p for p in tmp_path.rglob("*") if ".part-" in p.name]


def test_a_city_model_to_a_closed_standard_output_is_one_line(grid_args, tmp_path):
    """-o - with the command's standard output closed (>&-): one line before any work (was an
    internal error, AttributeError, after it); nothing written."""
    heights = tmp_path / "heights.gpkg"
    assert command(estimate(heights, *grid_args)).returncode == 0
    result = subprocess.run(
        f'"{sys.executable}" -m gnss_citygml convert "{heights}" -o - -q >&-',
        shell=True,
        stderr=subprocess.PIPE,
        text=True,
        timeout=600,
    )
    assert result.returncode == 2, result.stderr
    assert result.stderr.splitlines() == [
        "error: standard output is closed (-o -): give the command one (> FILE, or | cjio "
        "stdin ...), or write a file with -o FILE"
    ]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["heights.gpkg"]
