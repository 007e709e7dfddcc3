"""How much walking a district needs: converged share, RMSE to the roof span, right and wrong
answers against the number of days walked (issue 48, item 3).

Each scene is the walked district (``scenes.district_days``: 6 x 6 blocks, 20-40 people a
day, each day 1-7 days after the last at another time of day) with phone fixes, each
recording its own phone (``scenes.phones``), in streets as harsh as real ones
(``scenes.HARSH``; ``--today`` for the simulator's default fixes). One run over all the days
is what ``update`` gives a map updated day by day (its heights are the full run's:
docs/update.md). One initial threshold (30 dB-Hz). Epochs are thinned where many days would
pass the simulator's limit (at most 150,000 epochs a run: 2 s apart for 20 days, 5 s for 50).
With ``--match`` the fixes are placed by shadow matching first (:data:`MATCHING`; issue 48,
item 2: docs/issue-48-shadows.md).

    python data_needs.py [--scenes 5] [--days 1 5 20 50] [--signal-model mixture] [--today]
                              [--match]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import pandas as pd
from accuracy import judge, position_error, site_tables
from scenes import RIGHT_WITHIN, district_days, harsh, phones, random_physics

from gnss_citygml import Estimator, estimate_heights
from gnss_citygml.calibrate import calibrate_receivers
from gnss_citygml.pipeline import intersections, open_sky
from gnss_citygml.settings import SIGNAL_MODELS, Calibration
from gnss_citygml.simulate import simulate

#: Shadow matching (``--match``): 10 s windows, each window's prior its fixes' own error (the
#: 5 m where they have none), three rounds with the heights.
MATCHING = Calibration(prior_sd=5.0, window=10.0, rounds=3, matching="shadows")

#: Most epochs of one run: the simulator's limit is 200,000.
MAX_EPOCHS = 150_000


def district_run(
    k: int, days: int, signal_model: str, today: bool, matched: bool = False
) -> tuple[pd.DataFrame, int]:
    """The judged converged heights of district scene ``k`` walked on ``days`` days with phone
    fixes (:func:`accuracy.judge`), and its number of buildings; with ``matched`` the fixes
    placed by shadow matching first (:data:`MATCHING`)."""
    scene, start, _ = district_days(k, days)
    physics = random_physics(k) if today else harsh(k, random_physics(k))
    seconds = sum(s.duration for s in scene.sessions)
    interval = max(1.0, float(np.ceil(seconds / MAX_EPOCHS)))
    sim = simulate(
        scene,
        locations="gnss",
        seed=k,
        start=start,
        interval=interval,
        physics=phones(k, physics, len(scene.sessions)),
    )
    error = position_error("data", "gnss", None, None)
    rays, _, cast = site_tables(sim, position_error=error)
    estimator = Estimator(init_threshold=30.0, signal_model=signal_model)
    if matched:
        rays = calibrate_receivers(rays, sim.buildings, MATCHING, estimator=estimator)
        cast = intersections(rays, sim.buildings, position_error=error)
    heights = estimate_heights(cast, estimator, open_sky=open_sky(rays, cast))
    return judge(heights, sim.truth), len(sim.truth)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=5)
    parser.add_argument("--days", type=int, nargs="+", default=[1, 5, 20, 50])
    parser.add_argument("--signal-model", choices=SIGNAL_MODELS, default="paper")
    parser.add_argument("--today", action="store_true", help="the simulator's default fixes")
    parser.add_argument(
        "--match", action="store_true", help="the fixes placed by shadow matching first"
    )
    args = parser.parse_args()
    fixes = "today's" if args.today else "harsh"
    placed = ", placed by shadow matching" if args.match else ""
    print(f"Walked district, phone fixes ({fixes}{placed}), signal model {args.signal_model}, ")
    print(f"{args.scenes} scenes; cells over all scenes' buildings.\n")
    print("| days | converged | RMSE to span | ranges meet span | right | wrong | seconds a run |")
    print("|---|---|---|---|---|---|---|")
    for days in args.days:
        judged, n_buildings, began = [], 0, time.perf_counter()
        for k in range(args.scenes):
            run, buildings = district_run(k, days, args.signal_model, args.today, args.match)
            judged.append(run)
            n_buildings += buildings
        took = (time.perf_counter() - began) / args.scenes
        every = pd.concat(judged)
        n = len(every)
        rmse = float(np.sqrt(np.mean(every["span_error"] ** 2))) if n else float("nan")
        right = int((every["span_error"] <= RIGHT_WITHIN["gnss"]).sum())
        wrong = int((~every["meets"].astype(bool)).sum())
        print(
            f"| {days} | {n}/{n_buildings} ({n / n_buildings:.0%}) | {rmse:.2f} m | "
            f"{every['meets'].mean() if n else float('nan'):.0%} | {right} | "
            f"{wrong} ({wrong / max(n, 1):.0%}) | {took:.0f} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
