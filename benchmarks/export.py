"""Export speed and memory: buildings/s and peak memory of each writer, and validation time.

Writes N synthetic buildings (typical London footprints: rectangles, L-shapes, courtyards with
a hole, two-part buildings; 7.6 vertices on average) to CityJSONSeq, CityGML, CityJSON and 3D
Tiles (with the ranges; its size is the folder's), each
run in a fresh process so that its peak memory is its own. Peak memory is the growth of the
process's resident set (VmHWM, reset before writing) over its size once the buildings table is
built and the memory freed while building it is handed back to the system (glibc's and
Arrow's allocators): the memory of the writing only, not of the input table the caller holds.
Then the CityGML file is validated (XSD + geometry), and the tileset (its schemas from the
shared data, every GLB by Khronos' glTF validator).
Rates are given per wall-clock second and per CPU second (the two differ on a busy machine).

    python benchmarks/export.py                  # 10,000 and 100,000 buildings
    python benchmarks/export.py --sizes 2000     # a quick run
"""

from __future__ import annotations

import argparse
import ctypes
import gc
import json
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import geopandas as gpd
import numpy as np
import pyarrow as pa
import shapely
from shared_data import SHARED_DATA

WRITERS = ("cityjsonseq", "citygml", "cityjson", "3dtiles")
SUFFIX = {
    "cityjsonseq": ".city.jsonl",
    "citygml": ".gml",
    "cityjson": ".city.json",
    "3dtiles": "/tileset.json",
}


def buildings(n: int, seed: int = 0) -> gpd.GeoDataFrame:
    """n buildings on a 25 m grid from E 500000 N 180000, with a heights table's columns."""
    rng = np.random.default_rng(seed)
    side = int(np.ceil(np.sqrt(n)))
    e0 = 500000.0 + 25.0 * (np.arange(n) % side)
    n0 = 180000.0 + 25.0 * (np.arange(n) // side)
    w, d = rng.uniform(6, 18, n), rng.uniform(6, 18, n)
    kind = rng.choice(4, n, p=[0.6, 0.25, 0.1, 0.05])
    geoms = []
    for k, e, north, wide, deep in zip(kind, e0, n0, w, d, strict=True):
        east, top = e + wide, north + deep
        box = shapely.box(e, north, east, top)
        if k == 1:  # L-shape
            box = box.difference(shapely.box(e + wide / 2, north + deep / 2, east, top))
        elif k == 2:  # courtyard
            box = box.difference(
                shapely.box(e + wide / 3, north + deep / 3, e + 2 * wide / 3, north + 2 * deep / 3)
            )
        elif k == 3:  # two parts
            box = shapely.MultiPolygon([box, shapely.box(east + 1, north, east + 4, north + 3)])
        geoms.append(box)
    ground = rng.uniform(15, 30, n)
    height = ground + rng.uniform(4, 40, n)
    return gpd.GeoDataFrame(
        {
            "id": [f"osgb{1000000000000 + i}" for i in range(n)],
            "height": height,
            "height_lower": height - rng.uniform(0.5, 3, n),
            "height_upper": height + rng.uniform(0.5, 3, n),
            "ground": ground,
            "n_signals": rng.integers(10, 2000, n),
            "converged": True,
            "method": "4PL-B",
        },
        geometry=geoms,
        crs="EPSG:27700",
    )


def _status(field: str) -> int:
    """A field of /proc/self/status, in kB."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1])
    raise KeyError(field)


def one(writer: str, n: int, folder: str) -> dict:
    """Write n buildings with one writer in this process; time and memory."""
    from gnss_citygml import export

    frame = buildings(n)
    path = Path(folder) / f"b{n}{SUFFIX[writer]}"
    gc.collect()  # hand back what building the table freed, so that it is not reused unseen
    ctypes.CDLL("libc.so.6").malloc_trim(0)
    pa.default_memory_pool().release_unused()
    Path("/proc/self/clear_refs").write_text("5")  # reset the peak (VmHWM) to the current size
    before = _status("VmRSS")
    start, cpu = time.perf_counter(), time.process_time()
    options = {"ranges": True} if writer == "3dtiles" else {}
    getattr(export, f"write_{writer}")(frame, path, validate=False, overwrite=True, **options)
    seconds, cpu = time.perf_counter() - start, time.process_time() - cpu
    files = [path] if writer != "3dtiles" else [p for p in path.parent.rglob("*") if p.is_file()]
    result = {
        "writer": writer,
        "n": n,
        "seconds": seconds,
        "per_second": n / seconds,
        "per_cpu_second": n / cpu,
        "peak_mb": (_status("VmHWM") - before) / 1024,
        "file_mb": sum(f.stat().st_size for f in files) / 2**20,
    }
    if writer in ("citygml", "3dtiles"):
        from gnss_citygml.validate import validate_file, validate_tileset

        start, cpu = time.perf_counter(), time.process_time()
        if writer == "citygml":
            report = validate_file(path)
        else:
            report = validate_tileset(path, schema_dir=SHARED_DATA / "schemas")
        result["validate_seconds"] = time.perf_counter() - start
        result["validate_cpu"] = time.process_time() - cpu
        result["valid"] = report.valid
    if writer == "3dtiles":
        shutil.rmtree(path.parent)
    else:
        path.unlink()
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[10000, 100000])
    parser.add_argument("--one", nargs=3, metavar=("WRITER", "N", "FOLDER"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.one:
        print(json.dumps(one(args.one[0], int(args.one[1]), args.one[2])))
        return
    print(
        "| writer | buildings | time (s) | buildings/s | buildings/CPU-s "
        "| peak memory (MB) | file (MB) |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|")
    validations = []
    with tempfile.TemporaryDirectory() as folder:
        for n in args.sizes:
            for writer in WRITERS:
                out = subprocess.run(
                    [sys.executable, __file__, "--one", writer, str(n), folder],
                    capture_output=True,
                    text=True,
                    check=True,
                )
                r = json.loads(out.stdout)
                print(
                    f"| {writer} | {n:,} | {r['seconds']:.1f} | {r['per_second']:,.0f} "
                    f"| {r['per_cpu_second']:,.0f} | {r['peak_mb']:.0f} | {r['file_mb']:.0f} |"
                )
                if "validate_seconds" in r:
                    validations.append(r)
    for r in validations:
        kind = "CityGML" if r["writer"] == "citygml" else "the tileset"
        print(
            f"validate {kind}, {r['n']:,} buildings ({r['file_mb']:.0f} MB): "
            f"{r['validate_seconds']:.1f} s ({r['validate_cpu']:.1f} CPU-s), valid={r['valid']}"
        )


if __name__ == "__main__":
    main()
