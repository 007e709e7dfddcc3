"""How long the report of a 10,000-building run takes to write (target: under 30 s).

The run is synthetic but goes through the real model: 10,000 square footprints on a grid, 150
signals per building from 200 receivers on the streets, each signal open above a roof line
drawn at random (10-40 m above the ground) and its C/N0 drawn from open or reflected
distributions (a fifth of the closed ones not received at all), fitted by 4PL-B
(estimate_heights). Only the report is timed: the figures per building are drawn for the
worst, best and a sample, not for 10,000.

    python benchmarks/report.py [--buildings N]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import geopandas as gpd
import numpy as np
import pandas as pd
import shapely

from gnss_citygml.model.estimate import heights_and_signal_model
from gnss_citygml.pipeline import Run, join_heights
from gnss_citygml.report import write_report
from gnss_citygml.settings import Estimator

PER_BUILDING = 150
RECEIVERS = 200


def synthetic_run(n_buildings: int, seed: int = 0) -> Run:
    rng = np.random.default_rng(seed)
    side = int(np.ceil(np.sqrt(n_buildings)))
    i, j = np.divmod(np.arange(n_buildings), side)
    x0, y0 = 530000 + 30.0 * j, 180000 + 30.0 * i
    buildings = gpd.GeoDataFrame(
        {"id": [f"b{k}" for k in range(n_buildings)], "ground": 20.0},
        geometry=shapely.box(x0, y0, x0 + 20, y0 + 20),
        crs="EPSG:27700",
    )
    roof = 20.0 + rng.uniform(10, 40, n_buildings)
    n = n_buildings * PER_BUILDING
    building = np.repeat(np.arange(n_buildings), PER_BUILDING)
    height = roof[building] + rng.normal(0, 12, n)
    open_ = rng.random(n) < np.where(height > roof[building], 0.95, 0.05)
    cn0 = np.where(open_, rng.normal(43, 3, n), rng.normal(28, 5, n))
    cn0[~open_ & (rng.random(n) < 0.2)] = np.nan
    receiver = rng.integers(0, RECEIVERS, n)
    receivers = pd.DataFrame(
        {
            "receiver": [f"phone_{r}" for r in receiver],
            "time_utc": pd.Timestamp("2026-11-24", tz="UTC")
            + pd.to_timedelta(np.arange(n) // 40, "s"),
            "e": x0[building] - 5 + rng.normal(0, 1, n),
            "n": y0[building] - 5 + rng.normal(0, 1, n),
            "azimuth": rng.uniform(0, 360, n),
            "elevation": rng.uniform(10, 85, n),
            "cn0": cn0,
        }
    )
    intersections = pd.DataFrame(
        {
            "signal": np.arange(n),
            "building": buildings["id"].to_numpy()[building],
            "height": height,
            "distance": rng.uniform(5, 60, n),
            "order": 0,
            "cn0": cn0,
        }
    )
    heights, classifier = heights_and_signal_model(intersections, Estimator())
    joined = join_heights(buildings, heights, "4PL-B", "id")
    return Run(joined, receivers, intersections, buildings, classifier)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--buildings", type=int, default=10_000)
    args = parser.parse_args()
    start = time.perf_counter()
    run = synthetic_run(args.buildings)
    made = time.perf_counter() - start
    converged = int(run.heights["converged"].sum())
    print(
        f"report of {args.buildings:,} buildings ({converged:,} converged), "
        f"{len(run.intersections):,} signals from {RECEIVERS} receivers "
        f"(run made and fitted in {made:.1f} s):"
    )
    with tempfile.TemporaryDirectory() as folder:
        start = time.perf_counter()
        stages = []

        def told(what: str) -> None:
            stages.append((what, time.perf_counter()))

        page = write_report(run, folder, progress=told)
        total = time.perf_counter() - start
        size = Path(page).stat().st_size
    marks = [*stages, ("end", start + total)]
    for (what, at), (_, then) in zip(marks, marks[1:], strict=False):
        print(f"  {what:10s} {then - at:6.2f} s")
    print(f"  total      {total:6.2f} s (target < 30 s), report.html {size / 1e6:.1f} MB")


if __name__ == "__main__":
    main()
