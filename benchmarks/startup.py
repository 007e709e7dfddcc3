"""How fast the command starts: the median wall time of ``gnss-citygml --version``, ``--help``
and ``estimate --help`` over N runs (each a fresh process, as a user's), beside a bare Python's
(on a busy machine both grow), and the slowest imports of each (``python -X importtime``). The
target is 0.3 s: the group imports no stage to list its commands, a subcommand only its own
module.

    python benchmarks/startup.py [--runs 10] [--top 8]
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import time
from pathlib import Path

COMMANDS = (["--version"], ["--help"], ["estimate", "--help"])
TARGET = 0.3  # s
#: The command line as :mod:`gnss_citygml.cli` runs it, for ``python -X importtime``.
RUN_CLI = "import sys; from gnss_citygml.cli import main; main(sys.argv[1:])"


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=10, help="runs per command (default 10)")
    parser.add_argument("--top", type=int, default=8, help="slowest imports shown (default 8)")
    args = parser.parse_args()
    script = Path(sys.executable).parent / "gnss-citygml"
    command = [str(script)] if script.exists() else [sys.executable, "-m", "gnss_citygml"]

    print(f"## Start-up of `gnss-citygml` (median of {args.runs} runs)\n")
    print("| command | median | min | over a bare Python | under 0.3 s |")
    print("|---|---|---|---|---|")
    bare = _times([sys.executable, "-c", "pass"], args.runs)
    print(f"| python -c pass | {_row(bare)} | | |")
    for extra in COMMANDS:
        times = _times([*command, *extra], args.runs)
        median = statistics.median(times)
        over = median - statistics.median(bare)
        verdict = "yes" if median < TARGET else "**no**"
        print(f"| gnss-citygml {' '.join(extra)} | {_row(times)} | {over:+.3f} s | {verdict} |")

    for extra in COMMANDS:
        print(f"\n### Slowest imports of `gnss-citygml {' '.join(extra)}` (-X importtime)\n")
        print("| module | self | cumulative |")
        print("|---|---|---|")
        for name, own, total in _imports(extra)[: args.top]:
            print(f"| {name} | {own / 1e3:.1f} ms | {total / 1e3:.1f} ms |")


def _times(argv: list[str], runs: int) -> list[float]:
    """Wall times (s) of ``runs`` runs of ``argv``, each of which must succeed."""
    times = []
    for _ in range(runs):
        start = time.perf_counter()
        subprocess.run(argv, check=True, stdout=subprocess.DEVNULL)
        times.append(time.perf_counter() - start)
    return times


def _row(times: list[float]) -> str:
    return f"{statistics.median(times):.3f} s | {min(times):.3f} s"


def _imports(extra: list[str]) -> list[tuple[str, int, int]]:
    """(module, self us, cumulative us) of every import of one run, slowest first by self."""
    argv = [sys.executable, "-X", "importtime", "-c", RUN_CLI, *extra]
    run = subprocess.run(argv, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    rows = []
    for line in run.stderr.decode().splitlines():
        if not line.startswith("import time:") or "self [us]" in line:
            continue
        own, total, name = line.removeprefix("import time:").split("|")
        rows.append((name.strip(), int(own), int(total)))
    return sorted(rows, key=lambda row: -row[1])


if __name__ == "__main__":
    main()
