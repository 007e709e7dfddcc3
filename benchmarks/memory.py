"""The resident memory of a benchmark's measured process while it runs a step (the peak of
the process's own RSS, sampled every 5 ms from /proc: ``ru_maxrss`` would also count the
imports' peak, which is not the step's)."""

from __future__ import annotations

import resource
import threading
import time
from collections.abc import Callable
from typing import Any


def rss_mb() -> float:
    """The process's resident memory now (MB), from /proc."""
    with open("/proc/self/statm") as statm:
        return int(statm.read().split()[1]) * resource.getpagesize() / 1e6


def peak_while(step: Callable[[], Any]) -> tuple[Any, float, float]:
    """``step()``'s result, its seconds and its peak resident memory (MB) over the
    process's memory before it."""
    base, peak, done = rss_mb(), [0.0], threading.Event()

    def sample():
        while not done.is_set():
            peak[0] = max(peak[0], rss_mb())
            time.sleep(0.005)

    sampler = threading.Thread(target=sample)
    sampler.start()
    start = time.perf_counter()
    try:
        result = step()
    finally:
        done.set()
        sampler.join()
    return result, time.perf_counter() - start, peak[0] - base
