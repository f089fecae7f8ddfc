"""The connection limiter shared by the dashboard and the daemon's /metrics server: caps per client
and in total, eviction of the oldest connection still waiting for its headers, header and idle
deadlines (a slowloris trickling bytes is still closed), event-stream caps; on real sockets."""

from __future__ import annotations

import http.client
import logging
import os
import resource
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator

import pytest
from pydantic import ValidationError

from edgedsm.publish.http_guard import (
    FD_RESERVE,
    TRACKED_FACTOR,
    ConnectionLimiter,
    ConnectionLimits,
    GuardedHandler,
    GuardedServer,
    ensure_fd_budget,
)


def _limits(**changes: float) -> ConnectionLimits:
    base = {"max_connections": 4, "max_per_client": 3, "max_event_streams": 2, "max_event_streams_per_client": 1,
            "header_timeout_s": 30.0, "idle_timeout_s": 30.0, "request_timeout_s": 30.0}
    return ConnectionLimits(**{**base, **changes})


@pytest.fixture
def pairs() -> Iterator[list[tuple[socket.socket, socket.socket]]]:
    made: list[tuple[socket.socket, socket.socket]] = []
    yield made
    for a, b in made:
        a.close()
        b.close()


def _pair(pairs: list[tuple[socket.socket, socket.socket]]) -> tuple[socket.socket, socket.socket]:
    pair = socket.socketpair()
    for side in pair:
        side.settimeout(2.0)
    pairs.append(pair)
    return pair


def _shut_by_server(peer: socket.socket) -> bool:
    """Whether the server side was shut: the peer reads end of file."""
    try:
        return peer.recv(1) == b""
    except TimeoutError:
        return False


def test_a_client_at_its_cap_evicts_its_own_oldest_idle_connection(pairs: list) -> None:
    limiter = ConnectionLimiter(_limits())
    try:
        conns = [limiter.admit(_pair(pairs)[0], "10.0.0.1") for _ in range(3)]
        assert all(conns) and limiter.counts()["open"] == 3
        other = limiter.admit(_pair(pairs)[0], "10.0.0.2")  # the 4th: the total cap
        assert other is not None
        limiter.active(conns[1])  # headers in: no longer evictable
        newest = limiter.admit(_pair(pairs)[0], "10.0.0.1")
        assert newest is not None and conns[0] is not None and conns[0].closed  # the oldest waiting one
        assert _shut_by_server(pairs[0][1]) and not conns[1].closed and not other.closed
        assert limiter.counts() == {"open": 4, "tracked": 5, "streams": 0, "admitted": 5, "evicted": 1,
                                    "timed_out": 0, "refused": 0}
        limiter.release(conns[0])
        assert limiter.counts()["tracked"] == 4
    finally:
        limiter.close()


def test_at_the_total_cap_the_oldest_waiting_goes_and_when_all_are_busy_a_new_one_is_refused(pairs: list) -> None:
    limiter = ConnectionLimiter(_limits())
    try:
        conns = [limiter.admit(_pair(pairs)[0], f"10.0.0.{i}") for i in range(4)]
        fifth = limiter.admit(_pair(pairs)[0], "10.0.1.1")
        assert fifth is not None and conns[0].closed and not any(conn.closed for conn in conns[1:])
        for conn in [*conns[1:], fifth]:
            limiter.active(conn)
        assert limiter.admit(_pair(pairs)[0], "10.0.1.2") is None  # every connection busy: 503
        assert limiter.counts()["refused"] == 1 and limiter.counts()["open"] == 4
    finally:
        limiter.close()


def test_evicted_connections_not_yet_released_bound_the_tracked_total(pairs: list) -> None:
    limiter = ConnectionLimiter(_limits())
    try:
        admitted = [limiter.admit(_pair(pairs)[0], "10.0.0.1") for _ in range(TRACKED_FACTOR * 4 + 3)]
        refused = [conn for conn in admitted if conn is None]
        assert limiter.counts()["tracked"] == TRACKED_FACTOR * 4 and len(refused) == 3
    finally:
        limiter.close()


def test_event_streams_are_capped_in_total_and_per_client(pairs: list) -> None:
    limiter = ConnectionLimiter(_limits())
    try:
        a1, a2, b1, c1 = (limiter.admit(_pair(pairs)[0], client) for client in ("a", "a", "b", "c"))
        assert limiter.stream(a1) and not limiter.stream(a2)  # 1 per client
        assert limiter.stream(b1) and not limiter.stream(c1)  # 2 in total
        limiter.release(a1)
        assert limiter.stream(c1) and limiter.counts()["streams"] == 2
        limiter.admit(_pair(pairs)[0], "d")  # the 4th live connection
        limiter.admit(_pair(pairs)[0], "e")  # over the cap: the oldest waiting goes
        assert not b1.closed and not c1.closed  # streams are never evicted (a2 was, being oldest waiting)
        assert a2.closed
    finally:
        limiter.close()


def test_the_reaper_closes_a_connection_whose_headers_are_late_and_spares_active_ones(pairs: list) -> None:
    limiter = ConnectionLimiter(_limits(header_timeout_s=0.3, request_timeout_s=5.0))
    try:
        started = time.monotonic()
        late = limiter.admit(_pair(pairs)[0], "a")
        busy = limiter.admit(_pair(pairs)[0], "a")
        limiter.active(busy)
        assert _shut_by_server(pairs[0][1])
        assert 0.28 <= time.monotonic() - started < 0.8 and late.closed and not busy.closed
        assert limiter.counts()["timed_out"] == 1
    finally:
        limiter.close()


def test_limits_that_contradict_each_other_are_refused() -> None:
    with pytest.raises(ValidationError, match="max_per_client"):
        ConnectionLimits(max_connections=8, max_per_client=9)
    with pytest.raises(ValidationError, match="max_event_streams must stay below"):
        ConnectionLimits(max_connections=8, max_per_client=8, max_event_streams=8)
    with pytest.raises(ValidationError, match="extra"):
        ConnectionLimits(max_conns=8)


class _Hello(GuardedHandler):
    protocol_version = "HTTP/1.1"

    def do_GET(self) -> None:  # noqa: N802 (http.server names)
        self.send_response(200)
        self.send_header("Content-Length", "5")
        self.end_headers()
        self.wfile.write(b"hello")

    def log_message(self, format: str, *args: object) -> None:
        pass


@pytest.fixture
def server() -> Iterator[GuardedServer]:
    limits = _limits(max_connections=8, max_per_client=4, header_timeout_s=1.0, idle_timeout_s=0.5)
    server = GuardedServer(("127.0.0.1", 0), _Hello, limits=limits, name="test")
    thread = threading.Thread(target=server.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True)
    thread.start()
    yield server
    server.shutdown()
    server.server_close()


def _get(server: GuardedServer) -> tuple[int, bytes]:
    connection = http.client.HTTPConnection("127.0.0.1", server.server_address[1], timeout=5)
    try:
        connection.request("GET", "/")
        answer = connection.getresponse()
        return answer.status, answer.read()
    finally:
        connection.close()


def test_a_slowloris_trickling_a_byte_every_100_ms_is_closed_at_the_header_deadline(server: GuardedServer) -> None:
    client = socket.create_connection(("127.0.0.1", server.server_address[1]), timeout=5)
    started = time.monotonic()
    closed_after = None
    try:
        for byte in b"GET / HTTP/1.1\r\nHost: x\r\nX-Slow: " + b"a" * 200:
            client.sendall(bytes([byte]))
            time.sleep(0.1)
            if time.monotonic() - started > 5:
                break
    except OSError:  # reset or broken pipe: the server closed it
        closed_after = time.monotonic() - started
    finally:
        client.close()
    assert closed_after is not None and 0.9 <= closed_after < 2.0, closed_after
    assert _get(server) == (200, b"hello")


def test_a_keep_alive_connection_is_closed_after_the_idle_timeout(server: GuardedServer) -> None:
    connection = http.client.HTTPConnection("127.0.0.1", server.server_address[1], timeout=5)
    try:
        connection.request("GET", "/")
        assert connection.getresponse().read() == b"hello"
        assert connection.sock is not None
        started = time.monotonic()
        assert connection.sock.recv(1) == b""  # the server ended the idle connection
        assert 0.4 <= time.monotonic() - started < 1.2
    finally:
        connection.close()


def test_idle_sockets_from_one_address_never_lock_out_a_request_from_it(server: GuardedServer) -> None:
    idle = [socket.create_connection(("127.0.0.1", server.server_address[1])) for _ in range(50)]
    try:
        for _ in range(3):
            assert _get(server) == (200, b"hello")
        deadline = time.monotonic() + 3
        while server.limiter.counts()["tracked"] > 4 and time.monotonic() < deadline:
            time.sleep(0.02)
        counts = server.limiter.counts()
        assert counts["open"] <= 4 and counts["evicted"] >= 46 and counts["refused"] == 0
    finally:
        for sock in idle:
            sock.close()


def test_the_open_file_limit_is_raised_for_the_connections() -> None:
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    need = TRACKED_FACTOR * 200 + FD_RESERVE
    if hard != resource.RLIM_INFINITY and hard < need:
        pytest.skip(f"the hard open-file limit {hard} is below {need}")
    resource.setrlimit(resource.RLIMIT_NOFILE, (need - 100, hard))
    try:
        ensure_fd_budget(ConnectionLimits(max_connections=200), "test")
        assert resource.getrlimit(resource.RLIMIT_NOFILE)[0] == need
    finally:
        resource.setrlimit(resource.RLIMIT_NOFILE, (soft, hard))


def test_a_hard_limit_too_small_for_the_connections_is_a_config_error() -> None:
    script = ("import resource; resource.setrlimit(resource.RLIMIT_NOFILE, (256, 256))\n"
              "from edgedsm.publish.http_guard import ConnectionLimits, ensure_fd_budget\n"
              "ensure_fd_budget(ConnectionLimits(max_connections=128), 'dashboard')")
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60)
    assert done.returncode == 1
    assert "ConfigError: dashboard: max_connections 128 needs 384 open files; the limit is 256" in done.stderr


def test_out_of_descriptors_the_accept_loop_frees_one_and_does_not_spin(server: GuardedServer,
                                                                      caplog: pytest.LogCaptureFixture) -> None:
    """With the open-file limit reached, ``accept()`` fails at once and the listening socket stays
    readable: the loop closes the oldest idle connection (or pauses) instead of spinning a core."""
    port = server.server_address[1]
    child = ("import resource, socket, time\n"
             "resource.setrlimit(resource.RLIMIT_NOFILE, (256, resource.getrlimit(resource.RLIMIT_NOFILE)[1]))\n"
             f"held = [socket.create_connection(('127.0.0.1', {port}), timeout=5) for _ in range(40)]\n"
             "time.sleep(3)\n")
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    room = len(os.listdir("/proc/self/fd")) + 3  # the child's pipe, then two connections
    resource.setrlimit(resource.RLIMIT_NOFILE, (room, hard))
    caplog.set_level(logging.WARNING, logger="edgedsm.publish.http_guard")
    try:
        holder = subprocess.Popen([sys.executable, "-c", child])
        time.sleep(1.0)  # the 40 connect; the server runs out of descriptors on the way
        cpu = time.process_time()
        time.sleep(1.5)
        cpu = time.process_time() - cpu
        counts = server.limiter.counts()
    finally:
        resource.setrlimit(resource.RLIMIT_NOFILE, (soft, hard))
    assert holder.wait(timeout=10) == 0
    assert cpu < 0.15, cpu  # a spinning accept loop burns ~1.5 CPU-s here
    assert any("cannot accept a connection: Too many open files" in r.getMessage() for r in caplog.records)
    assert counts["evicted"] >= 1 and counts["open"] <= 4
    assert _get(server) == (200, b"hello")
