"""What cutting a run into tiles costs: the plan, and the rays each tile casts with its halo.

A synthetic city (``--km`` square of British National Grid, ``--buildings`` boxes of 8-40 m,
``--signals`` rays from random receivers with random bearings) is cast once whole, then cut
into 1, 4 and 16 tiles (tile side = km / 1, 2, 4) and cast tile by tile against each tile's
buildings and halo (:func:`gnss_citygml.tiling.grid.plan_tiles`). Printed per tiling: the time to
plan, the cast's total and largest tile time, and how many crossings the tiles cast beside
the single run's (the halo's overhead: a ray is cast in every tile whose buildings' extent it
enters). The rows of a tile's own buildings equal the single cast's (tests/test_tiles.py).

    python benchmarks/tiles.py [--km 4] [--buildings 20000] [--signals 1000000] [--reach 500]
"""

from __future__ import annotations

import argparse
import time

import geopandas as gpd
import numpy as np
from shapely.geometry import box

from gnss_citygml.raycast import footprint_entries
from gnss_citygml.tiling.grid import plan_tiles

#: South-west corner of the city (m, BNG): TQ2080, west London.
ORIGIN = (520_000.0, 180_000.0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--km", type=int, default=4, help="side of the city (km)")
    parser.add_argument("--buildings", type=int, default=20_000)
    parser.add_argument("--signals", type=int, default=1_000_000)
    parser.add_argument("--reach", type=float, default=500.0, help="rays' horizontal reach (m)")
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    side = args.km * 1000.0
    corners = rng.uniform(0, side - 40, (args.buildings, 2)) + ORIGIN
    sizes = rng.uniform(8, 40, (args.buildings, 2))
    geometry = np.array(
        [box(x, y, x + w, y + h) for (x, y), (w, h) in zip(corners, sizes, strict=True)]
    )
    buildings = gpd.GeoDataFrame(geometry=geometry, crs=27700)
    e, n = (rng.uniform(0, side, args.signals) + o for o in ORIGIN)
    bearing = rng.uniform(0, 360, args.signals)

    t = time.perf_counter()
    whole = footprint_entries(e, n, bearing, geometry, args.reach)[0].size
    single = time.perf_counter() - t
    print(
        f"{args.km} km city, {args.buildings:,} buildings, {args.signals:,} rays of "
        f"{args.reach:.0f} m: one cast {single:.1f} s, {whole:,} crossings\n"
    )
    print(
        "| tiles | tile side | plan | cast: all tiles | largest tile | crossings | halo overhead |"
    )
    print("|---|---|---|---|---|---|---|")
    for per_side in (1, 2, 4):
        size = side / per_side
        t = time.perf_counter()
        tiles = plan_tiles(e, n, buildings, args.reach, size, bearing)
        plan = time.perf_counter() - t
        times, rows = [], 0
        for tile in tiles:
            cast = np.concatenate([tile.buildings, tile.halo])
            r = tile.receivers
            t = time.perf_counter()
            rows += footprint_entries(e[r], n[r], bearing[r], geometry[cast], args.reach)[0].size
            times.append(time.perf_counter() - t)
        print(
            f"| {len(tiles)} | {size:.0f} m | {plan:.1f} s | {sum(times):.1f} s | "
            f"{max(times):.1f} s | {rows:,} | {rows / whole:.2f}x |"
        )


if __name__ == "__main__":
    main()
