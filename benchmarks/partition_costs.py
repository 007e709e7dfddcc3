"""A run from a partition that holds its footprints, for Great Britain (issue 30): what each
step costs per tile and per building, the client's memory against the number of buildings,
and the run on 1, 2 and 4 workers.

For each N, the sample city's observations and footprints plus N synthetic 15 m footprints
on a 25 m grid south of it (out of the receivers' reach, as most of a national map is on any
day), on a DEM of 5 km GeoTIFF tiles of 5 m cells in a folder (as OS Terrain 5 ships), are
partitioned with ``partition_observations(..., footprints=...)`` in tiles of each
``--tile-size`` (cached in benchmarks/out/). Printed:

1. **partition** (one process): per building, reading the footprints in batches, their
   ground from the DEM, and the rest (cutting into tiles, writing, the ids' check).
2. **run, per tile** (``write_tiles(FOLDER, None, None, OUT)`` in one process, each step
   timed, the time inside a step's reads counted as reading): the tiles with receivers
   within reach read, cast and fit; every tile's buildings are read, joined to their heights
   and written; every file's SHA-256 is checked.
3. **run on Dask**: a ``dask scheduler`` and ``dask worker --nworkers W`` (1, 2, 4), each its
   own process as on a cluster; the run's wall time, the client's peak resident memory over
   its memory after the imports (sampled every 5 ms, :mod:`memory`), and the scheduler's and
   the largest worker's peak resident memory (VmHWM).
4. A plan for Great Britain from these figures and the cast and fit's cost per signal of
   ``benchmarks/dask_tiles.py`` (``--us-per-signal``).

    python benchmarks/partition_costs.py [--buildings 10000 100000 1000000]
        [--tile-size 1000 10000] [--workers 1 2 4]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path
from typing import Any

from memory import peak_while
from shared_data import GRIDS

OUT = Path(__file__).parent / "out"
CITY = Path(__file__).resolve().parents[1] / "examples" / "city"
#: The synthetic grid's north-west corner: 3 km south of the sample city, beyond every ray.
WEST, NORTH = 528000.0, 179000.0
#: The DEM: tiles of 5 km, cells of 5 m (OS Terrain 5's).
DEM_TILE, DEM_CELL = 5000.0, 5.0
#: Great Britain: buildings, signals, and its 10 km tiles (a square without a building makes none).
GB_BUILDINGS, GB_SIGNALS, GB_TILES = 47e6, 1e10, 2_300

#: Steps of a run, by function name (a function not named here is counted as "fit").
STEPS = {
    "read_building_files": "read",
    "read_receivers": "read",
    "partition_files_part": "cast",
    "write": "write",
    "check_digests": "check",
    "file_counts": "signals",
    "file_moments": "signals",
}


def inputs(n: int) -> Path:
    """The sample city's footprints plus ``n`` synthetic ones, and a DEM folder (cached)."""
    import geopandas as gpd
    import numpy as np
    import pandas as pd
    import rasterio
    import shapely
    from rasterio.transform import from_origin

    from gnss_citygml.footprints import read_footprints

    work = OUT / f"partition_costs_{n}-inputs"
    if (work / "footprints.gpkg").exists():
        return work
    (work / "dem").mkdir(parents=True, exist_ok=True)
    side = int(np.ceil(np.sqrt(n)))
    i = np.arange(n)
    x0, y0 = WEST + 25.0 * (i % side), NORTH - 25.0 * (i // side)
    synthetic = gpd.GeoDataFrame(
        {"id": [f"s{k}" for k in i]},
        geometry=shapely.box(x0, y0 - 15.0, x0 + 15.0, y0),
        crs="EPSG:27700",
    )
    city = read_footprints(CITY / "footprints.gpkg")[["id", "geometry"]]
    both = pd.concat([city, synthetic], ignore_index=True)
    both.to_file(work / "footprints-part.gpkg", layer="buildings", driver="GPKG")
    west, south, east, north = np.floor(both.total_bounds / DEM_TILE) * DEM_TILE + [0, 0, 1, 1]
    cells = int(DEM_TILE / DEM_CELL)
    for x in np.arange(west, east, DEM_TILE):
        for y in np.arange(south, north, DEM_TILE):
            top = y + DEM_TILE
            yy, xx = np.mgrid[
                top - DEM_CELL / 2 : y : -DEM_CELL, x + DEM_CELL / 2 : x + DEM_TILE : DEM_CELL
            ]
            ground = (20.0 + 8.0 * np.sin(xx / 3000.0) * np.cos(yy / 4000.0)).astype("float32")
            name = work / "dem" / f"{int(x) // 1000}_{int(y) // 1000}.tif"
            with rasterio.open(
                name, "w", driver="GTiff", width=cells, height=cells, count=1, dtype="float32",
                crs="EPSG:27700", tiled=True, transform=from_origin(x, top, DEM_CELL, DEM_CELL),
            ) as dem:  # fmt: skip
                dem.write(ground, 1)
    (work / "footprints-part.gpkg").rename(work / "footprints.gpkg")
    return work


def partition(n: int, size: float) -> Path:
    """The partition of :func:`inputs` in tiles of ``size`` m (cached), with its costs per
    building (``costs.json``): read, ground, and the rest of the partition."""
    from gnss_citygml.footprints import footprint_batches
    from gnss_citygml.terrain import building_ground
    from gnss_citygml.tiling.buildings import Footprints
    from gnss_citygml.tiling.partition import partition_observations

    folder = OUT / f"partition_costs_{n}_{size:g}"
    if (folder / "costs.json").exists():
        return folder
    work = inputs(n)
    start = time.perf_counter()
    batches = list(footprint_batches(work / "footprints.gpkg", grid_dir=GRIDS))
    read = time.perf_counter() - start
    start = time.perf_counter()
    for batch in batches:
        building_ground(batch, work / "dem")
    ground = time.perf_counter() - start
    rows = sum(len(b) for b in batches)
    del batches
    start = time.perf_counter()
    partition_observations(
        [CITY / "observations.parquet"], folder, work / "dem", tile_size=size,
        footprints=Footprints(work / "footprints.gpkg"), grid_dir=GRIDS, overwrite=True,
    )  # fmt: skip
    whole = time.perf_counter() - start
    costs = {"rows": rows, "read": read, "ground": ground, "rest": whole - read - ground}
    (folder / "costs.json").write_text(json.dumps(costs))
    return folder


class Timed:
    """The in-process engine, timing each kind of step; a step's time inside another step's
    (the reads inside a cast or a write) is counted once, as the inner step's."""

    def __init__(self) -> None:
        self.seconds: Counter[str] = Counter()
        self.calls: Counter[str] = Counter()
        self._inner: list[tuple[str, float]] = []  # the steps running, and their inner time

    def timed(self, func: Any, step: str) -> Any:
        def run(*args: Any) -> Any:
            name = f"{step} in {self._inner[-1][0]}" if self._inner else step
            self._inner.append((step, 0.0))
            start = time.perf_counter()
            try:
                return func(*args)
            finally:
                took = time.perf_counter() - start
                self.seconds[name] += took - self._inner.pop()[1]
                self.calls[name] += 1
                if self._inner:
                    outer, inner = self._inner[-1]
                    self._inner[-1] = (outer, inner + took)

        return run

    def submit(self, func: Any, *args: Any, key: str | None = None) -> Any:
        return self.timed(func, STEPS.get(getattr(func, "__name__", ""), "fit"))(*args)

    def gather(self, futures: Any) -> Any:
        return futures

    def failures(self, futures: Any) -> dict[int, str]:
        return {}


def one_process(folder: Path) -> dict[str, Any]:
    """The run of ``folder`` written per tile in this process, each step timed."""
    from gnss_citygml.tiling import from_partition, output
    from gnss_citygml.tiling.from_partition import partitioned_heights
    from gnss_citygml.tiling.output import TileFolder

    engine = Timed()
    reads = [  # the reads, timed wherever they are called
        (module, name, getattr(module, name))
        for module in (from_partition, output)
        for name in ("read_building_files", "read_receivers")
        if hasattr(module, name)
    ]
    size = json.loads((folder / "partition.json").read_text())["tile_size"]
    with tempfile.TemporaryDirectory() as out:
        for module, name, read in reads:
            setattr(module, name, engine.timed(read, "read"))
        try:
            start = time.perf_counter()
            written = TileFolder(out, "4PL-B", "id", size)
            run = partitioned_heights(folder, engine=engine, output=written)
            wall = time.perf_counter() - start
        finally:
            for module, name, read in reads:
                setattr(module, name, read)
    return {
        "wall": wall,
        "tiles": len(run.table),
        "casts": engine.calls["cast"],
        "seconds": dict(engine.seconds),
    }


def on_dask(folder: Path, workers: int) -> dict[str, Any]:
    """The run of ``folder`` on a scheduler and ``workers`` worker processes of their own:
    its wall time, and the client's, the scheduler's and a worker's peak memory."""
    from gnss_citygml.tiling.cluster import WORKER_MALLOC

    env = {**os.environ, **{k: str(v) for k, v in WORKER_MALLOC.items()}}
    with tempfile.TemporaryDirectory() as tmp:
        address = Path(tmp) / "scheduler.json"
        scheduler = subprocess.Popen(
            [sys.executable, "-m", "distributed.cli.dask_scheduler",
             "--scheduler-file", str(address), "--port", "0", "--no-dashboard"],
            stderr=subprocess.DEVNULL,
        )  # fmt: skip
        while not address.exists():
            time.sleep(0.1)
        nanny = subprocess.Popen(
            [sys.executable, "-m", "distributed.cli.dask_worker", "--scheduler-file", str(address),
             "--nworkers", str(workers), "--nthreads", "1", "--no-dashboard"],
            env=env, stderr=subprocess.DEVNULL,
        )  # fmt: skip
        try:
            client = subprocess.run(
                [sys.executable, __file__, "--client", str(folder), str(address), str(workers)],
                check=True, capture_output=True, text=True,
            )  # fmt: skip
            figures = json.loads(client.stdout.splitlines()[-1])
            figures["scheduler"] = _peak_mb(scheduler.pid)
            figures["worker"] = max(_peak_mb(p) for p in _descendants(nanny.pid))
        finally:
            nanny.terminate()
            nanny.wait()
            scheduler.terminate()
            scheduler.wait()
    return figures


def client(folder: Path, address: Path, workers: int) -> None:
    """The measured client (a process of its own): one line of JSON."""
    from distributed import Client

    from gnss_citygml.pipeline import write_tiles
    from gnss_citygml.settings import Tiling

    scheduler = json.loads(address.read_text())["address"]
    with Client(scheduler) as waiting:
        waiting.wait_for_workers(workers)
    out = folder.with_name(folder.name + "-heights")
    _, seconds, peak = peak_while(
        lambda: write_tiles(folder, None, None, out, tiling=Tiling(scheduler), overwrite=True)
    )
    shutil.rmtree(out)
    print(json.dumps({"wall": seconds, "client": peak}))


def _peak_mb(pid: int) -> float:
    """A process's peak resident memory (MB), from /proc."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1e3
    return float("nan")


def _descendants(pid: int) -> list[int]:
    import psutil

    return [p.pid for p in psutil.Process(pid).children(recursive=True)]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--buildings", type=int, nargs="+", default=[10_000, 100_000, 1_000_000])
    parser.add_argument("--tile-size", type=float, nargs="+", default=[1000.0, 10000.0])
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2, 4])
    parser.add_argument(
        "--us-per-signal", type=float, default=75.0,
        help="the cast and fit's worker time per signal, halo included (dask_tiles.py)",
    )  # fmt: skip
    parser.add_argument("--client", nargs=3, help=argparse.SUPPRESS)  # the measured process
    args = parser.parse_args()
    if args.client:
        client(Path(args.client[0]), Path(args.client[1]), int(args.client[2]))
        return
    print(f"{os.cpu_count()} cores; the client's peak is over its memory after the imports\n")
    rows = []
    for size in args.tile_size:
        for n in args.buildings:
            folder = partition(n, size)
            rows.append((size, folder, json.loads((folder / "costs.json").read_text())))
    print("partition, one process, us per building: read | ground | cut, write, ids | total")
    for size, _, c in rows:
        per = {k: 1e6 * c[k] / c["rows"] for k in ("read", "ground", "rest")}
        print(
            f"  {c['rows']:>9,} buildings, {size:>5g} m tiles: {per['read']:5.1f} | "
            f"{per['ground']:5.1f} | {per['rest']:5.1f} | {sum(per.values()):5.1f}"
        )
    print("\nrun, one process: tiles (with receivers) | per tile with receivers: read, cast, fit"
          " | per tile: read, write, check | per building: read, write, check | wall")  # fmt: skip
    for size, folder, c in rows:
        t = one_process(folder)
        s, k, m = Counter(t["seconds"]), max(t["casts"], 1), t["tiles"]
        print(
            f"  {c['rows']:>9,} buildings, {size:>5g} m: {m} ({t['casts']}) | "
            f"{s['read in cast'] / k:.2f} s, {s['cast'] / k:.2f} s, {s['fit'] / k:.2f} s | "
            f"{1e3 * s['read in write'] / m:.0f} ms, {1e3 * s['write'] / m:.0f} ms, "
            f"{1e3 * s['check'] / m:.0f} ms | "
            f"{1e6 * (s['read in write'] + s['write'] + s['check']) / c['rows']:.1f} us | "
            f"{t['wall']:.1f} s"
        )
        c["run"] = t
    print("\nrun on Dask (scheduler, workers and client each a process): "
          "workers | wall | client peak | scheduler peak | a worker's peak")  # fmt: skip
    for size, folder, c in rows:
        for w in args.workers:
            d = on_dask(folder, w)
            print(
                f"  {c['rows']:>9,} buildings, {size:>5g} m, {w} workers: {d['wall']:6.1f} s | "
                f"+{d['client']:3.0f} MB | {d['scheduler']:4.0f} MB | {d['worker']:4.0f} MB"
            )
    plan(rows, args.us_per_signal)


def plan(rows: list[tuple[float, Path, dict[str, Any]]], us_per_signal: float) -> None:
    """Great Britain from the largest partition's costs per building."""
    size, _, c = max(rows, key=lambda r: (r[2]["rows"], r[0]))
    partition_h = GB_BUILDINGS * (c["read"] + c["ground"] + c["rest"]) / c["rows"] / 3600
    s = Counter(c["run"]["seconds"])
    per_building = (s["read in write"] + s["write"] + s["check"]) / c["rows"]
    worker_h = (GB_BUILDINGS * per_building + GB_SIGNALS * us_per_signal * 1e-6) / 3600
    print(
        f"\nGreat Britain ({GB_BUILDINGS / 1e6:.0f} M buildings, {GB_SIGNALS:.0e} signals, "
        f"{GB_TILES:,} tiles of 10 km), from {c['rows']:,} buildings in {size:g} m tiles:\n"
        f"  partition, one process: {partition_h:.1f} h\n"
        f"  run: {worker_h:.0f} worker-hours ({GB_BUILDINGS * per_building / 3600:.1f} of them "
        f"the buildings' read, check and write); 64 workers {worker_h / 64:.1f} h, "
        f"256 workers {worker_h / 256:.1f} h"
    )


if __name__ == "__main__":
    main()
