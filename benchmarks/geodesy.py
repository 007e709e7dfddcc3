"""Throughput of ETRS89 <-> British National Grid + ODN (OSTN15 / OSGM15 through PROJ).

Prints points per second of ``to_osgb`` and ``from_osgb`` for points in one city (London) and
for points spread over Great Britain in random order (the case PROJ's grid cache handles
badly unless the points are sorted, which the module does).

    python benchmarks/geodesy.py                      # grids found as always (bundled last)
    python benchmarks/geodesy.py --grid-dir ../shared/data/geodesy -n 2000000
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from gnss_citygml.geodesy import from_osgb, to_osgb


def _rate(function, *args, grid_dir, repeat=3) -> float:
    """Best points per second over ``repeat`` runs (after one warm-up run)."""
    function(*(a[:10] for a in args), grid_dir=grid_dir)
    best = min(_timed(function, args, grid_dir) for _ in range(repeat))
    return args[0].size / best


def _timed(function, args, grid_dir) -> float:
    start = time.perf_counter()
    function(*args, grid_dir=grid_dir)
    return time.perf_counter() - start


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--grid-dir", default=None, help="folder holding the OS grids")
    parser.add_argument("-n", type=int, default=1_000_000, help="points per run")
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    areas = {
        "London (0.2 x 0.15 deg)": ((51.45, 51.60), (-0.25, -0.05)),
        "Great Britain, random order": ((50.5, 57.5), (-5.0, 1.0)),
    }
    print(f"{'points':>9}  {'area':<28} {'to_osgb /s':>12} {'from_osgb /s':>13}")
    for label, ((lat0, lat1), (lon0, lon1)) in areas.items():
        lat = rng.uniform(lat0, lat1, args.n)
        lon = rng.uniform(lon0, lon1, args.n)
        h = rng.uniform(40.0, 120.0, args.n)
        forward = _rate(to_osgb, lat, lon, h, grid_dir=args.grid_dir)
        e, n, odn = to_osgb(lat, lon, h, grid_dir=args.grid_dir)
        backward = _rate(from_osgb, e, n, odn, grid_dir=args.grid_dir)
        print(f"{args.n:>9}  {label:<28} {forward:>12,.0f} {backward:>13,.0f}")


if __name__ == "__main__":
    main()
