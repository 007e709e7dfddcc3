"""Which side of the street the errors fall on (issue 28, item 3): the runs ``scenes.py --save``
wrote, per regime, locations and row of buildings.

In ``scenes.py --regimes``'s streets the receivers walk or stand nearer the south row
(:func:`~gnss_citygml.simulate.scenes.street_scene`), so a bias that every phone shares (a
fix pushed across the street by the reflections there) shows as an error of one sign on one
row, which no number of recordings averages away; an error of each recording's own averages
out and leaves both rows alike.

    python benchmarks/scenes.py --regimes --scenes 30 --phones each --save runs.csv
    python benchmarks/sides.py runs.csv

With ``--fixes N`` it prints the phone fixes' own errors in the first N scenes of each street
regime instead (``scenes.py --regimes --phones each``'s, by the simulator's truth): across the
street (north) and along it (east), their mean, and what the phones claim.

    python benchmarks/sides.py --fixes 10
"""

from __future__ import annotations

import argparse

import numpy as np
import pandas as pd

#: The rows of a street scene, by the letter after ``street_`` in a building's id.
ROWS = {"n": "north (across the street)", "s": "south (the receivers' side)"}


def side_table(runs: pd.DataFrame) -> pd.DataFrame:
    """Per group and row: converged runs, the mean and median signed error to the true height
    (m), the RMSE to the roof span, the share of ranges meeting it, and the mean signed error of
    the runs whose range misses it."""
    row = runs["id"].str.extract(r"^street_([ns])\d", expand=False).map(ROWS).fillna("other")
    runs = runs.assign(row=row, missed=np.where(runs["meets"], np.nan, runs["error"]))
    return runs.groupby(["group", "row"]).agg(
        runs=("error", "size"),
        mean_error=("error", "mean"),
        median_error=("error", "median"),
        rmse_to_span=("span_error", lambda e: float(np.sqrt(np.mean(e**2)))),
        meets_span=("meets", "mean"),
        mean_error_missed=("missed", "mean"),
    )


def fix_errors(regime: str, n_scenes: int) -> dict[str, float]:
    """The phone fixes' errors (m) in the first ``n_scenes`` scenes of ``regime``, each fix
    once: RMS across (north) and along (east) the street, the mean across (positive: towards
    the north row), the share of scenes and of recordings whose mean is north, and the mean
    claimed error (``position_sd``, per axis)."""
    from scenes import phones, random_physics, regime_scene

    from gnss_citygml.simulate import simulate

    rows = []
    for k in range(n_scenes):
        scene, start, _ = regime_scene(k, regime)
        physics = phones(k, random_physics(k), len(scene.sessions))
        sim = simulate(scene, locations="gnss", seed=k, start=start, physics=physics)
        fixes = sim.observations.drop_duplicates(["receiver", "time_utc"])
        north = fixes["n"] - fixes["n_true"]
        east = (fixes["e"] - fixes["e_true"]).to_numpy()
        by_recording = north.groupby(fixes["receiver"]).mean()
        rows.append(
            [
                np.sqrt(np.mean(north**2)),
                np.sqrt(np.mean(east**2)),
                north.mean(),
                (by_recording > 0).mean(),
                fixes["position_sd"].mean(),
            ]
        )
    r = np.array(rows)
    return {
        "rms_across": r[:, 0].mean(),
        "rms_along": r[:, 1].mean(),
        "mean_across": r[:, 2].mean(),
        "scenes_north": (r[:, 2] > 0).mean(),
        "recordings_north": r[:, 3].mean(),
        "claimed": r[:, 4].mean(),
    }


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="?", help="a CSV written by scenes.py --save")
    parser.add_argument("--fixes", type=int, help="the fixes' own errors in this many scenes")
    args = parser.parse_args()
    if args.fixes:
        print(
            "| regime | RMS across | RMS along | claimed | mean across | scenes north | "
            "recordings north |"
        )
        print("|---" * 7 + "|")
        for regime in ("street", "narrow street", "square"):
            f = fix_errors(regime, args.fixes)
            print(
                f"| {regime} | {f['rms_across']:.2f} m | {f['rms_along']:.2f} m | "
                f"{f['claimed']:.2f} m | {f['mean_across']:+.2f} m | {f['scenes_north']:.0%} | "
                f"{f['recordings_north']:.0%} |"
            )
        return
    if not args.runs:
        parser.error("give a CSV written by scenes.py --save, or --fixes N")
    table = side_table(pd.read_csv(args.runs))
    print(
        "| regime, locations | row | runs | mean error | median error | RMSE to span | "
        "range meets span | mean error of the ranges missing it |"
    )
    print("|---" * 8 + "|")
    for (group, row), r in table.iterrows():
        missed = "-" if np.isnan(r.mean_error_missed) else f"{r.mean_error_missed:+.2f} m"
        print(
            f"| {group} | {row} | {r.runs:.0f} | {r.mean_error:+.2f} m | {r.median_error:+.2f} m "
            f"| {r.rmse_to_span:.2f} m | {r.meets_span:.0%} | {missed} |"
        )


if __name__ == "__main__":
    main()
