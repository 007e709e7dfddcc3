"""What a run in tiles costs, in one process and on Dask, and a plan for Great Britain.

A simulated city (``--km`` square: blocks 60 m apart, one building each, walked by
``--walkers`` phones for ``--seconds`` each at 1 Hz; the simulator's own physics) is moved
into British National Grid at TQ2080 and estimated once whole (:func:`estimate_heights` on
the single cast), then in 1, 4 and 16 tiles (of km, km/2 and km/4;
:func:`gnss_citygml.tiling.run.tiled_heights`): in one process, with each step timed, and on a
Dask ``LocalCluster`` of 1 and 2 worker processes. Printed per
tiling: the steps' cost per tile (cast; fit; exchange, i.e. the visibility model and the
classifier's counts; the final judgement), the driver's share (plan, the classifier's refit),
the wall time in one process and on Dask, Dask's overhead over one process, the speed-up of
2 workers, and the largest height difference from the single run. Then a plan for Great
Britain built from the measured cost per signal.

    python benchmarks/dask_tiles.py [--km 2] [--walkers 60] [--seconds 300]
"""

from __future__ import annotations

import argparse
import os
import time
from collections import Counter
from typing import Any

import numpy as np
import shapely

from gnss_citygml.model.classifier import SignalClassifier
from gnss_citygml.model.engine import InProcess
from gnss_citygml.model.estimate import estimate_heights
from gnss_citygml.model.parts import Part
from gnss_citygml.pipeline import intersections, open_sky
from gnss_citygml.settings import Tiling
from gnss_citygml.simulate import simulate
from gnss_citygml.simulate.scenes import city_scene
from gnss_citygml.tiling.cluster import connect
from gnss_citygml.tiling.run import tile_part, tiled_heights

#: South-west corner of the city (m, BNG): TQ2080, west London.
ORIGIN = np.array([520_000.0, 180_000.0])

#: Great Britain: buildings (OS MasterMap's ~47 M structures), signals, and its area in km^2
#: (England, Wales and Scotland): at most so many 1 km tiles (a square without a building
#: makes none).
GB_BUILDINGS, GB_SIGNALS, GB_KM2 = 47e6, 1e10, 230_000

#: Tasks per tile and iteration of run_parts (fit, share, exchange, part, tally), and per tile
#: once (cast, finish, and the write of an output per tile).
TASKS_PER_ITERATION, TASKS_ONCE = 5, 3

#: Steps of run_parts and tiled_heights, by function name, as printed.
STEPS = {
    "tile_part": "cast",
    "_fitted": "fit",
    "_shared": "exchange",
    "_exchanged": "exchange",
    "_first": "exchange",
    "_second": "exchange",
    "_total": "reduce",
    "tile_heights": "judge",
}


class Timed(InProcess):
    """The in-process engine, timing each kind of step."""

    def __init__(self) -> None:
        self.seconds: Counter[str] = Counter()
        self.rows: list[int] = []  # each tile's rows
        self.bytes: list[int] = []  # and what its part holds

    def submit(self, func: Any, *args: Any, key: str | None = None) -> Any:
        t = time.perf_counter()
        out = func(*args)
        self.seconds[STEPS[func.__name__]] += time.perf_counter() - t
        if func is tile_part:
            self.rows.append(out.h.size)
            self.bytes.append(_nbytes(out))
        return out


def _nbytes(part: Part) -> int:
    """What a part's arrays hold, after a fit (its state as it stays on a worker)."""
    fitted = part.fitted(SignalClassifier())
    arrays = [v for v in vars(fitted).values() if isinstance(v, np.ndarray)]
    arrays += [v for v in vars(fitted.last).values() if isinstance(v, np.ndarray)]
    return sum(a.nbytes for a in arrays)


def bng_city(km: float, walkers: int, seconds: float, seed: int) -> tuple[Any, Any]:
    """The simulated city (``km`` square, blocks 60 m apart, ``walkers`` phones walking for
    ``seconds`` each) moved into BNG at :data:`ORIGIN`: its rays and buildings."""
    blocks = int(km * 1000 // 60)
    scene = city_scene(
        np.random.default_rng(seed),
        blocks,
        blocks,
        walkers=walkers,
        walk_seconds=seconds,
        walk_length=600.0,
    )
    sim = simulate(scene, locations="gnss", seed=seed)
    rx = sim.rays.assign(e=sim.rays["e"] + ORIGIN[0], n=sim.rays["n"] + ORIGIN[1])
    moved = shapely.transform(sim.buildings.geometry.to_numpy(), lambda xy: xy + ORIGIN)
    return rx, sim.buildings.set_geometry(moved).set_crs(27700)


def city_arguments(description: str) -> argparse.Namespace:
    """The command line of a benchmark on :func:`bng_city`: its side, walkers, walk length
    and seed."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("--km", type=float, default=2.0, help="side of the city (km)")
    parser.add_argument("--walkers", type=int, default=60)
    parser.add_argument("--seconds", type=float, default=300.0, help="each walk's length (s)")
    parser.add_argument("--seed", type=int, default=0)
    return parser.parse_args()


def main() -> None:
    args = city_arguments(__doc__.splitlines()[0])
    t = time.perf_counter()
    rx, buildings = bng_city(args.km, args.walkers, args.seconds, args.seed)
    side = args.km * 1000.0
    print(
        f"{side / 1000:.2f} km city: {len(buildings):,} buildings, {len(rx):,} signals from "
        f"{args.walkers} phones (simulated in {time.perf_counter() - t:.0f} s); "
        f"{os.cpu_count()} cores\n"
    )
    t = time.perf_counter()
    inter = intersections(rx, buildings)
    cast = time.perf_counter() - t
    single = estimate_heights(inter, open_sky=open_sky(rx, inter))
    whole = time.perf_counter() - t
    print(
        f"single process: cast {cast:.1f} s ({len(inter):,} crossings), 4PL-B "
        f"{whole - cast:.1f} s, {whole:.1f} s in all; {int(single['converged'].sum())} "
        f"converged in {int(single['iterations'].max())} iterations\n"
    )
    print(
        "| tiles | tile side | per tile: cast | fit | exchange | judge | driver | one process "
        "| Dask, 1 worker | Dask, 2 workers | Dask overhead | speed-up, 2 workers | max diff |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    costs = {}
    for per_side in (1, 2, 4):
        size = float(np.ceil(side / per_side))
        engine = Timed()
        t = time.perf_counter()
        table = tiled_heights(rx, buildings, tile_size=size, engine=engine).table
        wall = time.perf_counter() - t
        n = _tiles(buildings, size)
        steps = engine.seconds
        driver = wall - sum(steps.values())
        walls, diff = [], _diff(table, single)
        for workers in (1, 2):
            with connect(Tiling("local", workers=workers, size=size)) as dask:
                t = time.perf_counter()
                on_dask = tiled_heights(rx, buildings, tile_size=size, engine=dask).table
                walls.append(time.perf_counter() - t)
                if workers == 2 and per_side == 1:
                    rate = _task_rate(dask)
            diff = max(diff, _diff(on_dask, single))
        costs[per_side] = (steps, n, engine)
        per = {k: steps[k] / n for k in ("cast", "fit", "exchange", "judge")}
        print(
            f"| {n} | {size:.0f} m | {per['cast']:.2f} s | {per['fit']:.2f} s | "
            f"{per['exchange']:.2f} s | {per['judge']:.2f} s | {driver:.1f} s | {wall:.1f} s | "
            f"{walls[0]:.1f} s | {walls[1]:.1f} s | {walls[0] - wall:+.1f} s | "
            f"{walls[0] / walls[1]:.2f}x | {diff:.1e} m |"
        )
    print(f"\nDask's scheduler: {rate:,.0f} small tasks/s (2 workers)")
    _plan(costs[2], len(rx), len(inter), rate, int(single["iterations"].max()))


def _task_rate(dask, n=5000) -> float:
    """Tasks per second through the engine: chains of trivial steps, as run_parts submits
    them (each takes the one before)."""
    t = time.perf_counter()
    futures = [dask.submit(abs, -k, key=f"bench-{k}-0") for k in range(n // 5)]
    for step in range(1, 5):
        futures = [dask.submit(abs, f, key=f"bench-{k}-{step}") for k, f in enumerate(futures)]
    dask.gather(futures)
    return n / (time.perf_counter() - t)


def _tiles(buildings, size) -> int:
    """How many tiles the plan made: the distinct tiles of the buildings."""
    from gnss_citygml.tiling.grid import building_tiles

    return len(set(building_tiles(buildings, size)))


def _diff(table, single) -> float:
    a, b = (t.set_index("id").sort_index() for t in (single, table))
    if not (a["converged"] == b["converged"]).all():
        return float("inf")
    return float(np.nanmax(np.abs(a["height"] - b["height"]), initial=0.0))


def _plan(measured, n_signals, n_crossings, rate, iterations) -> None:
    """Great Britain from the measured tiling's cost per signal (its halo included) and
    bytes per row, and the scheduler's task rate. Every tile's part stays on its worker for
    the whole run (each iteration needs it). The halo's share falls with larger tiles, so the
    1 km figures hold as an upper bound for 10 km tiles."""
    steps, n, engine = measured
    per_signal = sum(steps.values()) / n_signals  # s of one worker, halo overhead included
    worker_hours = GB_SIGNALS * per_signal / 3600
    rows = sum(engine.rows)
    per_row = sum(engine.bytes) / rows
    total = GB_SIGNALS * rows / n_signals * per_row  # bytes of every part at once
    print(
        f"\nPlan for Great Britain ({GB_BUILDINGS / 1e6:.0f} M buildings, "
        f"{GB_SIGNALS:.0e} signals) from the {n}-tile run: {per_signal * 1e6:.0f} us of one "
        f"worker per signal; {rows / n_signals:.1f} rows per signal in the tiles "
        f"({n_crossings / n_signals:.1f} crossings in the single cast) of {per_row:.0f} bytes "
        f"each: {total / 1e12:.1f} TB of parts held over the run; {worker_hours:,.0f} "
        f"worker-hours; {iterations} iterations"
    )
    print("| tile | tiles (at most) | tasks | scheduler | workers | hours | memory per worker |")
    print("|---|---|---|---|---|---|---|")
    for km in (1, 10):
        tiles = GB_KM2 / km**2
        tasks = tiles * (TASKS_PER_ITERATION * iterations + TASKS_ONCE)
        scheduler = tasks / rate / 3600
        for workers in (64, 256, 1024):
            print(
                f"| {km} km | {tiles:,.0f} | {tasks / 1e6:.1f} M | {scheduler:.1f} h | "
                f"{workers} | {max(worker_hours / workers, scheduler):.1f} | "
                f"{total / workers / 1e9:.0f} GB |"
            )


if __name__ == "__main__":
    main()
