"""Where the fit of benchmarks/raycast.py spends its time (issue 33): 4PL-B step by step, then
cProfile's top entries.

Reads the city that ``benchmarks/raycast.py`` cached in benchmarks/out/ (run that first with the
same ``--signals`` and ``--blocks``), runs the stages before the fit as it does (untimed), then
runs the fit (``estimate_heights``, with the open sky as raycast.py gives it: the phones
levelled) twice on the same intersections:

1. with wall-clock timers around 4PL-B's steps (nothing else changed) and prints, per 4PL-B
   iteration, the seconds of ``Part.fitted`` (of which ``fit_4pl``: its Levenberg-Marquardt
   iterations and likelihood evaluations), ``Part.shared``, ``Part.exchanged`` (of which the
   visibility model ``_unoccluded`` and the signals counted, over every row or, with the
   paper's classifier late in the loop, updated: :mod:`gnss_citygml.model.exchange`) and the
   classifier's refit;
   then the final ``Part.judged`` (the likelihood interval ``c_interval``, the position-error
   margin ``position_margin``) and the table's setup (``intersections_part``);
2. under cProfile, and prints the top ``--top`` entries by cumulative and by own time, and
   writes the stats to ``--pstats`` (default benchmarks/out/profile/fit.pstats).

It checks that both runs give the same heights.

    python benchmarks/profile_fit.py [--signals 1000000] [--blocks 100] [--top 25]
"""

from __future__ import annotations

import argparse
import cProfile
import functools
import pstats
import time
from collections import defaultdict
from pathlib import Path

import numpy as np
import pandas as pd
from raycast import OUT
from shared_data import GRIDS

from gnss_citygml.footprints import read_footprints
from gnss_citygml.model import estimate, exchange, fourpl, parts
from gnss_citygml.model.classifier import SignalClassifier
from gnss_citygml.model.estimate import estimate_heights
from gnss_citygml.observations import read_observations
from gnss_citygml.pipeline import intersections, open_sky, receivers
from gnss_citygml.terrain import building_ground

#: (owner, attribute) of the timed functions: the owners' names are what the fit calls.
TIMED = [
    (estimate, "intersections_part"),
    (parts.Part, "fitted"),
    (parts, "fit_4pl"),
    (fourpl, "evaluate"),
    (parts.Part, "shared"),
    (parts.Part, "exchanged"),
    (exchange, "_everything"),
    (exchange, "_update"),
    (exchange, "_unoccluded"),
    (SignalClassifier, "refit_counts"),
    (parts.Part, "judged"),
    (parts, "c_interval"),
    (parts, "position_margin"),
]


def load(folder: Path, grid_dir):
    """The intersections table of raycast.py's run (the stages before the fit) and its open
    sky."""
    obs = read_observations(folder / "observations.parquet")
    dem = str(folder / "dem.tif")
    fp = building_ground(read_footprints(folder / "footprints.gpkg"), dem)
    rx = receivers(obs, dem, grid_dir=grid_dir)
    inter = intersections(rx, fp)
    return inter, open_sky(rx, inter)


def timed_fit(inter: pd.DataFrame, sky) -> pd.DataFrame:
    """The fit with a timer around each of :data:`TIMED`; prints the steps per iteration."""
    # per iteration (a Part.fitted call starts one; 0 = before the first): name -> [s, calls]
    steps: dict[int, dict[str, list[float]]] = defaultdict(lambda: defaultdict(lambda: [0.0, 0]))
    lm_iterations: dict[int, int] = {}
    # _evaluate calls per iteration: rows summed, and the calls with at most 1 % of the groups
    # still active (the long tail of a few slow fits): [calls, seconds, rows]
    rows: dict[int, float] = defaultdict(float)
    tail: dict[int, list[float]] = defaultdict(lambda: [0, 0.0, 0.0])
    iteration = [0]
    originals = [(owner, name, getattr(owner, name)) for owner, name in TIMED]

    def wrap(name, func):
        @functools.wraps(func)
        def timer(*args, **kwargs):
            if name == "fitted":
                iteration[0] += 1
            start = time.perf_counter()
            result = func(*args, **kwargs)
            entry = steps[iteration[0]][name]
            entry[0] += time.perf_counter() - start
            entry[1] += 1
            if name == "fit_4pl":
                lm_iterations[iteration[0]] = int(result.n_iter.max(initial=0))
            if name == "evaluate":  # (theta, x, y, w, g, v, n_groups, active)
                g, active = args[4], args[7]
                n_rows = int(np.count_nonzero(active[g]))
                rows[iteration[0]] += n_rows
                if active.sum() <= 0.01 * active.size:
                    tail[iteration[0]][0] += 1
                    tail[iteration[0]][1] += time.perf_counter() - start
                    tail[iteration[0]][2] += n_rows
            return result

        return timer

    for owner, name, func in originals:
        setattr(owner, name, wrap(name, func))
    try:
        start = time.perf_counter()
        heights = estimate_heights(inter, open_sky=sky)
        total = time.perf_counter() - start
    finally:
        for owner, name, func in originals:
            setattr(owner, name, func)
    names = [name for _, name in TIMED]
    print(f"fit (4PL-B) {total:.2f} s, {iteration[0]} iterations; seconds (calls) per step:")
    print("iter " + " ".join(f"{n[:16]:>16s}" for n in names) + "  LM iters")
    for k in sorted(steps):
        cells = []
        for n in names:
            seconds, calls = steps[k].get(n, (0.0, 0))
            cells.append(f"{seconds:9.2f} ({calls:3d})" if calls else f"{'':>16s}")
        print(f"{k:4d} " + " ".join(cells) + f"  {lm_iterations.get(k, '')!s:>8s}")
    sums = {n: sum(steps[k][n][0] for k in steps if n in steps[k]) for n in names}
    print("all  " + " ".join(f"{sums[n]:16.2f}" for n in names))
    print("\n_evaluate: rows summed, and its calls with <= 1 % of the groups active (the tail):")
    for k in sorted(rows):
        calls, seconds, tail_rows = tail[k]
        print(
            f"{k:4d} {rows[k] / 1e6:8.1f} M rows; tail {calls:3d} calls "
            f"{seconds:6.2f} s {tail_rows / 1e6:6.1f} M rows"
        )
    return heights


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--signals", type=int, default=1_000_000)
    parser.add_argument("--blocks", type=int, default=100, help="blocks per side")
    parser.add_argument("--grid-dir", type=Path, default=GRIDS)
    parser.add_argument("--top", type=int, default=25)
    parser.add_argument("--pstats", type=Path, default=OUT / "profile" / "fit.pstats")
    args = parser.parse_args()
    folder = OUT / f"city_{args.blocks}x{args.blocks}_{args.signals}"
    if not (folder / "dem.tif").exists():
        parser.error(f"no cached city in {folder}: run benchmarks/raycast.py with these sizes")
    inter, sky = load(folder, args.grid_dir)
    print(f"{len(inter):,} intersections of {inter['building'].nunique():,} buildings")
    heights = timed_fit(inter, sky)
    profiler = cProfile.Profile()
    start = time.perf_counter()
    profiled = profiler.runcall(estimate_heights, inter, open_sky=sky)
    print(f"\nfit under cProfile {time.perf_counter() - start:.2f} s")
    same = heights.equals(profiled)  # NaN where NaN counts as equal
    print(f"{int(heights['converged'].sum()):,} heights; both runs the same: {same}")
    args.pstats.parent.mkdir(parents=True, exist_ok=True)
    profiler.dump_stats(args.pstats)
    stats = pstats.Stats(profiler).strip_dirs()
    for key in ("cumulative", "tottime"):
        print(f"\ntop {args.top} by {key} (stats in {args.pstats}):")
        stats.sort_stats(key).print_stats(args.top)


if __name__ == "__main__":
    main()
