"""How many position errors a roof line rests on, and how often such an answer is wrong.

A recording is a set of rows that share one position error (a receiver's stay, a 50 m stretch
of a walk: :func:`gnss_citygml.pipeline.recordings`). A roof line seen through one recording's
rays only may be that recording's own error: its rays moved across a building they missed, or
through another that blocked them. This counts, per regime and positions, the converged
buildings by the number of recordings among their rows within the roof line's transition
(``|height - c| <= 1.5/b + height_sd``, the rows :func:`~gnss_citygml.model.fourplb.
position_margin` weighs; 0: the roof line sits in a gap of the rays), with their right answers
(within 1 m of the roof span with hand-placed points, 2 m with phone fixes) and wrong ones (the
range missing the span); then what refusing the roof lines of fewer than K recordings would
leave (issue 47, item 3). One initial threshold (30 dB-Hz), the positions' errors as the data
say (:func:`accuracy.position_error`), no open sky.

    python roof_recordings.py [--scenes 30] [--labels los|cn0]
"""

from __future__ import annotations

import argparse

import numpy as np
import pandas as pd
from accuracy import judge, labelled, position_error, site_tables
from scenes import REGIMES, RIGHT_WITHIN, random_physics, regime_scene

from gnss_citygml import Estimator, estimate_heights
from gnss_citygml.simulate import LOCATIONS, simulate

#: The streets' regimes (the walked district is issue 48's).
STREETS = tuple(r for r in REGIMES if r != "district")


def roof_recordings(sim, locations: str, labels: str) -> pd.DataFrame:
    """The converged buildings of one simulated scene: their recordings near the roof line,
    whether the answer is right and whether it is wrong."""
    _, _, cast = site_tables(sim, position_error=position_error("data", locations, None, None))
    estimator = Estimator(init_threshold=30.0, level_phones=False)
    heights = estimate_heights(labelled(sim, cast, labels), estimator)
    judged = judge(heights, sim.truth)  # the converged ones, by id
    fit = heights.set_index("id").reindex(cast["building"].astype(str).to_numpy())
    near = np.abs(cast["height"].to_numpy() - fit["c"].to_numpy()) <= (
        1.5 / fit["b"].to_numpy() + cast["height_sd"].to_numpy()
    )
    rows = cast.loc[near, ["building", "recording"]].astype(str)
    counts = rows.drop_duplicates().groupby("building").size()
    return pd.DataFrame(
        {
            "recordings": counts.reindex(judged.index, fill_value=0).to_numpy(),
            "right": (judged["span_error"] <= RIGHT_WITHIN[locations]).to_numpy(),
            "wrong": ~judged["meets"].astype(bool).to_numpy(),
        }
    )


def _cells(table: pd.DataFrame) -> str:
    n, right, wrong = len(table), int(table["right"].sum()), int(table["wrong"].sum())
    return f"{n}, {right}, {wrong} ({wrong / max(n, 1):.0%})"


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=30)
    parser.add_argument("--labels", choices=("los", "cn0"), default="los")
    args = parser.parse_args()
    judged = []
    for k in range(args.scenes):
        for regime in STREETS:
            scene, start, _ = regime_scene(k, regime)
            physics = random_physics(k)
            for locations in LOCATIONS:
                sim = simulate(scene, locations=locations, seed=k, start=start, physics=physics)
                found = roof_recordings(sim, locations, args.labels)
                judged.append(found.assign(regime=regime, locations=locations))
        print(f"scene {k} done", flush=True)
    every = pd.concat(judged)
    every["bucket"] = every["recordings"].clip(upper=4).map(lambda r: "4+" if r == 4 else str(r))
    buckets = ["0", "1", "2", "3", "4+"]
    print(f"\nLabels {args.labels}; cells: answers, right, wrong (share of the answers).\n")
    print("| regime, positions | " + " | ".join(f"{b} recordings" for b in buckets) + " |")
    print("|---" * (1 + len(buckets)) + "|")
    for (regime, locations), group in every.groupby(["regime", "locations"], sort=False):
        by = dict(iter(group.groupby("bucket")))
        cells = [_cells(by[b]) if b in by else "-" for b in buckets]
        print(f"| {regime}, {locations} | " + " | ".join(cells) + " |")
    print("\nRefusing a roof line resting on fewer than K recordings (a gap's kept):\n")
    print("| regime, positions | all | K = 2 | K = 3 |")
    print("|---|---|---|---|")
    for (regime, locations), group in every.groupby(["regime", "locations"], sort=False):
        r = group["recordings"]
        kept = [group[(r >= k) | (r == 0)] for k in (1, 2, 3)]
        print(f"| {regime}, {locations} | " + " | ".join(_cells(t) for t in kept) + " |")


if __name__ == "__main__":
    main()
