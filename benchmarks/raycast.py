"""Cast + fit at city scale: 1,000,000 signals x 10,000 buildings through the pipeline.

Simulates a 100 x 100 block city (6 km square, one building per block) walked by people with
phones until about a million signals are observed, writes it as the files a user brings
(observations, footprints GeoPackage, DEM GeoTIFF; cached in benchmarks/out/), then runs the
pipeline's stages on them in a fresh process and prints the time of each stage, signals per
second and the peak memory (RSS) of that process.

    python benchmarks/raycast.py [--signals 1000000] [--blocks 100] [--grid-dir DIR]
                                 [--signal-model paper|mixture] [--no-level-phones]
                                 [--locations gnss [--calibrate shadows [--rounds 3]]]

With ``--locations gnss`` the walkers' positions are their phones' fixes; ``--calibrate
shadows`` self-calibrates them first by shadow matching (10 s windows, ``--rounds`` rounds
with the heights, default one, each window's prior its fixes' own error) and times it.

``--against REV`` measures side by side: the same process with the package of git revision
REV (``git archive``, in a temporary folder) and with this tree's, alternately ``--repeat``
times each, then prints each stage's best time of each, the speed-up, the peak memory, and
whether the two give the same intersections (a hash of the table) and the same heights
(``DataFrame.equals``; else the largest difference of the heights both give).

    python benchmarks/raycast.py --against d079ccf [--repeat 2]

Targets (issue 4): cast + fit <= 60 s on a 2-core machine, peak memory <= 2 GB; (issue 28)
with shadow matching, within 3 times the run without it, peak memory <= 3 GB.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from shared_data import GRIDS

OUT = Path(__file__).parent / "out"
#: Signals per walker: 300 s at 1 Hz with about 30 satellites in view.
SIGNALS_PER_WALKER = 9000


def prepare(folder: Path, signals: int, blocks: int, grid_dir, locations: str) -> None:
    from gnss_citygml.simulate import simulate
    from gnss_citygml.simulate.files import write_site
    from gnss_citygml.simulate.scenes import city_scene

    walkers = max(1, round(signals / SIGNALS_PER_WALKER))
    scene = city_scene(np.random.default_rng(0), blocks, blocks, walkers=walkers, walk_length=300.0)
    start = time.perf_counter()
    sim = simulate(scene, seed=0, interval=1.0, locations=locations)
    write_site(sim, folder, grid_dir=grid_dir)
    print(
        f"simulated {len(sim.observations):,} signals, {len(scene.buildings):,} buildings, "
        f"{walkers} walkers in {time.perf_counter() - start:.0f} s -> {folder}"
    )


def run(folder: Path, grid_dir, estimator_options: dict, calibrate, save, crossing, rounds=1):
    import pandas as pd

    from gnss_citygml.calibrate import calibrate_receivers
    from gnss_citygml.footprints import read_footprints
    from gnss_citygml.model.estimate import estimate_heights
    from gnss_citygml.observations import read_observations
    from gnss_citygml.pipeline import intersections, open_sky, receivers
    from gnss_citygml.settings import Calibration, Estimator, PositionError
    from gnss_citygml.terrain import building_ground

    times = {}

    def timed(name, func, *args, **kwargs):
        start = time.perf_counter()
        result = func(*args, **kwargs)
        times[name] = time.perf_counter() - start
        return result

    obs = timed("read observations", read_observations, folder / "observations.parquet")
    fp = timed("read footprints", read_footprints, folder / "footprints.gpkg")
    dem = str(folder / "dem.tif")
    rx = timed("receivers (geodesy + DEM)", receivers, obs, dem, grid_dir=grid_dir)
    fp = timed("ground under buildings", building_ground, fp, dem)
    estimator = Estimator(**estimator_options)
    if calibrate is not None:
        calibration = Calibration(prior_sd=5.0, window=10.0, rounds=rounds, matching=calibrate)
        rx = timed(
            f"calibrate ({calibrate})",
            calibrate_receivers,
            rx,
            fp,
            calibration,
            estimator=estimator,
        )
    inter = timed("cast", intersections, rx, fp, position_error=PositionError(crossing=crossing))
    heights = timed(
        "fit (4PL-B)",
        lambda: estimate_heights(inter, estimator, open_sky=open_sky(rx, inter)),
    )
    peak_gb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024**2
    if save is not None:  # for --against: the figures, a hash of the intersections, the heights
        digest = int(pd.util.hash_pandas_object(inter, index=False).sum())
        figures = {"times": times, "peak_gb": peak_gb, "intersections": digest}
        (save / "figures.json").write_text(json.dumps(figures))
        heights.to_parquet(save / "heights.parquet")
    for name, seconds in times.items():
        print(f"  {name:28s} {seconds:7.2f} s")
    cast_fit = times["cast"] + times["fit (4PL-B)"] + times.get(f"calibrate ({calibrate})", 0.0)
    print(
        f"{len(obs):,} signals x {len(fp):,} buildings: {len(inter):,} intersections, "
        f"{int(heights['converged'].sum()):,} heights; "
        f"{'calibrate + ' if calibrate else ''}cast + fit {cast_fit:.1f} s "
        f"({len(obs) / cast_fit:,.0f} signals/s), all stages {sum(times.values()):.1f} s, "
        f"peak memory {peak_gb:.2f} GB"
    )


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--signals", type=int, default=1_000_000)
    parser.add_argument("--blocks", type=int, default=100, help="blocks per side")
    parser.add_argument("--grid-dir", type=Path, default=GRIDS)
    parser.add_argument("--signal-model", default="paper", help="paper or mixture")
    parser.add_argument(
        "--no-level-phones", action="store_true", help="the C/N0 as recorded (before issue 28)"
    )
    parser.add_argument(
        "--blame", choices=("ray", "drop"), help="Estimator.blame (default: the estimator's)"
    )
    parser.add_argument(
        "--crossing",
        action="store_true",
        help="PositionError(crossing=True): each row's chance of crossing, near misses cast",
    )
    parser.add_argument("--locations", choices=("manual", "gnss"), default="manual")
    parser.add_argument("--calibrate", choices=("shadows", "roof lines"))
    parser.add_argument("--rounds", type=int, default=1, help="with --calibrate: its rounds")
    parser.add_argument("--against", metavar="REV", help="side by side with git revision REV")
    parser.add_argument("--repeat", type=int, default=1, help="runs of each with --against")
    parser.add_argument("--run", type=Path, help=argparse.SUPPRESS)  # the measured process
    parser.add_argument("--save", type=Path, help=argparse.SUPPRESS)  # its results, for --against
    args = parser.parse_args()
    if args.run:
        options = {"signal_model": args.signal_model, "level_phones": not args.no_level_phones}
        options |= {} if args.blame is None else {"blame": args.blame}
        run(args.run, args.grid_dir, options, args.calibrate, args.save, args.crossing, args.rounds)
        return
    folder = OUT / f"city_{args.blocks}x{args.blocks}_{args.signals}"
    if args.locations != "manual":
        folder = folder.with_name(f"{folder.name}_{args.locations}")
    if not (folder / "dem.tif").exists():
        prepare(folder, args.signals, args.blocks, args.grid_dir, args.locations)
    command = [sys.executable, __file__, "--run", str(folder), "--grid-dir", str(args.grid_dir)]
    command += ["--signal-model", args.signal_model]
    command += (
        ["--calibrate", args.calibrate, "--rounds", str(args.rounds)] if args.calibrate else []
    )
    command += ["--no-level-phones"] if args.no_level_phones else []
    command += ["--blame", args.blame] if args.blame else []
    command += ["--crossing"] if args.crossing else []
    if args.against:
        side_by_side(command, args.against, args.repeat)
    else:
        subprocess.run(command, check=True)


def side_by_side(command: list[str], revision: str, repeat: int) -> None:
    """The measured process at ``revision``'s package and at this tree's, alternately."""
    import pandas as pd

    repo = Path(__file__).resolve().parents[1]
    with tempfile.TemporaryDirectory(prefix="raycast-") as tmp:
        old = Path(tmp) / "old"
        old.mkdir()
        archive = subprocess.run(
            ["git", "-C", str(repo), "archive", revision, "gnss_citygml"],
            check=True,
            capture_output=True,
        ).stdout
        subprocess.run(["tar", "-x", "-C", str(old)], input=archive, check=True)
        trees = {revision: old, "this tree": repo}
        runs: dict[str, list[dict]] = {name: [] for name in trees}
        for k in range(repeat):
            for name, tree in trees.items():
                save = Path(tmp) / f"{name.replace(' ', '_')}-{k}"
                save.mkdir()
                print(f"--- {name} ({tree}), run {k + 1} of {repeat}", flush=True)
                env = {**os.environ, "PYTHONPATH": str(tree)}
                subprocess.run([*command, "--save", str(save)], check=True, env=env)
                runs[name].append(json.loads((save / "figures.json").read_text()))
                runs[name][-1]["heights"] = pd.read_parquet(save / "heights.parquet")
        _print_side_by_side(runs, revision)


def _print_side_by_side(runs: dict[str, list[dict]], revision: str) -> None:
    old, new = runs[revision], runs["this tree"]
    stages = list(new[0]["times"])
    best = {name: {s: min(r["times"][s] for r in rs) for s in stages} for name, rs in runs.items()}
    print(f"\nbest of {len(new)} (s)            {revision:>12s} {'this tree':>12s} speed-up")
    for stage in [*stages, "cast + fit"]:
        if stage == "cast + fit":
            a, b = (sum(best[n][s] for s in ("cast", "fit (4PL-B)")) for n in runs)
        else:
            a, b = best[revision][stage], best["this tree"][stage]
        print(f"  {stage:28s} {a:12.2f} {b:12.2f} {a / b:7.2f}x")
    peaks = [max(r["peak_gb"] for r in rs) for rs in (old, new)]
    print(f"  {'peak memory (GB)':28s} {peaks[0]:12.2f} {peaks[1]:12.2f}")
    same_cast = {r["intersections"] for r in old} == {r["intersections"] for r in new}
    h_old, h_new = old[0]["heights"], new[0]["heights"]
    same = h_old.equals(h_new)
    print(f"intersections identical: {same_cast}; heights identical: {same}")
    if not same:
        both = h_old["converged"].to_numpy() & h_new["converged"].to_numpy()
        diff = (h_old["height"] - h_new["height"]).abs().to_numpy()[both]
        print(
            f"  converged {int(h_old['converged'].sum())} -> {int(h_new['converged'].sum())}; "
            f"largest height difference where both converged {diff.max(initial=0):.6f} m"
        )


if __name__ == "__main__":
    main()
