"""The city-model commands (``convert``, ``export``) writing CityJSONSeq to standard output
with ``-o -``: the real command piped into real ``cjio stdin``, nothing on standard output
when a run fails, and one error line when the reader stops early.

The heights layers are made here with geopandas (EPSG:27700, ground and absolute heights), so
no grid or DEM is needed.
"""

import json
import subprocess
import sys
from pathlib import Path

import geopandas as gpd
import pandas as pd
import shapely
from test_cli import run

BIN = Path(sys.executable).parent
ERROR_CLOSED = (
    "error: standard output was closed before the whole city model was written (-o -): "
    "let the reader take all of it, or write a file with -o FILE\n"
)


def heights_layer(path, n=3, *, extra=(), roofs=True):
    """``n`` boxes in a row near UCL, ``b0``, ``b1``, ..., with ground 20 m and (``roofs``)
    heights 30-35 m ODN, then the ``extra`` footprints (roof 30 m)."""
    boxes = [shapely.box(529500 + 12 * i, 182300, 529510 + 12 * i, 182308) for i in range(n)]
    geometry = boxes + list(extra)
    frame = gpd.GeoDataFrame(
        {"id": [f"b{i}" for i in range(len(geometry))], "ground": 20.0},
        geometry=geometry,
        crs="EPSG:27700",
    )
    if roofs:
        frame["height"] = [30.0 + i % 6 for i in range(n)] + [30.0] * len(extra)
    frame.to_file(path, layer="heights")
    return path


def command(*args):
    return [str(BIN / "gnss-citygml"), *map(str, args)]


def test_convert_to_stdout_feeds_cjio(tmp_path):
    source = heights_layer(tmp_path / "heights.gpkg", n=50)
    saved = tmp_path / "from_stdin.city.json"
    writer = subprocess.Popen(
        command("convert", source, "-o", "-"), stdout=subprocess.PIPE, stderr=subprocess.PIPE
    )
    reader = subprocess.Popen(
        [str(BIN / "cjio"), "stdin", "save", str(saved)],
        stdin=writer.stdout,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    writer.stdout.close()  # cjio alone reads the pipe
    _, cjio_err = reader.communicate(timeout=300)
    err = writer.stderr.read().decode()
    assert writer.wait(timeout=300) == 0, err
    assert reader.returncode == 0, cjio_err.decode()
    # every message went to stderr, stdout held the stream alone
    assert err.strip().splitlines()[-1].startswith("50 buildings, 0 skipped -> standard output")
    model = json.loads(saved.read_text())
    buildings = [k for k, v in model["CityObjects"].items() if v["type"] == "Building"]
    assert sorted(buildings) == sorted(f"b{i}" for i in range(50))


def test_export_to_stdout_writes_only_cityjsonseq(tmp_path, capsys):
    source = heights_layer(tmp_path / "footprints.gpkg", roofs=False)
    table = tmp_path / "h.csv"
    pd.DataFrame({"id": ["b0", "b1"], "height": [31.0, 32.0]}).to_csv(table, index=False)
    args = ["export", str(table), "--footprints", str(source), "-o", "-", "-q"]
    code, out, err = run(args, capsys)
    assert code == 0, err
    lines = [json.loads(line) for line in out.splitlines()]
    assert lines[0]["type"] == "CityJSON"
    assert [line["id"] for line in lines[1:]] == ["b0", "b1"]
    assert "skipped b2: no height" in err and "-> standard output, valid" in err
    assert not list(tmp_path.glob("*.jsonl")) and not list(tmp_path.glob(".*"))


def test_a_failed_run_leaves_stdout_empty(tmp_path):
    """--strict and a footprint that vanishes at 1 mm: the writer stops after it has written
    the header line to its file; nothing reaches standard output."""
    sliver = shapely.box(529400, 182300, 529400.0004, 182310)
    source = heights_layer(tmp_path / "heights.gpkg", extra=[sliver])
    done = subprocess.run(
        command("convert", source, "-o", "-", "--strict"), capture_output=True, timeout=300
    )
    assert done.returncode == 2
    assert done.stdout == b""
    err = done.stderr.decode()
    assert err.startswith("error: 1 footprint(s) vanish at 1 mm precision: b3")
    assert len(err.strip().splitlines()) == 1


def test_a_closed_stdout_is_one_error_line(tmp_path):
    """Standard output closed before the model is copied there (its reader has gone): one
    error line and exit 2, not a traceback."""
    source = heights_layer(tmp_path / "heights.gpkg")
    writer = subprocess.Popen(
        command("convert", source, "-o", "-", "-q"), stdout=subprocess.PIPE, stderr=subprocess.PIPE
    )
    writer.stdout.close()  # the only reader
    _, err = writer.communicate(timeout=300)
    assert writer.returncode == 2
    assert err.decode() == ERROR_CLOSED


def test_head_reads_the_start_without_a_traceback(tmp_path):
    """``| head -c 10``: head takes its 10 bytes and leaves; whether the rest still fitted in
    the pipe (exit 0) or met the closed pipe (exit 2, one error line), no traceback."""
    source = heights_layer(tmp_path / "heights.gpkg", n=600)  # 350 kB of CityJSONSeq
    line = " ".join(command("convert", source, "-o", "-", "-q"))
    done = subprocess.run(
        ["bash", "-c", f"set -o pipefail; {line} | head -c 10"], capture_output=True, timeout=300
    )
    assert done.stdout == b'{"type":"C'
    err = done.stderr.decode()
    done_line = "600 buildings, 0 skipped -> standard output, valid (json, structure, geometry)\n"
    assert (done.returncode, err) in ((0, done_line), (2, ERROR_CLOSED))
