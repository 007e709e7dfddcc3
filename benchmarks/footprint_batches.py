"""Footprints read whole against read in batches: the peak memory of each, for a national
map that must never be held whole (issue 30).

Writes N synthetic footprints (15 m squares with a text id and three attributes, like a
MasterMap extract) as a GeoPackage, cached in benchmarks/out/, then in a fresh process each
reads them whole (``read_footprints``) or batch by batch (``footprint_batches``, keeping
nothing), and prints the time and the process's peak memory (RSS) over its baseline.

    python benchmarks/footprint_batches.py [--buildings 100000 300000]
"""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

from memory import peak_while

OUT = Path(__file__).parent / "out"


def prepare(path: Path, n: int) -> None:
    import geopandas as gpd
    import numpy as np
    import shapely

    rng = np.random.default_rng(0)
    side = int(np.ceil(np.sqrt(n)))
    i = np.arange(n)
    x0 = 500000.0 + 25.0 * (i % side)
    y0 = 150000.0 + 25.0 * (i // side)
    frame = gpd.GeoDataFrame(
        {
            "toid": [f"osgb{1000000000000 + k}" for k in i],
            "descriptivegroup": "Building",
            "storeys": rng.integers(1, 12, n),
            "height": rng.uniform(3.0, 40.0, n),
        },
        geometry=shapely.box(x0, y0, x0 + 15.0, y0 + 15.0),
        crs="EPSG:27700",
    )
    frame.to_file(path, layer="buildings")


def measure(path: Path, how: str) -> None:
    """Read the footprints one way, the resident memory sampled (:mod:`memory`)."""
    from gnss_citygml.footprints import footprint_batches, read_footprints

    def read():
        if how == "whole":
            return len(read_footprints(path))
        return sum(len(batch) for batch in footprint_batches(path))

    rows, seconds, peak = peak_while(read)
    print(f"  {how:8s} {rows:>9,} footprints  {seconds:6.1f} s  peak +{peak:7.0f} MB")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--buildings", type=int, nargs="+", default=[100_000, 300_000])
    parser.add_argument("--run", nargs=2, help=argparse.SUPPRESS)  # the measured process
    args = parser.parse_args()
    if args.run:
        measure(Path(args.run[0]), args.run[1])
        return
    OUT.mkdir(exist_ok=True)
    for n in args.buildings:
        path = OUT / f"footprints_{n}.gpkg"
        if not path.exists():
            prepare(path, n)
        print(f"{n:,} footprints ({path.stat().st_size / 1e6:.0f} MB GeoPackage):")
        for how in ("whole", "batches"):
            subprocess.run([sys.executable, __file__, "--run", str(path), how], check=True)


if __name__ == "__main__":
    main()
