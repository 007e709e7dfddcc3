"""Work on many groups' samples in threads, a run of whole groups each.

A 4PL fit and its likelihood interval treat every group on its own, to the same bits whatever
groups surround it (:mod:`.likelihood`), so cutting the samples (sorted by group) into runs of
whole groups and working on the runs in threads (:mod:`gnss_citygml.threads`) gives one
pass's bits.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ..threads import in_threads, threads

__all__ = ["by_groups"]

#: Samples per run below which threads cost more than they save (a few milliseconds of work).
MIN_ROWS = 1 << 16
#: Runs per thread: a few slow groups (hundreds of Levenberg-Marquardt steps) in one run should
#: not leave the other threads idle, and each run costs its own Python steps.
RUNS_PER_THREAD = 2


def by_groups(
    g: np.ndarray,
    n_groups: int,
    work: Callable[[slice, slice], tuple[np.ndarray, ...]],
) -> tuple[np.ndarray, ...]:
    """``work(rows, groups)`` of runs of whole groups (``g``: each sample's group, sorted;
    ``rows`` a run's samples, ``groups`` its groups, empty ones included), in threads, and its
    per-group arrays joined in the groups' order: what ``work`` of all samples and groups
    would give."""
    n_threads = min(threads(), g.size // MIN_ROWS)
    if n_threads <= 1:
        return work(slice(0, g.size), slice(0, n_groups))
    # cut at the first sample of a group near each even share of the samples
    shares = np.linspace(0, g.size, n_threads * RUNS_PER_THREAD + 1)[1:-1].astype(np.intp)
    cuts = np.unique(np.r_[0, g[shares], n_groups])
    rows = np.searchsorted(g, cuts)
    runs = [
        (slice(rows[k], rows[k + 1]), slice(cuts[k], cuts[k + 1])) for k in range(cuts.size - 1)
    ]
    parts = in_threads(lambda run: work(*run), runs, n_threads)
    return tuple(np.concatenate(arrays) for arrays in zip(*parts, strict=True))
