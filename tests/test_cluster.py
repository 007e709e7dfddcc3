"""Connecting to a Dask scheduler (gnss_citygml.tiling.cluster.connect): a real scheduler is
used; an address where something else answers, or nothing, is one line naming the address and what
answered, within the connect timeout, and the command exits. The servers are real, on
127.0.0.1."""

import http.server
import os
import socket
import subprocess
import sys
import threading
import time

import dask
import pytest
from distributed import LocalCluster
from test_outputs import estimate

from gnss_citygml.errors import InputError
from gnss_citygml.settings import Tiling
from gnss_citygml.tiling.cluster import connect

#: The connect timeout of these tests (Dask's config, as a user sets it).
TIMEOUT = 2


class Server:
    """A TCP server on a free port of 127.0.0.1 that accepts every connection, keeps it open
    and sends it ``greeting`` (nothing when empty), or closes it at once (``close``)."""

    def __init__(self, greeting=b"", close=False):
        self.listener = socket.create_server(("127.0.0.1", 0))
        self.port = self.listener.getsockname()[1]
        self.greeting, self.close_at_once, self.accepted = greeting, close, []
        threading.Thread(target=self._serve, daemon=True).start()

    def _serve(self):
        while True:
            try:
                conn, _ = self.listener.accept()
            except OSError:  # closed
                return
            self.accepted.append(conn)
            if self.greeting:
                conn.sendall(self.greeting)
            if self.close_at_once:
                conn.close()

    def close(self):
        self.listener.close()
        for conn in self.accepted:
            conn.close()


@pytest.fixture
def servers():
    """Make servers, closed after the test: ``servers(kind)`` gives the address of one."""
    made = []

    def server(kind):
        if kind == "http":
            httpd = http.server.ThreadingHTTPServer(
                ("127.0.0.1", 0), http.server.SimpleHTTPRequestHandler
            )
            threading.Thread(target=httpd.serve_forever, daemon=True).start()
            made.append(httpd.server_close)
            made.append(httpd.shutdown)
            return f"tcp://127.0.0.1:{httpd.server_address[1]}"
        if kind == "refused":  # a port nothing listens on
            with socket.create_server(("127.0.0.1", 0)) as probe:
                return f"tcp://127.0.0.1:{probe.getsockname()[1]}"
        one = Server(**KINDS[kind])
        made.append(one.close)
        return f"tcp://127.0.0.1:{one.port}"

    yield server
    for close in reversed(made):
        close()


#: The servers that are not a Dask scheduler, as Server's arguments.
KINDS = {
    "silent": {},
    "ssh": {"greeting": b"SSH-2.0-OpenSSH_9.2\r\n"},
    "closes": {"close": True},
    "binary": {"greeting": bytes(range(200, 256))},
    "half a greeting": {"greeting": (40).to_bytes(8, "little") + b"\x83\xabcomp"},
    # a whole message by its length, but not Dask's frames (was an internal error: Dask's
    # unpacking of it failed)
    "one byte": {"greeting": (1).to_bytes(8, "little") + b"\x01"},
    "frames that do not fill it": {
        "greeting": (24).to_bytes(8, "little") + (1).to_bytes(8, "little") + bytes(16)
    },
    # Dask's frames, but no message of Dask's in them (0xc1 is no MessagePack)
    "frames of no message": {
        "greeting": b"".join(n.to_bytes(8, "little") for n in (20, 1, 4)) + b"\xc1" * 4
    },
}


@pytest.mark.parametrize(
    "kind, answered",
    [
        ("silent", "accepted the connection but sent nothing in 2 s"),
        ("ssh", "an SSH server answered 'SSH-2.0-OpenSSH_9.2'"),
        ("http", "an HTTP server answered 'HTTP/1.0 "),
        ("closes", "accepted the connection and closed it at once"),
        ("binary", "answered '\\xc8\\xc9"),
        ("half a greeting", "answered '(\\x00"),
        ("one byte", "answered '\\x01\\x00"),
        ("frames that do not fill it", "answered '\\x18\\x00"),
        ("frames of no message", "answered '\\x14\\x00"),
        ("refused", "nothing listens on port"),
    ],
)
def test_what_answers_instead_of_a_scheduler_is_said_in_time(servers, kind, answered):
    address = servers(kind)
    start = time.monotonic()
    with dask.config.set({"distributed.comm.timeouts.connect": f"{TIMEOUT}s"}):
        with pytest.raises(InputError) as error:
            with connect(Tiling(address)):
                pass
    took = time.monotonic() - start
    message = str(error.value)
    assert address in message and answered in message, message
    assert "dask scheduler" in error.value.fix
    assert took < 3 * TIMEOUT + 2, took


def test_an_unknown_host_is_named():
    with pytest.raises(InputError, match="no host is named nohost.invalid") as error:
        with connect(Tiling("tcp://nohost.invalid:8786")):
            pass
    assert "tcp://nohost.invalid:8786" in str(error.value)


@pytest.mark.parametrize(
    "address",
    [
        "tcp://",
        "tcp://host:notaport",
        "tcp://:8786",
        "tcp://host:0",
        "tcp://host:99999",
        "tcp://host:8786/path",
        "tcp://a host:8786",
        "tcp://host:",
        "udp://host:8786",
        "http://host:8787",
        "host:8786",
    ],
)
def test_a_malformed_address_is_refused_before_any_work(address):
    with pytest.raises(InputError, match="tcp://HOST:PORT") as error:
        Tiling(address)
    assert repr(address) in str(error.value)


def test_a_real_scheduler_is_used():
    """A real scheduler at its tcp:// address (as ``dask scheduler`` prints it), with a
    worker: the engine runs a task there."""
    with LocalCluster(
        n_workers=1, processes=False, protocol="tcp://", dashboard_address=":0"
    ) as cluster:
        with connect(Tiling(cluster.scheduler_address)) as engine:
            assert engine.gather(engine.submit(sum, [1, 2])) == 3


@pytest.mark.parametrize("kind", ["silent", "ssh"])
def test_the_command_says_what_answered_and_exits(servers, grid_args, tmp_path, kind):
    """The command line, in a process of its own: one line and exit 2, in time (no thread of
    Dask's left waiting), the connect timeout taken from Dask's configuration."""
    address = servers(kind)
    args = estimate(tmp_path, grid_args, "h.gpkg", "--scheduler", address)
    env = {**os.environ, "DASK_DISTRIBUTED__COMM__TIMEOUTS__CONNECT": "3s"}
    start = time.monotonic()
    done = subprocess.run(
        [sys.executable, "-m", "gnss_citygml", *args],
        capture_output=True,
        text=True,
        env=env,
        timeout=120,
    )
    took = time.monotonic() - start
    assert done.returncode == 2, done.stderr
    lines = done.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), done.stderr
    assert address in lines[0] and "dask scheduler" in lines[0], lines[0]
    assert took < 60, took
    assert not list(tmp_path.iterdir())
