"""How many threads a step may use, and a step's independent pieces run in them.

The cast's batches of rays and the fits' runs of whole groups are independent pieces whose
results, joined in order, are one pass's bits. numpy's array functions, shapely's and the
compiled likelihood sums release the GIL, so threads let a laptop's cores share such a step.

Threads follow ``OMP_NUM_THREADS`` where it is set, as numerical libraries do: a Dask worker's
nanny sets it to 1, the workers' processes being the parallelism there.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

__all__ = ["in_threads", "threads"]

_Piece = TypeVar("_Piece")
_Result = TypeVar("_Result")


def threads() -> int:
    """The threads a step may use: ``OMP_NUM_THREADS`` where it is a positive whole number,
    else the cores this process may run on."""
    value = os.environ.get("OMP_NUM_THREADS", "").strip()
    if value.isdigit() and int(value) > 0:
        return int(value)
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def in_threads(
    work: Callable[[_Piece], _Result], pieces: Iterable[_Piece], n_threads: int
) -> list[_Result]:
    """``work`` of each piece, in order, in ``n_threads`` threads (in this one where 1)."""
    if n_threads <= 1:
        return [work(piece) for piece in pieces]
    with ThreadPoolExecutor(n_threads) as pool:
        return list(pool.map(work, pieces))
