"""The dashboard's HTTP server: the page, its static files, JSON/CSV APIs and live updates by
Server-Sent Events, on the standard library's ``ThreadingHTTPServer`` (no web framework: the
page needs a dozen routes and one event stream; see ``docs/dashboard.md``)."""

from __future__ import annotations

import csv
import hmac
import io
import json
import logging
import math
import queue
import select
import socket
import ssl
import threading
import time
from collections.abc import Callable
from http import HTTPStatus
from importlib import resources
from pathlib import Path
from typing import Any
from urllib.parse import parse_qs, urlsplit

from pydantic import ValidationError

from edgedsm.dashboard import access, commissioning, maps
from edgedsm.dashboard.history import History
from edgedsm.dashboard.plant import Plant
from edgedsm.publish.http_guard import ConnectionLimits, GuardedHandler, GuardedServer

log = logging.getLogger(__name__)

STATIC = {  # file -> content type; nothing else is served
    "index.html": "text/html; charset=utf-8",
    "app.js": "text/javascript; charset=utf-8",
    "kinetics.js": "text/javascript; charset=utf-8",
    "app.css": "text/css; charset=utf-8",
    "vendor/uPlot.iife.min.js": "text/javascript; charset=utf-8",
    "vendor/uPlot.min.css": "text/css; charset=utf-8",
}
CSP = ("default-src 'self'; script-src 'self'; style-src 'self' 'unsafe-inline'; img-src 'self' data:; "
       "connect-src 'self'; frame-ancestors 'none'; base-uri 'none'; form-action 'none'")
MAX_BODY = 64 * 1024
SSE_QUEUE = 2000  # events buffered per page; a page that falls further behind is disconnected
KEEPALIVE_S = 15.0
DAY_S = 86400.0

SendCommand = Callable[[str, str], None]


class EventClient:
    """One open page's event queue; ``closed`` when it fell too far behind (it reconnects)."""

    def __init__(self) -> None:
        self.queue: queue.Queue[bytes] = queue.Queue(SSE_QUEUE)
        self.closed = threading.Event()


class EventHub:
    """Fans events out to every open page (one queue each)."""

    def __init__(self) -> None:
        self._clients: list[EventClient] = []
        self._lock = threading.Lock()
        self.sent = 0

    def publish(self, event: str, data: dict[str, Any]) -> None:
        message = f"event: {event}\ndata: {json.dumps(_finite(data), default=_jsonable)}\n\n".encode()
        with self._lock:
            for client in list(self._clients):
                try:
                    client.queue.put_nowait(message)
                    self.sent += 1
                except queue.Full:
                    self._clients.remove(client)
                    client.closed.set()

    def subscribe(self) -> EventClient:
        client = EventClient()
        with self._lock:
            self._clients.append(client)
        return client

    def unsubscribe(self, client: EventClient) -> None:
        with self._lock:
            if client in self._clients:
                self._clients.remove(client)

    def close(self) -> None:
        with self._lock:
            for client in self._clients:
                client.closed.set()
            self._clients.clear()


def _jsonable(value: Any) -> Any:
    return str(value)


def _finite(value: Any) -> Any:
    """JSON has no NaN: non-finite floats become null, recursively."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {key: _finite(item) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return [_finite(item) for item in value]
    return value


class DashboardServer(GuardedServer):
    """Connections bounded and timed by ``http_guard``; Host allow-list, optional viewer login and
    TLS by ``access``."""

    allow_reuse_address = True

    def __init__(self, address: tuple[str, int], plant: Plant, history: History, hub: EventHub, *,
                 token: str | None, send_command: SendCommand | None,
                 broker_connected: Callable[[], bool] = lambda: False,
                 commissioning_dirs: dict[str, Path] | None = None,
                 limits: ConnectionLimits | None = None, tls: ssl.SSLContext | None = None,
                 allowed_hosts: list[str] | None = None, login: access.ViewerLogin | None = None) -> None:
        super().__init__(address, Handler, limits=limits, tls=tls, name="dashboard")
        self.plant = plant
        self.history = history
        self.hub = hub
        self.token = token
        self.send_command = send_command
        self.broker_connected = broker_connected
        self.commissioning_dirs = dict(commissioning_dirs or {})  # device -> its last tune report's folder
        self.hosts = access.HostGuard(address[0], allowed_hosts or [])
        self.login = login
        self.stopping = threading.Event()

    @property
    def url(self) -> str:
        host, port = self.server_address[:2]
        host = f"[{host}]" if ":" in host else host
        return f"{'https' if self.tls else 'http'}://{host}:{port}/"

    def stop(self) -> None:
        self.stopping.set()
        self.hub.close()
        self.shutdown()
        self.server_close()


class Handler(GuardedHandler):
    server: DashboardServer
    protocol_version = "HTTP/1.1"
    server_version = "edgedsm-dashboard"

    def log_message(self, format: str, *args: Any) -> None:
        log.debug("http: " + format, *args)

    # -- routing ----------------------------------------------------------------------------

    def do_GET(self) -> None:  # noqa: N802 (http.server names)
        self._answer(self._get)

    def do_POST(self) -> None:  # noqa: N802 (http.server names)
        self._answer(self._post)

    def _answer(self, route: Callable[[], None]) -> None:
        """Run a route; a bad request answers 400, a bug 500 (logged), a vanished client nothing."""
        try:
            if access.gate(self):
                route()
        except BadRequest as exc:
            self._error(HTTPStatus.BAD_REQUEST, str(exc))
        except (BrokenPipeError, ConnectionResetError):
            pass
        except Exception:  # a bug answers 500 and is logged; the server goes on
            log.exception("dashboard: %s %s failed", self.command, self.path[:200])
            self._error(HTTPStatus.INTERNAL_SERVER_ERROR, "internal error (logged)")

    def _get(self) -> None:
        url = urlsplit(self.path)
        path = url.path
        try:
            query = {key: values[0] for key, values in parse_qs(url.query, max_num_fields=20).items()}
        except ValueError:
            raise BadRequest("too many query fields") from None
        if path in ("/", "/index.html"):
            self._static("index.html")
        elif path.startswith("/static/"):
            self._static(path[len("/static/"):])
        elif path == "/api/info":
            self._json({"read_only": self.server.token is None, "prefix": self.server.plant.prefix,
                        "broker_connected": self.server.broker_connected()})
        elif path == "/api/devices":
            self._json(self.server.plant.snapshot())
        elif path == "/api/events":
            self._events()
        elif path == "/api/map.png":
            self._map(query)
        elif path == "/api/colorbar.png":
            self._send(HTTPStatus.OK, maps.colour_bar_png(), "image/png", cache=True)
        elif path == "/api/history":
            self._history(query)
        elif path == "/api/commissioning":
            device = _required(query, "device")
            self._json(commissioning.load(device, self.server.commissioning_dirs.get(device)))
        elif path.startswith("/api/commissioning/"):
            image = commissioning.plot(self.server.commissioning_dirs.get(_required(query, "device")),
                                       path[len("/api/commissioning/"):])
            if image is None:
                self._error(HTTPStatus.NOT_FOUND, "no such plot")
            else:
                self._send(HTTPStatus.OK, image, "image/png")
        else:
            self._error(HTTPStatus.NOT_FOUND, "no such page")

    def _post(self) -> None:
        path = urlsplit(self.path).path
        body = self._body()
        if path == "/api/region-stats":
            self._region_stats(body)
        elif path == "/api/command":
            self._command(body)
        else:
            self._error(HTTPStatus.NOT_FOUND, "no such page")

    # -- pages ------------------------------------------------------------------------------

    def _static(self, name: str) -> None:
        kind = STATIC.get(name)
        if kind is None:
            self._error(HTTPStatus.NOT_FOUND, "no such file")
            return
        data = resources.files("edgedsm.dashboard").joinpath("static", *name.split("/")).read_bytes()
        self._send(HTTPStatus.OK, data, kind, cache=name.startswith("vendor/"))

    def _events(self) -> None:
        if not self.server.limiter.stream(self.conn):
            self._error(HTTPStatus.SERVICE_UNAVAILABLE, "too many open pages: close one", {"Retry-After": "5"})
            return
        client = self.server.hub.subscribe()
        self.send_response(HTTPStatus.OK)
        self.send_header("Content-Type", "text/event-stream")
        self.send_header("Cache-Control", "no-store")
        self.send_header("Connection", "close")
        self.end_headers()
        self.close_connection = True
        try:
            snapshot = _finite(self.server.plant.snapshot())
            self.wfile.write(f"event: snapshot\ndata: {json.dumps(snapshot, default=_jsonable)}\n\n".encode())
            self.wfile.flush()
            last_write = time.monotonic()
            while not (self.server.stopping.is_set() or client.closed.is_set() or _peer_closed(self.connection)):
                chunk: list[bytes] = []
                try:
                    chunk.append(client.queue.get(timeout=1.0))
                    while len(chunk) < 100:  # write what piled up at once
                        chunk.append(client.queue.get_nowait())
                except queue.Empty:
                    pass
                if not chunk:
                    if time.monotonic() - last_write < KEEPALIVE_S:
                        continue
                    chunk = [b": keepalive\n\n"]
                self.wfile.write(b"".join(chunk))
                self.wfile.flush()
                last_write = time.monotonic()
        finally:
            self.server.hub.unsubscribe(client)

    def _map(self, query: dict[str, str]) -> None:
        image = self.server.plant.map_image(_required(query, "device"), _required(query, "name"))
        if image is None:
            self._error(HTTPStatus.NOT_FOUND, "no such map (yet)")
            return
        self._send(HTTPStatus.OK, image.png, "image/png")

    def _history(self, query: dict[str, str]) -> None:
        device, region = _required(query, "device"), _required(query, "region")
        end = _number(query, "to", time.time())
        start = _number(query, "from", end - 3600.0)
        if not start <= end or end - start > 31 * DAY_S:
            raise BadRequest("from must be before to, at most 31 days apart")
        points = self.server.history.samples(device, region, start, end)
        kinetics = self.server.history.kinetics(device, region, start, end)
        alerts = self.server.history.alerts(device, region, start, end)
        if query.get("format", "json") == "csv":
            out = io.StringIO()
            writer = csv.writer(out, lineterminator="\n")
            header = ["t", "device", "region", "activity", "state"]
            rows = {t: [t, device, region, "" if a is None else a, s] for t, a, s in points}
            if kinetics:  # the kinetics' columns on the same rows (a sample carries both); its rate is 1/τ
                header += ["kinetics_tau_s", "kinetics_rate_hz", "kinetics_status", "kinetics_bound_s"]
                for row in rows.values():
                    row += ["", "", "", ""]
                for t, tau, status, bound in kinetics:
                    row = rows.setdefault(t, [t, device, region, "", "", "", "", "", ""])
                    row[5:] = ["" if tau is None else tau, "" if tau is None else 1.0 / tau, status,
                               "" if bound is None else bound]
            writer.writerow(header)
            writer.writerows(rows[t] for t in sorted(rows))
            self._send(HTTPStatus.OK, out.getvalue().encode(), "text/csv; charset=utf-8",
                       extra={"Content-Disposition": 'attachment; filename="history.csv"'})
            return
        info = self.server.plant.region_info(device, region)
        thresholds = None if info is None else {"wet_above": info.wet_above, "dry_below": info.dry_below}
        self._json({"device": device, "region": region, "from": start, "to": end, "points": points,
                    "alerts": alerts, "thresholds": thresholds, "kinetics": kinetics,
                    "stages": [] if info is None else info.stages})

    def _region_stats(self, body: dict[str, Any]) -> None:
        device, name = str(body.get("device", "")), str(body.get("map", ""))
        image = self.server.plant.map_image(device, name)
        if image is None:
            raise BadRequest("no such map (yet)")
        try:
            shape = maps.parse_shape(body.get("shape"))
        except ValidationError as exc:
            error = exc.errors()[0]
            raise BadRequest(f"shape: {'.'.join(map(str, error['loc']))}: {error['msg']}") from None
        source = image.meta.get("source_shape") or list(image.values.shape)
        try:
            source_shape = (int(source[0]), int(source[1]))
        except (TypeError, ValueError, IndexError):
            source_shape = image.values.shape
        region = str(body.get("name") or "new_region")[:64]
        self._json({"stats": maps.shape_stats(image.values, source_shape, shape),
                    "toml": maps.region_toml(region, shape)})

    def _command(self, body: dict[str, Any]) -> None:
        token = self.server.token
        if token is None or self.server.send_command is None:
            self._error(HTTPStatus.FORBIDDEN, "the dashboard is read-only (no command token configured)")
            return
        given = self.headers.get("Authorization", "").removeprefix("Bearer ").strip()
        if not hmac.compare_digest(given.encode(), token.encode()):
            self._error(HTTPStatus.UNAUTHORIZED, "wrong or missing token")
            return
        try:
            self.server.send_command(str(body.get("device", "")), str(body.get("command", "")))
        except ValueError as exc:
            raise BadRequest(str(exc)) from None
        self._json({"sent": True})

    # -- plumbing ---------------------------------------------------------------------------

    def _body(self) -> dict[str, Any]:
        try:
            length = int(self.headers.get("Content-Length", "0"))
        except ValueError:
            raise BadRequest("bad Content-Length") from None
        if not 0 <= length <= MAX_BODY:
            self.close_connection = True
            raise BadRequest(f"request body over {MAX_BODY} bytes")
        try:
            data = json.loads(self.rfile.read(length) or b"{}")
        except ValueError:
            raise BadRequest("body is not JSON") from None
        if not isinstance(data, dict):
            raise BadRequest("body must be a JSON object")
        return data

    def _json(self, data: Any) -> None:
        self._send(HTTPStatus.OK, json.dumps(_finite(data), default=_jsonable).encode(), "application/json")

    def _error(self, status: HTTPStatus, message: str, extra: dict[str, str] | None = None) -> None:
        self._send(status, json.dumps({"error": message}).encode(), "application/json", extra=extra)

    def _send(self, status: HTTPStatus, data: bytes, kind: str, *, cache: bool = False,
              extra: dict[str, str] | None = None) -> None:
        self.send_response(status)
        self.send_header("Content-Type", kind)
        self.send_header("Content-Length", str(len(data)))
        self.send_header("Cache-Control", "max-age=3600" if cache else "no-store")
        self.send_header("Content-Security-Policy", CSP)
        self.send_header("X-Content-Type-Options", "nosniff")
        for key, value in (extra or {}).items():
            self.send_header(key, value)
        self.end_headers()
        self.wfile.write(data)


def _peer_closed(sock: socket.socket) -> bool:
    """Whether the page went away (its end of file is waiting): its stream's place is freed within a
    second, not at the next failed write. A poll that never waits, then the plain socket's peek
    (even under TLS: the bytes stay for the TLS layer)."""
    poller = select.poll()
    poller.register(sock.fileno(), select.POLLIN)
    ready = poller.poll(0)
    if not ready:
        return False
    if ready[0][1] & (select.POLLERR | select.POLLHUP | select.POLLNVAL):
        return True
    try:
        return socket.socket.recv(sock, 1, socket.MSG_PEEK | socket.MSG_DONTWAIT) == b""
    except (BlockingIOError, InterruptedError):
        return False
    except OSError:
        return True


class BadRequest(ValueError):
    """A request the dashboard refuses (the message goes back as ``{"error": ...}``)."""


def _required(query: dict[str, str], key: str) -> str:
    value = query.get(key)
    if not value:
        raise BadRequest(f"missing {key}")
    return value


def _number(query: dict[str, str], key: str, default: float) -> float:
    if key not in query:
        return default
    try:
        value = float(query[key])
    except ValueError:
        raise BadRequest(f"{key} must be a number (UTC epoch s)") from None
    if not math.isfinite(value):
        raise BadRequest(f"{key} must be finite")
    return value
