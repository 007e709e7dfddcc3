"""An incremental update of a 10,000-building map with 1 % new data, against a full run.

The city of benchmarks/raycast.py (100 x 100 blocks, about a million signals; simulated once
and cached in benchmarks/out/). Its last 1 % of epochs are the new data: the map is first
updated with the other 99 %, then with the 1 %, and that second update is timed stage by stage
against one full run (`estimate`) over all of the observations. The two results are compared.

    python benchmarks/update.py [--grid-dir DIR]
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pyogrio
from raycast import OUT, prepare
from shared_data import GRIDS

from gnss_citygml.jobs import estimate_file
from gnss_citygml.update import update_map


def timed_stages() -> tuple[dict[str, float], object]:
    """A progress callback that records when each stage starts."""
    marks: dict[str, float] = {}

    def told(what: str, done: float) -> None:
        marks[what] = time.perf_counter()

    return marks, told


def lap(marks: dict[str, float], end: float) -> str:
    names = list(marks)
    times = [*marks.values(), end]
    return ", ".join(f"{n} {b - a:.1f} s" for n, a, b in zip(names, times, times[1:], strict=False))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--grid-dir", type=Path, default=GRIDS)
    args = parser.parse_args()
    grid_dir = args.grid_dir if args.grid_dir and args.grid_dir.exists() else None
    folder = OUT / "city_100x100_1000000"
    if not folder.exists():
        prepare(folder, 1_000_000, 100, grid_dir)
    obs = pd.read_parquet(folder / "observations.parquet")
    epochs = np.sort(obs["time_utc"].unique())
    cut = epochs[int(len(epochs) * 0.99)]
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        base, new = work / "base.parquet", work / "new.parquet"
        obs[obs["time_utc"] < cut].to_parquet(base)
        obs[obs["time_utc"] >= cut].to_parquet(new)
        n_new = int((obs["time_utc"] >= cut).sum())
        the_map = work / "map.gpkg"
        shutil.copy(folder / "footprints.gpkg", the_map)
        dem = str(folder / "dem.tif")
        start = time.perf_counter()
        update_map(the_map, [base], dem, grid_dir=grid_dir, backup=False)
        first = time.perf_counter() - start
        marks, told = timed_stages()
        start = time.perf_counter()
        result = update_map(the_map, [new], dem, grid_dir=grid_dir, backup=False, progress=told)
        incremental = time.perf_counter() - start
        stages = lap(marks, start + incremental)
        marks, told = timed_stages()
        start = time.perf_counter()
        full = estimate_file(
            folder / "observations.parquet",
            folder / "footprints.gpkg",
            dem,
            work / "full.gpkg",
            grid_dir=grid_dir,
            progress=told,
        )
        whole = time.perf_counter() - start
        full_stages = lap(marks, start + whole)
        ours = pyogrio.read_dataframe(the_map, layer="footprints", read_geometry=False)
        ours = ours.set_index("id")
        theirs = full.heights.set_index("id").loc[ours.index]
        size = the_map.stat().st_size / 1e6
    mine = ours["converged"].astype("boolean").fillna(False).astype(bool)  # (no signal: NULL)
    same = (mine == theirs["converged"].astype(bool)).all()
    gap = np.nanmax(np.abs(ours["height_gnss"].to_numpy() - theirs["height"].to_numpy()))
    print(
        f"map of {len(ours):,} buildings, {len(obs):,} signals; new data: the last 1 % of "
        f"epochs, {n_new:,} signals"
    )
    print(f"  first update (99 %, from nothing)   {first:6.1f} s")
    print(f"  incremental update (1 % new)        {incremental:6.1f} s  ({stages})")
    print(f"  full run over all the observations  {whole:6.1f} s  ({full_stages})")
    updated = set(result.updated["id"])
    untouched = updated - result.touched
    table = result.buildings[result.buildings["id"].isin(untouched)]
    moved = (table["after"] - table["before"]).abs()
    newly = int((table["before"].isna() != table["after"].isna()).sum())
    print(
        f"  incremental / full: {incremental / whole:.2f}; same converged set: {same}; largest "
        f"height difference {gap:.2e} m; map with its evidence {size:.0f} MB"
    )
    print(
        f"  {len(result.touched):,} buildings touched by the new signals; {len(updated):,} "
        f"changed, {len(untouched):,} of them untouched by any new signal (what refitting only "
        f"the touched ones would have missed, the co-trained classifier having moved): heights "
        f"moved by up to {moved.max():.2f} m (median {moved.median():.2f} m), {newly} gained or "
        "lost a height"
    )


if __name__ == "__main__":
    main()
