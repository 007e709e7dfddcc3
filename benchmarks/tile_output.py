"""What the client holds and writes: heights gathered into one file, or written per tile.

The simulated city of ``dask_tiles.py`` (``--km`` square, in BNG) is estimated in tiles on a
Dask ``LocalCluster`` of 2 workers, twice for each tiling: once gathering the heights on the
client, which joins them onto the footprints and writes one GeoParquet file (``estimate -o
heights.parquet``), and once with each tile's worker writing its own
(:func:`gnss_citygml.pipeline.write_tiles`'s path: ``estimate -o FOLDER``). Printed per
tiling: the wall time of each, what the client received (the heights table against the tile
index, in memory), the files and bytes written, and whether the heights read back are the
gathered ones, bit for bit.

    python benchmarks/tile_output.py [--km 2] [--walkers 60] [--seconds 300]
"""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

import geopandas as gpd
import numpy as np
from dask_tiles import bng_city, city_arguments

from gnss_citygml.files.tables import write_layer
from gnss_citygml.pipeline import join_heights
from gnss_citygml.settings import Tiling
from gnss_citygml.tiling.cluster import connect
from gnss_citygml.tiling.output import TileFolder, write_index
from gnss_citygml.tiling.run import tiled_heights


def main() -> None:
    args = city_arguments(__doc__.splitlines()[0])
    rx, buildings = bng_city(args.km, args.walkers, args.seconds, args.seed)
    buildings = buildings.assign(ground=0.0)  # the simulator's ground
    print(
        f"{args.km:g} km city: {len(buildings):,} buildings, {len(rx):,} signals; "
        f"{os.cpu_count()} cores, Dask LocalCluster of 2 workers\n"
    )
    print(
        "| tiles | gathered: wall | client receives | writes | per tile: wall "
        "| client receives | files | bytes | same heights |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    side = args.km * 1000.0
    for per_side in (2, 4):
        size = float(np.ceil(side / per_side))
        with tempfile.TemporaryDirectory() as tmp, connect(Tiling("local", 2, size)) as dask:
            t = time.perf_counter()
            table = tiled_heights(rx, buildings, tile_size=size, engine=dask).table
            heights = join_heights(buildings, table, "4PL-B", "id")
            write_layer(heights, Path(tmp) / "heights.parquet", "heights")
            gathered = time.perf_counter() - t
            one = (Path(tmp) / "heights.parquet").stat().st_size
            folder = Path(tmp) / "tiles"
            folder.mkdir()
            t = time.perf_counter()
            out = TileFolder(str(folder), "4PL-B", "id", size)
            index = tiled_heights(rx, buildings, tile_size=size, engine=dask, output=out).table
            write_index(index, folder)
            written = time.perf_counter() - t
            files = [p for p in folder.rglob("*") if p.is_file()]
            size_on_disk = sum(p.stat().st_size for p in files)
            back = gpd.read_parquet(folder / "heights")
            same = _same(heights, back)
        print(
            f"| {len(index)} | {gathered:.1f} s | {_kb(table)} | 1 file, {one / 1e3:.0f} kB "
            f"| {written:.1f} s | {_kb(index)} | {len(files)} "
            f"| {size_on_disk / 1e3:.0f} kB | {same} |"
        )


def _kb(frame) -> str:
    """A table's size in memory."""
    return f"{frame.memory_usage(deep=True).sum() / 1e3:.1f} kB"


def _same(heights, back) -> str:
    """Whether the heights read back from the tiles are the gathered ones, bit for bit."""
    a, b = (t.set_index("id").sort_index() for t in (heights, back))
    floats = ["height", "height_lower", "height_upper", "relative_height"]
    equal = (
        a.index.tolist() == b.index.tolist()
        and all(np.array_equal(a[c], b[c], equal_nan=True) for c in floats)
        and a["status"].tolist() == b["status"].tolist()
    )
    return "yes" if equal else "NO"


if __name__ == "__main__":
    main()
