"""Bounded connections for the standard library's threaded HTTP servers: the dashboard's and the
daemon's ``/metrics`` server share it (docs/dashboard.md, "Security").

A ``ThreadingHTTPServer`` gives every accepted socket a thread and waits on it for ever: a few
hundred idle sockets exhaust the open-file limit, after which ``accept()`` fails at once and the
accept loop spins a core. Here:

- at most ``max_connections`` connections are open at once, ``max_per_client`` from one address;
- a new connection beyond either cap **evicts the oldest connection still waiting for its request
  headers** (of that address first), so idle or slow sockets never lock out a browser; when every
  connection is busy with a request or an event stream, the new one is answered 503 and closed;
- a connection must send its complete request headers within ``header_timeout_s`` of being
  accepted (``idle_timeout_s`` between requests of a keep-alive connection), however slowly it
  trickles bytes; one thread (the reaper) closes those that do not, sleeping until the next deadline;
- event streams are counted and capped (``max_event_streams``, per client too);
- with TLS, the handshake runs in the connection's thread under the header deadline, never in the
  accept loop; a plain-HTTP request on a TLS port gets a plain 400 saying so.

Closing from outside is ``shutdown(SHUT_RDWR)`` on the socket: the connection's thread, blocked in
``recv``, sees end of file and ends; its file descriptor is closed by that thread."""

from __future__ import annotations

import contextlib
import errno
import logging
import resource
import socket
import ssl
import sys
import threading
import time
from collections import Counter
from dataclasses import dataclass, field
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any

from pydantic import Field, model_validator

from edgedsm.errors import ConfigError
from edgedsm.validation import StrictModel

log = logging.getLogger(__name__)

#: File descriptors the process keeps for itself beyond its connections (files, MQTT, SQLite, logs).
FD_RESERVE = 128
#: A connection evicted or timed out counts until its thread has closed it; beyond this many such
#: plus the live ones (``max_connections`` x this), new connections are refused: file descriptors stay bounded.
TRACKED_FACTOR = 2
_TLS_HANDSHAKE = 0x16  # the first byte of a TLS ClientHello record


class QuietDisconnects:
    """``socketserver``'s ``handle_error`` prints a traceback to stderr (the journal) for any error
    of a connection. A client that went away mid-request (a browser closing a keep-alive socket, a
    scraper killed), a read that timed out, a failed TLS handshake are routine: a debug line. Any
    other error is logged with its traceback."""

    def handle_error(self, request: Any, client_address: Any) -> None:
        error = sys.exc_info()[1]
        if isinstance(error, ConnectionError | TimeoutError | ssl.SSLError):
            log.debug("http: client %s went away: %s", client_address, error)
            return
        log.exception("http: a request from %s failed", client_address)


class ConnectionLimits(StrictModel):
    """How many connections a server keeps and how long it waits for them."""

    max_connections: int = Field(128, ge=2, le=4096, description="connections open at once, all clients")
    max_per_client: int = Field(32, ge=1, le=4096, description="connections open at once from one address")
    max_event_streams: int = Field(32, ge=0, le=4096, description="live event streams (open pages) at once")
    max_event_streams_per_client: int = Field(8, ge=0, le=4096,
                                              description="live event streams from one address")
    header_timeout_s: float = Field(10.0, gt=0, le=300,
                                    description="a new connection's complete request headers (and TLS "
                                                "handshake) must arrive within this")
    idle_timeout_s: float = Field(30.0, gt=0, le=3600,
                                  description="a keep-alive connection's next request headers must arrive within this")
    request_timeout_s: float = Field(60.0, gt=0, le=3600,
                                     description="a request (its body and answer) must be done within this; "
                                                 "also any one read or write on the socket")

    @model_validator(mode="after")
    def _caps_fit(self) -> ConnectionLimits:
        if self.max_per_client > self.max_connections:
            raise ValueError("max_per_client must not exceed max_connections")
        if self.max_event_streams >= self.max_connections:
            raise ValueError("max_event_streams must stay below max_connections (pages need requests too)")
        if self.max_event_streams_per_client > self.max_event_streams:
            raise ValueError("max_event_streams_per_client must not exceed max_event_streams")
        return self


@dataclass(eq=False)
class Connection:
    """One accepted socket as the limiter sees it."""

    sock: socket.socket
    client: str
    deadline: float | None
    waiting: bool = True  # for request headers: may be evicted
    stream: bool = False
    closed: bool = False  # evicted or timed out (its thread still has to close the socket)
    requests: int = 0
    seq: int = field(default=0)


class ConnectionLimiter:
    """Admits, times and evicts connections (see the module's docstring); thread-safe."""

    def __init__(self, limits: ConnectionLimits, name: str = "http") -> None:
        self.limits = limits
        self.name = name
        self._cond = threading.Condition()
        self._conns: dict[int, Connection] = {}  # by admission order: oldest first
        self._live: Counter[str] = Counter()
        self._streams: Counter[str] = Counter()
        self._seq = 0
        self._stopping = False
        self.admitted = self.evicted = self.timed_out = self.refused = 0
        self._reaper = threading.Thread(target=self._reap, name=f"{name}-reaper", daemon=True)
        self._reaper.start()

    # -- admission --------------------------------------------------------------------------

    def admit(self, sock: socket.socket, client: str) -> Connection | None:
        """A new connection, or None (refused: answer 503 and close it)."""
        victim: Connection | None = None
        with self._cond:
            live = sum(self._live.values())
            if len(self._conns) >= TRACKED_FACTOR * self.limits.max_connections:
                self.refused += 1
                return None
            if self._live[client] >= self.limits.max_per_client:
                victim = self._oldest_waiting(client)
            elif live >= self.limits.max_connections:
                victim = self._oldest_waiting(None)
            else:
                victim = None
            if victim is None and (self._live[client] >= self.limits.max_per_client
                                   or live >= self.limits.max_connections):
                self.refused += 1
                return None
            if victim is not None:
                self._close_locked(victim)
                self.evicted += 1
            self._seq += 1
            conn = Connection(sock, client, time.monotonic() + self.limits.header_timeout_s, seq=self._seq)
            self._conns[conn.seq] = conn
            self._live[client] += 1
            self.admitted += 1
            self._cond.notify()
        if victim is not None:
            _shut(victim.sock)
        return conn

    def _oldest_waiting(self, client: str | None) -> Connection | None:
        for conn in self._conns.values():
            if conn.waiting and not conn.closed and (client is None or conn.client == client):
                return conn
        return None

    def evict_one(self) -> bool:
        """Close the oldest connection waiting for its headers (the process ran out of descriptors)."""
        with self._cond:
            victim = self._oldest_waiting(None)
            if victim is None:
                return False
            self._close_locked(victim)
            self.evicted += 1
        _shut(victim.sock)
        return True

    # -- phases of a connection -------------------------------------------------------------

    def waiting(self, conn: Connection) -> None:
        """Its thread now reads the next request's headers: evictable, with a deadline."""
        with self._cond:
            if conn.requests > 0:  # the first request keeps the deadline of its admission (TLS handshake included)
                conn.deadline = time.monotonic() + self.limits.idle_timeout_s
            conn.requests += 1
            conn.waiting = True
            self._cond.notify()

    def active(self, conn: Connection) -> None:
        """Its headers are in: no longer evictable; the request must be done within ``request_timeout_s``."""
        with self._cond:
            conn.waiting, conn.deadline = False, time.monotonic() + self.limits.request_timeout_s
            self._cond.notify()

    def stream(self, conn: Connection) -> bool:
        """The connection becomes an event stream (no deadline), if the caps allow one more."""
        with self._cond:
            if (sum(self._streams.values()) >= self.limits.max_event_streams
                    or self._streams[conn.client] >= self.limits.max_event_streams_per_client):
                return False
            conn.stream, conn.waiting, conn.deadline = True, False, None
            self._streams[conn.client] += 1
            return True

    def release(self, conn: Connection) -> None:
        """Its thread is done and has closed the socket."""
        with self._cond:
            if self._conns.pop(conn.seq, None) is None:
                return
            if not conn.closed:
                self._uncount(conn)

    def _close_locked(self, conn: Connection) -> None:
        conn.closed = True
        self._uncount(conn)

    def _uncount(self, conn: Connection) -> None:
        self._live[conn.client] -= 1
        if self._live[conn.client] <= 0:
            del self._live[conn.client]
        if conn.stream:
            self._streams[conn.client] -= 1
            if self._streams[conn.client] <= 0:
                del self._streams[conn.client]

    def replace_socket(self, conn: Connection, sock: socket.socket) -> None:
        with self._cond:
            conn.sock = sock

    # -- the reaper -------------------------------------------------------------------------

    def _reap(self) -> None:
        while True:
            expired: list[Connection] = []
            with self._cond:
                if self._stopping:
                    return
                now = time.monotonic()
                next_deadline: float | None = None
                for conn in self._conns.values():
                    if conn.closed or conn.deadline is None:
                        continue
                    if conn.deadline <= now:
                        expired.append(conn)
                    elif next_deadline is None or conn.deadline < next_deadline:
                        next_deadline = conn.deadline
                for conn in expired:
                    self._close_locked(conn)
                    self.timed_out += 1
                if not expired:
                    self._cond.wait(None if next_deadline is None else next_deadline - now + 0.01)
            for conn in expired:
                _shut(conn.sock)

    def counts(self) -> dict[str, int]:
        with self._cond:
            return {"open": sum(self._live.values()), "tracked": len(self._conns),
                    "streams": sum(self._streams.values()), "admitted": self.admitted, "evicted": self.evicted,
                    "timed_out": self.timed_out, "refused": self.refused}

    def close(self) -> None:
        """Stop the reaper and shut every connection (their threads end)."""
        with self._cond:
            self._stopping = True
            conns = list(self._conns.values())
            for conn in conns:
                if not conn.closed:
                    self._close_locked(conn)
            self._cond.notify_all()
        for conn in conns:
            _shut(conn.sock)
        self._reaper.join(2)


def _shut(sock: socket.socket) -> None:
    """End a socket another thread may be blocked on (the plain socket's shutdown even for TLS:
    ``SSLSocket.shutdown`` would drop the TLS state under the reading thread)."""
    with contextlib.suppress(OSError):
        socket.socket.shutdown(sock, socket.SHUT_RDWR)


def ensure_fd_budget(limits: ConnectionLimits, what: str) -> None:
    """Raise the soft open-file limit if the connections plus ``FD_RESERVE`` need it (up to the hard
    limit); a config error if even the hard limit is too small."""
    need = TRACKED_FACTOR * limits.max_connections + FD_RESERVE
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if soft != resource.RLIM_INFINITY and soft < need:
        if hard != resource.RLIM_INFINITY and hard < need:
            raise ConfigError(f"{what}: max_connections {limits.max_connections} needs {need} open files; "
                              f"the limit is {hard} (LimitNOFILE=)")
        resource.setrlimit(resource.RLIMIT_NOFILE, (need, hard))
        log.info("%s: open-file limit raised from %d to %d", what, soft, need)


_REFUSED = b"HTTP/1.1 503 Service Unavailable\r\nContent-Length: 0\r\nRetry-After: 1\r\nConnection: close\r\n\r\n"
_NOT_TLS = (b"HTTP/1.1 400 Bad Request\r\nContent-Type: text/plain; charset=utf-8\r\nContent-Length: 37\r\n"
            b"Connection: close\r\n\r\nthis port speaks HTTPS: use https://\n")


class GuardedServer(QuietDisconnects, ThreadingHTTPServer):
    """``ThreadingHTTPServer`` under a ``ConnectionLimiter``, optionally TLS; its handler should
    derive from ``GuardedHandler`` (which tells the limiter when headers are in)."""

    daemon_threads = True
    block_on_close = False
    request_queue_size = 1024  # a burst of connections waits in the kernel's queue (no descriptor of ours), not dropped

    def __init__(self, address: tuple[str, int], handler: type[BaseHTTPRequestHandler], *,
                 limits: ConnectionLimits | None = None, tls: ssl.SSLContext | None = None,
                 name: str = "http") -> None:
        self.limits = limits or ConnectionLimits()
        ensure_fd_budget(self.limits, name)
        super().__init__(address, handler)
        self.tls = tls
        self.limiter = ConnectionLimiter(self.limits, name)
        self._current = threading.local()
        self._fd_warned = 0.0

    def get_request(self) -> tuple[Any, Any]:
        try:
            return super().get_request()
        except OSError as exc:
            if exc.errno in (errno.EMFILE, errno.ENFILE, errno.ENOBUFS, errno.ENOMEM):
                now = time.monotonic()
                if now - self._fd_warned > 60:
                    self._fd_warned = now
                    log.warning("%s: cannot accept a connection: %s", self.limiter.name, exc.strerror)
                if not self.limiter.evict_one():
                    time.sleep(0.05)  # nothing to free: never spin on a listening socket that stays readable
            raise

    def process_request(self, request: Any, client_address: Any) -> None:
        conn = self.limiter.admit(request, str(client_address[0]))
        if conn is None:
            with contextlib.suppress(OSError):
                request.setblocking(False)
                request.send(_REFUSED)
            self.shutdown_request(request)
            return
        thread = threading.Thread(target=self._serve_connection, args=(request, client_address, conn),
                                  name=f"{self.limiter.name}-conn", daemon=True)
        try:
            thread.start()
        except RuntimeError:  # no thread to be had: refuse this one
            self.limiter.release(conn)
            self.shutdown_request(request)

    def _serve_connection(self, request: Any, client_address: Any, conn: Connection) -> None:
        self._current.conn = conn
        try:
            if self.tls is not None:
                request = self._handshake(request, conn)
            if request is not None:
                self.finish_request(request, client_address)
        except Exception:
            self.handle_error(request, client_address)
        finally:
            if request is not None:
                self.shutdown_request(request)
            self.limiter.release(conn)

    def _handshake(self, sock: socket.socket, conn: Connection) -> ssl.SSLSocket | None:
        """TLS in the connection's thread; the reaper's header deadline bounds it."""
        assert self.tls is not None
        sock.settimeout(self.limits.header_timeout_s)
        first = sock.recv(1, socket.MSG_PEEK)
        if not first:
            self.shutdown_request(sock)
            return None
        if first[0] != _TLS_HANDSHAKE:
            with contextlib.suppress(OSError):
                sock.sendall(_NOT_TLS)
            self.shutdown_request(sock)
            return None
        secure = self.tls.wrap_socket(sock, server_side=True, do_handshake_on_connect=False)
        self.limiter.replace_socket(conn, secure)
        try:
            secure.do_handshake()
        except BaseException:
            self.shutdown_request(secure)
            raise
        return secure

    def connection(self) -> Connection:
        """The calling connection thread's ``Connection``."""
        return self._current.conn  # type: ignore[no-any-return]

    def server_close(self) -> None:
        super().server_close()
        limiter = getattr(self, "limiter", None)  # absent when binding failed in __init__
        if limiter is not None:
            limiter.close()


class GuardedHandler(BaseHTTPRequestHandler):
    """Tells the limiter when a request's headers are awaited and when they are in."""

    server: GuardedServer

    def setup(self) -> None:
        self.timeout = self.server.limits.request_timeout_s  # any one read or write
        self.conn = self.server.connection()
        super().setup()

    def handle_one_request(self) -> None:
        self.server.limiter.waiting(self.conn)
        super().handle_one_request()

    def parse_request(self) -> bool:
        ok = super().parse_request()  # reads the headers: the connection stays evictable until they are in
        self.server.limiter.active(self.conn)
        return ok
