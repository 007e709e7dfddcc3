"""A run cut into tiles on a Dask cluster (:class:`Tiling`): the tile sizes and the scheduler's
address it takes."""

from __future__ import annotations

import os
import re
from dataclasses import dataclass

from ..errors import InputError
from .checks import count, finite

#: Side of a tile of a run in tiles (m): the OS 1 km square.
DEFAULT_TILE_SIZE = 1000.0
#: The tile sizes a run takes (m): from a few buildings' width (a tile's work is its rays'
#: reach around it: smaller tiles only repeat it; see also
#: :func:`gnss_citygml.tiling.grid.check_reach`) to the OS 100 km square (a larger one has too
#: few tiles to share among workers).
TILE_SIZES = (50.0, 100_000.0)

#: The port a Dask scheduler listens on when not told otherwise (``dask scheduler --port``).
SCHEDULER_PORT = 8786

#: A Dask scheduler's address: ``tcp://`` (or ``tls://``), a host name or address (IPv6 in
#: brackets), and a port (default :data:`SCHEDULER_PORT`).
_SCHEDULER = re.compile(r"(tcp|tls)://(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9._-]+)(?::([0-9]{1,5}))?")


def scheduler_address(scheduler: str | None) -> tuple[str, str, int]:
    """The protocol, host and port of a Dask scheduler's address (``tcp://host:port``), or a
    one-line error naming it: Dask's own parsing lets ``tcp://`` or ``tcp://host:notaport``
    through to an internal error when connecting."""
    match = _SCHEDULER.fullmatch(scheduler) if isinstance(scheduler, str) else None
    port = int(match.group(3) or SCHEDULER_PORT) if match else 0
    if match is None or not 1 <= port <= 65535:
        raise InputError(
            f"unknown scheduler {scheduler!r}",
            fix="give --scheduler local, or the address of a running Dask scheduler, "
            "tcp://HOST:PORT, as `dask scheduler` prints it (e.g. tcp://192.168.1.5:8786)",
        )
    return match.group(1), match.group(2).strip("[]"), port


def check_tile_size(size: float) -> None:
    """Refuse a tile size that is not a whole number of metres (tiles are named by their
    south-west corner to the metre) within :data:`TILE_SIZES`."""
    low, high = TILE_SIZES
    if not (finite(size) and low <= size <= high and float(size).is_integer()):
        raise InputError(
            f"a tile size must be a whole number of metres from {low:g} to {high:,.0f}, "
            f"not {size!r}",
            fix="give --tile-size in metres, e.g. 1000",
        )


#: A local cluster's worker processes per core, at most: each holds a tile's rows and its own
#: Python; more processes than that only share the cores and multiply the memory.
WORKERS_PER_CORE = 4


@dataclass(frozen=True)
class Tiling:
    """A run cut into square tiles of British National Grid on a Dask cluster
    (:mod:`gnss_citygml.tiling.run`, the ``[dask]`` extra), with the single process's heights.

    Parameters
    ----------
    scheduler
        ``None`` (default): one process, no tiles. ``"local"``: a Dask ``LocalCluster`` on
        this machine. ``"tcp://host:port"``: a running Dask scheduler and its workers.
    workers
        With ``"local"``: how many worker processes (default: one per core).
    size
        Side of a tile (m, whole metres, :data:`TILE_SIZES`). ``None`` (default):
        :data:`DEFAULT_TILE_SIZE`, the OS 1 km square (tiles are named by OS grid reference,
        ``TQ2982``), or a partition's own.
    """

    scheduler: str | None = None
    workers: int | None = None
    size: float | None = None

    def __post_init__(self):
        if self.scheduler not in (None, "local"):
            scheduler_address(self.scheduler)
        if self.workers is not None and (self.scheduler != "local" or not count(self.workers)):
            raise InputError(
                f"--workers {self.workers} is for --scheduler local, a whole number 1 or more",
                fix="leave it out: a running scheduler has its own workers",
            )
        most = WORKERS_PER_CORE * (os.cpu_count() or 1)
        if self.workers is not None and int(self.workers) > most:
            raise InputError(
                f"--workers {self.workers}: a local cluster runs at most {WORKERS_PER_CORE} "
                f"worker processes per core, {most} on this machine",
                fix="give fewer (leave it out for one per core), or a scheduler of several "
                "machines (--scheduler tcp://host:port)",
            )
        if self.size is not None:
            check_tile_size(self.size)
        if self.scheduler is None and self.size is not None:
            raise InputError(
                "a tile size is for a run on a Dask scheduler",
                fix="give --scheduler local (or tcp://host:port) too, or leave out --tile-size",
            )

    @property
    def on(self) -> bool:
        """Whether the run is cut into tiles on a Dask cluster."""
        return self.scheduler is not None

    @property
    def side(self) -> float:
        """The tile size of a run from observations in memory (a partition has its own)."""
        return DEFAULT_TILE_SIZE if self.size is None else float(self.size)
