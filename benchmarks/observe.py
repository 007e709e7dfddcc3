"""Speed of ``observe`` on a long multi-GNSS log: parsing, and logs + orbits -> observations.

Synthesises a log of about 100,000 Raw rows (30 minutes at 1 Hz) by repeating the London log
of 2020-02-11 (Galaxy S10, GPS + GLONASS + BeiDou + Galileo, 280 epochs) with its clock and fix
times shifted by the log's length at each repetition, and moved as a whole to 2025-11-16, the
day of the complete multi-GNSS SP3 file in the shared data (no orbits of 2020-02-11 are
there). Prints the parse speed of :func:`~gnss_citygml.gnss.gnsslogger.read_gnsslogger` and
the time of the whole :func:`~gnss_citygml.gnss.observe.observe` stage.

    python benchmarks/observe.py [--rows 100000] [--data ../shared/data]
"""

from __future__ import annotations

import argparse
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np
from shared_data import SHARED_DATA

from gnss_citygml.gnss.gnsslogger import read_gnsslogger
from gnss_citygml.gnss.observe import observe

LONDON = "gnss/london_ucl_2020-02-11_SM-G973F_gnss_log.txt"
SP3 = "orbits/GFZ0MGXRAP_20253200000_01D_05M_ORB.SP3"
#: From the London log's day to the SP3 file's (same GPS - UTC, 18 s, on both days).
SHIFT_S = int(
    (np.datetime64("2025-11-16T10:00") - np.datetime64("2020-02-11T08:49")).item().total_seconds()
)


def synthesise(source: Path, rows: int, shift_s: int = SHIFT_S) -> str:
    """The text of a log with at least ``rows`` Raw rows: ``source`` repeated, times shifted
    by its length at each repetition and by ``shift_s`` in all."""
    lines = source.read_text().split("\n")
    header = [line for line in lines if line.startswith("#")]
    raw_commas = next(line for line in header if line.startswith("# Raw,")).count(",")
    # the Raw and Fix records, without the London log's cut-off last line
    records = [
        line
        for line in lines
        if line.startswith("Fix,") or (line.startswith("Raw,") and line.count(",") == raw_commas)
    ]
    raw_times = [int(r.split(",")[2]) for r in records if r.startswith("Raw,")]
    length_s = round((max(raw_times) - min(raw_times)) / 1e9) + 1
    n_raw = len(raw_times)
    out = list(header)
    for k in range((rows + n_raw - 1) // n_raw):
        step = k * length_s
        for record in records:
            fields = record.split(",")
            if fields[0] == "Raw":  # ElapsedRealtimeNanos, TimeNanos (FullBiasNanos: -shift)
                fields[1] = str(int(fields[1]) + step * 10**9)
                fields[2] = str(int(fields[2]) + step * 10**9)
                fields[5] = str(int(fields[5]) - shift_s * 10**9)
            else:  # Fix: (UTC)TimeInMs, ElapsedRealtimeNanos
                fields[7] = str(int(fields[7]) + (step + shift_s) * 1000)
                fields[8] = str(int(fields[8]) + step * 10**9)
            out.append(",".join(fields))
    return "\n".join(out) + "\n"


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rows", type=int, default=100_000, help="Raw rows to synthesise")
    parser.add_argument("--data", type=Path, default=SHARED_DATA, help="shared data folder")
    args = parser.parse_args()
    text = synthesise(args.data / LONDON, args.rows)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "long_gnss_log.txt"
        path.write_text(text)
        best = float("inf")
        for _ in range(3):
            start = time.perf_counter()
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                log = read_gnsslogger(path)
            best = min(best, time.perf_counter() - start)
        n = len(log.raw) + len(log.dropped)
        span = log.epochs[-1] - log.epochs[0]
        print(
            f"parse: {n} Raw rows ({len(log.raw)} kept), {len(log.epochs)} epochs over {span}, "
            f"{len(log.fixes)} fixes: {best:.2f} s (best of 3), {n / best:,.0f} rows/s"
        )
        start = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            obs = observe([path], [args.data / SP3])
        seconds = time.perf_counter() - start
    print(
        f"observe (parse + SP3 + sky + table): {len(obs)} signals "
        f"({int(obs['cn0'].notna().sum())} received) in {seconds:.2f} s, "
        f"{len(obs) / seconds:,.0f} signals/s"
    )


if __name__ == "__main__":
    main()
