"""Kill -9 at random moments during every writer: the previous output or a complete new one.

For each writer of ``tests/test_kill9.py`` (``estimate``, ``convert``, ``export``,
``observe``, ``simulate``, and the folder outputs ``tileset``, ``partition`` and ``tiles``, a
run's folder from ``estimate -o FOLDER --scheduler local``; with the same inputs and the same
checks), a complete run is timed, then ``--kills`` runs over the previous output are killed
with SIGKILL after delays drawn between 0 and that duration (one in each of N equal slices).
Printed per writer: how often the previous output was kept byte for byte, how often the new
one was complete and valid, how often a site was left mixed (some files previous, some new:
``simulate`` writes five), how often anything was broken (must be 0), and the hidden
temporary files the killed runs left (runs that left some, files in all; a folder output's
hidden folders count as files). Then two kills at chosen moments: as the output folder first
changes (the start of writing) and as the first output is replaced (a rename): what each
left, and how many temporary files.

    python benchmarks/kill9.py                     # 50 kills per writer
    python benchmarks/kill9.py --kills 10 --writers estimate observe
    python benchmarks/kill9.py --kills 10 --writers tileset partition tiles
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from test_kill9 import WRITERS, Trials, prepare_inputs  # noqa: E402

COLUMNS = (
    "writer",
    "run (s)",
    "kills",
    "ended first",
    "previous kept",
    "new complete",
    "mixed",
    "broken",
    "left temps",
    "temp files",
    "at writing",
    "at 1st rename",
)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--kills", type=int, default=50, help="Kills per writer.")
    parser.add_argument("--writers", nargs="+", choices=list(WRITERS), default=list(WRITERS))
    parser.add_argument("--seed", type=int, default=0, help="Seed of the delays.")
    args = parser.parse_args()
    rng = np.random.default_rng(args.seed)
    rows, broken = [], []
    start = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        prepare_inputs(folder / "inputs")
        for name in args.writers:
            trials = Trials(WRITERS[name], folder / name, folder / "inputs")
            kills = [trials.kill(delay) for delay in trials.delays(args.kills, rng)]
            chosen = [trials.kill_when_writing(replaced=replaced) for replaced in (False, True)]
            verdicts = [kill.verdict() for kill in kills]
            broken += [(name, kill) for kill in kills + chosen if kill.verdict() == "broken"]
            rows.append(
                (
                    name,
                    f"{trials.duration:.2f}",
                    len(kills),
                    sum(kill.ended for kill in kills),
                    verdicts.count("previous"),
                    verdicts.count("new"),
                    verdicts.count("mixed"),
                    verdicts.count("broken"),
                    sum(bool(kill.temps()) for kill in kills),
                    sum(len(kill.temps()) for kill in kills),
                    *(f"{kill.verdict()} +{len(kill.temps())}" for kill in chosen),
                )
            )
            print(f"{name}: {len(kills)} kills", file=sys.stderr, flush=True)
    widths = [max(len(str(v)) for v in column) for column in zip(COLUMNS, *rows, strict=True)]
    for row in (COLUMNS, *rows):
        print("  ".join(str(v).rjust(w) for v, w in zip(row, widths, strict=True)))
    for name, kill in broken:
        print(f"BROKEN {name} after {kill.delay:.2f} s: {kill.outputs}, left {kill.left}")
    print(f"({time.perf_counter() - start:.0f} s)")
    return 1 if broken else 0


if __name__ == "__main__":
    sys.exit(main())
