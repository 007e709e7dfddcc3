"""Dask, the engine of a run in tiles on many cores or machines (the ``[dask]`` extra).

:func:`connect` gives a :class:`DaskEngine` on a new ``LocalCluster`` (``local``: one worker
process per core, or ``workers``) or on a running scheduler (``tcp://host:port``), as a
:class:`~gnss_citygml.settings.Tiling` says.
Each step of :func:`~gnss_citygml.model.engine.run_parts` becomes a Dask task whose result
stays on the worker that made it; a step that fails is run once more, and a worker that dies
takes its results with it, which Dask recomputes from the steps that made them, with the same
result. The core package does not import Dask: only this module does, when it is asked for.
"""

from __future__ import annotations

import socket
import struct
import time
import warnings
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from typing import Any

from ..errors import InputError, escape_controls, first_line
from ..settings import SCHEDULER_PORT, Tiling, scheduler_address

__all__ = ["DaskEngine", "connect"]

#: Times Dask runs a failed task again before it reports it.
RETRIES = 1

#: The longest greeting a Dask scheduler opens a connection with (its handshake is a few dozen
#: bytes): a longer one is not Dask's (an SSH banner read as a length is 2.82 EiB).
GREETING_MAX = 1 << 20

#: Seconds to wait for an answer to the HTTP request a silent server is sent, to name it.
HTTP_WAIT = 5.0

#: How to mend an address where no scheduler answers.
SCHEDULER_FIX = (
    f"give the address `dask scheduler` prints (tcp://HOST:{SCHEDULER_PORT} by default, not "
    "its dashboard's port), or start one there: dask scheduler"
)

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
    """An :class:`~gnss_citygml.model.engine.Engine` on a ``dask.distributed.Client``."""

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
    timeout = connect_timeout()
    check_scheduler(tiling.scheduler, timeout)
    try:
        client = Client(tiling.scheduler, timeout=timeout)
    except (struct.error, ValueError) as err:  # (its messages are not laid out as Dask's)
        raise InputError(
            f"no Dask scheduler at {tiling.scheduler}: what answered does not speak Dask's "
            f"protocol ({escape_controls(first_line(err))})",
            fix=SCHEDULER_FIX,
        ) from err
    except OSError as err:
        raise InputError(
            f"cannot reach the Dask scheduler at {tiling.scheduler}: {err}",
            fix="start it (dask scheduler) or check the address",
        ) from err
    with client:
        yield DaskEngine(client)


def connect_timeout() -> float:
    """Seconds to wait for a scheduler to answer: Dask's ``distributed.comm.timeouts.connect``
    (30 s by default; ``DASK_DISTRIBUTED__COMM__TIMEOUTS__CONNECT=60s`` sets it)."""
    import dask
    from dask.utils import parse_timedelta

    return float(parse_timedelta(dask.config.get("distributed.comm.timeouts.connect"), "s"))


def check_scheduler(scheduler: str | None, timeout: float) -> None:
    """Refuse, in one line naming what answered, an address where no Dask scheduler is, in
    ``timeout`` seconds (and :data:`HTTP_WAIT` more to name a server that says nothing).

    Dask's own connection waits forever on a server that accepts and says nothing, and reads
    a banner (SSH's) as the length of a message of exabytes. A scheduler greets each new
    connection at once (8 bytes, the length of a short message, then the message): that
    greeting is read here, on a connection of its own, before Dask's. Behind ``tls://`` the
    scheduler speaks only after the TLS handshake: only the connection is checked there."""
    protocol, host, port = scheduler_address(scheduler)
    where = f"cannot reach the Dask scheduler at {scheduler}"
    try:
        sock = socket.create_connection((host, port), timeout=timeout)
    except socket.gaierror as err:
        raise InputError(
            f"{where}: no host is named {host} ({err.strerror})",
            fix="check the host name, or give the scheduler's IP address",
        ) from err
    except ConnectionRefusedError as err:
        raise InputError(
            f"{where}: nothing listens on port {port} of {host} (connection refused)",
            fix=f"start a scheduler there (dask scheduler --port {port}), or {SCHEDULER_FIX}",
        ) from err
    except TimeoutError as err:
        raise InputError(
            f"{where}: {host} did not answer in {timeout:g} s (it is down, or a firewall "
            "drops the connection)",
            fix=f"check the address, and that port {port} is open to this machine; "
            "DASK_DISTRIBUTED__COMM__TIMEOUTS__CONNECT=60s waits longer",
        ) from err
    except OSError as err:
        raise InputError(f"{where}: {err.strerror or err}", fix=SCHEDULER_FIX) from err
    with sock:
        answered = None if protocol == "tls" else _not_a_greeting(sock, timeout)
    if answered is not None:
        raise InputError(f"no Dask scheduler at {scheduler}: {answered}", fix=SCHEDULER_FIX)


def _not_a_greeting(sock: socket.socket, timeout: float) -> str | None:
    """None when ``sock``'s server greets as a Dask scheduler within ``timeout`` seconds, or
    what it did instead; one that says nothing is sent an HTTP request, to name it."""
    data, closed = _receive(sock, 8, timeout)
    if len(data) == 8:
        (length,) = struct.unpack("<Q", data)
        if 0 < length <= GREETING_MAX:
            rest, closed = _receive(sock, length, timeout)
            if len(rest) == length and _handshake(rest):
                return None
            data += rest
    if data and not closed:  # the rest of its first line, to name it
        data += _receive(sock, 512, min(timeout, 0.5))[0]
    if not data and closed:
        return "something accepted the connection and closed it at once"
    if not data:
        try:
            sock.sendall(b"GET / HTTP/1.0\r\n\r\n")
            data, _ = _receive(sock, 512, HTTP_WAIT)
        except OSError:
            pass
        if not data:
            return (
                f"something accepted the connection but sent nothing in {timeout:g} s, where "
                "a scheduler greets at once (one too busy to: "
                "DASK_DISTRIBUTED__COMM__TIMEOUTS__CONNECT=60s waits longer)"
            )
    line = data.split(b"\n")[0].rstrip(b"\r")
    shown = repr(line[:60])[1:] + ("..." if len(line) > 60 else "")
    if data.startswith(b"SSH-"):
        return f"an SSH server answered {shown}"
    if data.startswith(b"HTTP/"):
        return f"an HTTP server answered {shown}"
    return f"something else answered {shown}"


def _handshake(message: bytes) -> bool:
    """Whether ``message`` is a Dask handshake: frames as Dask lays them out (their count, each
    one's length, 8 bytes each, then the frames, filling it exactly), the first a MessagePack
    map with the peer's Python version. (Any length followed by as many bytes was taken for a
    greeting: Dask then failed unpacking it, an internal error and its traceback logged.)"""
    import msgpack  # (Dask's own)

    if len(message) < 8:
        return False
    (count,) = struct.unpack_from("<Q", message)
    if not 0 < count <= (len(message) - 8) // 8:
        return False
    lengths = struct.unpack_from(f"<{count}Q", message, 8)
    start = 8 * (count + 1)
    if sum(lengths) != len(message) - start:
        return False
    try:
        header = msgpack.unpackb(message[start : start + lengths[0]])
    except (ValueError, TypeError, msgpack.UnpackException):
        return False
    return isinstance(header, dict) and "python" in header


def _receive(sock: socket.socket, size: int, timeout: float) -> tuple[bytes, bool]:
    """Up to ``size`` bytes from ``sock``, what came in ``timeout`` seconds; and whether the
    other end closed the connection."""
    deadline = time.monotonic() + timeout
    data = b""
    while len(data) < size:
        left = deadline - time.monotonic()
        if left <= 0:
            return data, False
        sock.settimeout(left)
        try:
            chunk = sock.recv(size - len(data))
        except TimeoutError:
            return data, False
        except OSError:  # reset
            return data, True
        if not chunk:
            return data, True
        data += chunk
    return data, False
