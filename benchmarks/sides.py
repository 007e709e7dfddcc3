"""Which side of the street the errors fall on (issue 28, item 3): the runs ``scenes.py --save``
wrote, per regime, locations and row of buildings.

In ``scenes.py --regimes``'s streets the receivers walk or stand nearer the south row
(:func:`~gnss_citygml.simulate.scenes.street_scene`), so a bias that every phone shares (a
fix pushed across the street by the reflections there) shows as an error of one sign on one
row, which no number of recordings averages away; an error of each recording's own averages
out and leaves both rows alike.

    python benchmarks/scenes.py --regimes --scenes 30 --phones each --save runs.csv
    python benchmarks/sides.py runs.csv
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


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", help="a CSV written by scenes.py --save")
    table = side_table(pd.read_csv(parser.parse_args().runs))
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
