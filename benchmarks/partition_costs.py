"""The client of a run from a partition that holds its footprints, written per tile: its peak
memory against the number of buildings (issue 30: it must not grow with them).

Builds, for each N, the sample city's observations and footprints plus N synthetic 15 m
footprints on a 25 m grid south of it (out of the receivers' reach, as most of a national map
is on any day), a flat synthetic DEM under all of them, and partitions them
(``partition_observations(..., footprints=...)``, 1 km tiles; cached in benchmarks/out/).
Then, in a fresh process, runs ``write_tiles(FOLDER, None, None, OUT)`` on a local Dask
cluster and samples the client's resident memory every 5 ms (the workers are other
processes), printing the plan's size, the time and the client's peak over its memory after
the imports.

    python benchmarks/partition_client.py [--buildings 10000 100000] [--workers 1]
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import time
from pathlib import Path

from memory import peak_while
from shared_data import GRIDS

OUT = Path(__file__).parent / "out"
CITY = Path(__file__).resolve().parents[1] / "examples" / "city"
#: The synthetic grid's north-west corner: 3 km south of the sample city, beyond every ray.
WEST, NORTH = 528000.0, 179000.0


def prepare(folder: Path, n: int) -> None:
    import geopandas as gpd
    import numpy as np
    import pandas as pd
    import rasterio
    import shapely
    from rasterio.transform import from_origin

    from gnss_citygml.footprints import read_footprints
    from gnss_citygml.tiling.buildings import Footprints
    from gnss_citygml.tiling.partition import partition_observations

    work = folder.with_name(folder.name + "-inputs")
    work.mkdir(parents=True, exist_ok=True)
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
    both.to_file(work / "footprints.gpkg", layer="buildings")
    west, south, east, north = both.total_bounds
    cells = 50.0
    width, height = int((east - west) // cells) + 3, int((north - south) // cells) + 3
    with rasterio.open(
        work / "dem.tif", "w", driver="GTiff", width=width, height=height, count=1,
        dtype="float32", crs="EPSG:27700", tiled=True,
        transform=from_origin(west - cells, north + cells, cells, cells),
    ) as dem:  # fmt: skip
        dem.write(np.full((height, width), 20.0, dtype="float32"), 1)
    partition_observations(
        [CITY / "observations.parquet"], folder, work / "dem.tif", tile_size=1000.0,
        footprints=Footprints(work / "footprints.gpkg"), grid_dir=GRIDS,
    )  # fmt: skip
    shutil.rmtree(work)


def measure(folder: Path, workers: int) -> None:
    """One run written per tile, the client's resident memory sampled (:mod:`memory`)."""
    import json

    from gnss_citygml.pipeline import write_tiles
    from gnss_citygml.settings import Tiling

    index = json.loads((folder / "partition.json").read_text())
    out = folder.with_name(folder.name + "-heights")
    tiles, seconds, peak = peak_while(
        lambda: write_tiles(
            folder, None, None, out, tiling=Tiling("local", workers), overwrite=True
        )
    )
    shutil.rmtree(out)
    buildings = index["buildings"]
    print(
        f"  {buildings['rows']:>9,} buildings in {len(buildings['tiles'])} tiles, "
        f"{len(tiles)} tiles written ({int(tiles['with_height'].sum())} heights), "
        f"index {(folder / 'partition.json').stat().st_size / 1e3:.0f} kB: {seconds:6.1f} s, "
        f"client peak +{peak:5.0f} MB"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--buildings", type=int, nargs="+", default=[10_000, 100_000])
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--run", help=argparse.SUPPRESS)  # the measured process
    args = parser.parse_args()
    if args.run:
        measure(Path(args.run), args.workers)
        return
    for n in args.buildings:
        folder = OUT / f"partition_client_{n}"
        if not (folder / "partition.json").exists():
            start = time.perf_counter()
            prepare(folder, n)
            print(f"partitioned {n:,} synthetic footprints in {time.perf_counter() - start:.0f} s")
        subprocess.run(
            [sys.executable, __file__, "--run", str(folder), "--workers", str(args.workers)],
            check=True,
        )


if __name__ == "__main__":
    main()
