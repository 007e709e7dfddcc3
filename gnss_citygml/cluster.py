"""Dask, the engine of a run in tiles on many cores or machines (the ``[dask]`` extra).

:func:`connect` gives a :class:`DaskEngine` on a new ``LocalCluster`` (``local``: one worker
process per core, or ``workers``) or on a running scheduler (``tcp://host:port``), as a
:class:`~gnss_citygml.settings.Tiling` says.
Each step of :func:`~gnss_citygml.model.fourplb.run_parts` becomes a Dask task whose result
stays on the worker that made it; a step that fails is run once more, and a worker that dies
takes its results with it, which Dask recomputes from the steps that made them, with the same
result. The core package does not import Dask: only this module does, when it is asked for.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from typing import Any

from .errors import InputError, escape_controls, first_line
from .settings import Tiling

__all__ = ["DaskEngine", "connect"]

#: Times Dask runs a failed task again before it reports it.
RETRIES = 1

#: Seconds to wait for a scheduler to answer.
CONNECT_TIMEOUT = 30.0

#: glibc's allocator settings for the workers. Dask's default trim threshold (64 kB) also
#: freezes glibc's mmap threshold at 128 kB, so every temporary array of the fits (blocks of
#: 65,536 rows, 512 kB) is mapped and unmapped, page faults and all: the fits ran 2.3x
#: slower on a worker than in one process (benchmarks/dask_tiles.py). Temporaries up to
#: 64 MB come from the heap, which keeps up to 256 MB free for the next ones.
WORKER_MALLOC = {
    "MALLOC_MMAP_THRESHOLD_": 64 << 20,
    "MALLOC_TRIM_THRESHOLD_": 256 << 20,
}


class DaskEngine:
    """An :class:`~gnss_citygml.model.fourplb.Engine` on a ``dask.distributed.Client``."""

    def __init__(self, client: Any) -> None:
        self.client = client

    def submit(self, func: Callable[..., Any], *args: Any, key: str | None = None) -> Any:
        """A future of ``func(*args)`` (``args`` may be futures), run once more if it fails.

        Data given as it is (a tile's receivers) travel with the task, not scattered ahead:
        the scheduler keeps them, so a tile whose worker died can be cast again. Dask's
        warning about such large tasks is therefore left out."""
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", "Sending large graph", UserWarning)
            return self.client.submit(func, *args, key=key, retries=RETRIES, pure=key is None)

    def gather(self, futures: Any) -> Any:
        """The futures' values, here."""
        return self.client.gather(futures)

    def failures(self, futures: Sequence[Any]) -> dict[int, str]:
        """Which of ``futures`` failed (after their retry), with why: waits for all of them."""
        from distributed import wait

        wait(list(futures))
        return {
            k: f"{type(f.exception()).__name__}: {escape_controls(first_line(f.exception()))}"
            for k, f in enumerate(futures)
            if f.status == "error"
        }


@contextmanager
def connect(tiling: Tiling) -> Iterator[DaskEngine]:
    """A :class:`DaskEngine` for the length of a ``with`` block, on ``tiling.scheduler``: a
    new ``LocalCluster`` of ``tiling.workers`` processes of one thread each (``local``;
    default: one per core), or the Dask scheduler at that address (its workers are its own).
    """
    try:
        import dask
        from distributed import Client, LocalCluster
    except ImportError as err:
        raise InputError(
            "a run on a Dask scheduler needs Dask, which is not installed",
            fix="pip install 'gnss-citygml[dask]'",
        ) from err
    if tiling.scheduler == "local":
        environ = {**dask.config.get("distributed.nanny.pre-spawn-environ"), **WORKER_MALLOC}
        with dask.config.set({"distributed.nanny.pre-spawn-environ": environ}):
            cluster = LocalCluster(
                n_workers=tiling.workers,
                threads_per_worker=1,
                processes=True,
                dashboard_address=":0",  # any free port: two clusters on one machine do not clash
            )
        with cluster, Client(cluster) as client:
            yield DaskEngine(client)
        return
    try:
        client = Client(tiling.scheduler, timeout=CONNECT_TIMEOUT)
    except OSError as err:
        raise InputError(
            f"cannot reach the Dask scheduler at {tiling.scheduler}: {err}",
            fix="start it (dask scheduler) or check the address",
        ) from err
    with client:
        yield DaskEngine(client)
