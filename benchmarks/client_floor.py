"""What a run in tiles still does on its client: read every footprint and find its ground.

A run in tiles reads the footprints and samples their ground from the DEM on the machine
that runs the command (each tile's then travel with its task). This measures that floor on
real OS MasterMap buildings (the shared UCL/Bloomsbury extract, never copied into the
repository), repeated ``--copies`` times side by side with their own ids into a GeoPackage,
with a flat 1 m DEM under them: seconds and bytes per building for
:func:`~gnss_citygml.footprints.read_footprints` and
:func:`~gnss_citygml.terrain.building_ground`, and what that makes for Great Britain's
47 M buildings.

    python benchmarks/client_floor.py [--copies 100]
"""

from __future__ import annotations

import argparse
import tempfile
import time
import tracemalloc
from pathlib import Path

import geopandas as gpd
import numpy as np
import pandas as pd
import rasterio
import shapely
from rasterio.transform import from_origin
from shared_data import SHARED_DATA

from gnss_citygml.footprints import read_footprints
from gnss_citygml.terrain import building_ground

#: The MasterMap extract (Euston / Bloomsbury: 160 buildings).
MASTERMAP = SHARED_DATA / "footprints" / "mastermap-topo_3473984_0.gml"

#: Great Britain's buildings (OS MasterMap's ~47 M structures).
GB_BUILDINGS = 47e6


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--copies", type=int, default=100)
    args = parser.parse_args()
    one = read_footprints(MASTERMAP)
    x0, y0, x1, y1 = one.total_bounds
    side = int(np.ceil(np.sqrt(args.copies)))
    step = max(x1 - x0, y1 - y0) + 100.0
    frames = []
    for k in range(args.copies):
        dx, dy = (k % side) * step, (k // side) * step
        moved = one.set_geometry(one.geometry.translate(dx, dy))
        frames.append(moved.assign(id=moved["id"] + f"-{k}"))
    city = gpd.GeoDataFrame(pd.concat(frames, ignore_index=True), crs=one.crs)
    vertices = shapely.get_num_coordinates(city.geometry.to_numpy()).mean()
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "footprints.gpkg"
        city.rename(columns={"id": "toid"}).to_file(path, layer="buildings")
        dem = Path(tmp) / "dem.tif"
        _flat_dem(dem, city.total_bounds)
        t = time.perf_counter()
        footprints = read_footprints(path)
        read = time.perf_counter() - t
        t = time.perf_counter()
        grounded = building_ground(footprints, dem)
        ground = time.perf_counter() - t
        tracemalloc.start()  # again, traced (which slows them down)
        building_ground(read_footprints(path), dem)
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
    n = len(grounded)
    held = grounded.memory_usage(deep=True).sum() + sum(
        len(w) for w in shapely.to_wkb(grounded.geometry.to_numpy())
    )
    print(
        f"{n:,} MasterMap buildings ({args.copies} copies of {len(one)}; {vertices:.1f} "
        f"vertices each on average), one process\n"
    )
    print("| step | per building | Great Britain (47 M) |")
    print("|---|---|---|")
    for what, seconds in (("read_footprints", read), ("building_ground", ground)):
        print(
            f"| {what} | {seconds / n * 1e6:.0f} us | {seconds / n * GB_BUILDINGS / 3600:.1f} h |"
        )
    for what, size in (
        ("the table held (attributes + WKB)", held),
        ("peak of the two (traced by Python)", peak),
    ):
        print(f"| {what} | {size / n:.0f} B | {size / n * GB_BUILDINGS / 1e9:.0f} GB |")


def _flat_dem(path: Path, bounds: np.ndarray) -> None:
    """A flat 1 m DEM in EPSG:27700 covering ``bounds`` with a 10 m margin, in blocks of 256
    cells as LIDAR tiles come (the ground is read block by block)."""
    west, south = np.floor(bounds[:2]) - 10.0
    east, north = np.ceil(bounds[2:]) + 10.0
    width, height = int(east - west), int(north - south)
    grid = {"width": width, "height": height, "transform": from_origin(west, north, 1.0, 1.0)}
    blocks = {"tiled": True, "blockxsize": 256, "blockysize": 256, "compress": "deflate"}
    with rasterio.open(
        path, "w", driver="GTiff", count=1, dtype="float32", crs="EPSG:27700", **grid, **blocks
    ) as out:
        out.write(np.full((1, height, width), 25.0, dtype=np.float32))


if __name__ == "__main__":
    main()
