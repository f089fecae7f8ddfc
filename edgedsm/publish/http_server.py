"""A small HTTP server for ``/metrics`` (Prometheus text format) and ``/healthz`` (200 / 503).

Bad input never reaches the measurement: only ``GET``/``HEAD`` of the two paths are served;
other paths are 404, other methods 405, a request with a body 413, a request line or headers
beyond the limits 414/431 (``http.server``'s own checks). Connections are bounded and timed by
``http_guard`` (``LIMITS``: 16 at once, 8 per address, request headers within 5 s; idle
connections are evicted by new ones, 503 when all are busy). Requests run on their own threads,
never the pipeline's.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler

from prometheus_client.exposition import CONTENT_TYPE_LATEST

from edgedsm.errors import ConfigError
from edgedsm.publish.http_guard import ConnectionLimits, GuardedHandler, GuardedServer, QuietDisconnects

log = logging.getLogger(__name__)

#: The metrics server's connection limits (the shared mechanism of ``http_guard``): a scraper or two,
#: a health check; a client that does not send its request within 5 s is dropped (slowloris).
LIMITS = ConnectionLimits(max_connections=16, max_per_client=8, max_event_streams=0,
                          max_event_streams_per_client=0, header_timeout_s=5.0, idle_timeout_s=5.0,
                          request_timeout_s=5.0)
#: Most header lines accepted (``http.client``'s limit is 100).
MAX_HEADERS = 32

__all__ = ["LIMITS", "MAX_HEADERS", "MetricsServer", "QuietDisconnects"]


class MetricsServer:
    """Serves ``exposition()`` on ``/metrics`` and ``healthy()`` on ``/healthz`` at ``address``."""

    def __init__(self, address: tuple[str, int], exposition: Callable[[], bytes],
                 healthy: Callable[[], tuple[bool, str]]) -> None:
        self.exposition = exposition
        self.healthy = healthy
        handler = _handler_for(self)
        try:
            self._server = GuardedServer(address, handler, limits=LIMITS, name="metrics")
        except OSError as exc:
            raise ConfigError(f"http.listen: cannot listen on {address[0]}:{address[1]}: {exc.strerror or exc}") \
                from None
        self.thread = threading.Thread(target=self._server.serve_forever, kwargs={"poll_interval": 0.2},
                                       name="edgedsm-http", daemon=True)

    @property
    def port(self) -> int:
        return int(self._server.server_address[1])

    def start(self) -> MetricsServer:
        self.thread.start()
        log.info("metrics on http://%s:%d/metrics, health on /healthz", *self._server.server_address[:2])
        return self

    def close(self) -> None:
        if self.thread.is_alive():
            self._server.shutdown()
        self._server.server_close()


def _handler_for(server: MetricsServer) -> type[BaseHTTPRequestHandler]:
    class Handler(GuardedHandler):
        server_version = "edgedsm"
        sys_version = ""

        def do_GET(self) -> None:  # noqa: N802 (http.server names)
            self._serve(body=True)

        def do_HEAD(self) -> None:  # noqa: N802 (http.server names)
            self._serve(body=False)

        def do_POST(self) -> None:  # noqa: N802 (http.server names)
            self._refuse(HTTPStatus.METHOD_NOT_ALLOWED, "only GET and HEAD are served")

        do_PUT = do_DELETE = do_PATCH = do_OPTIONS = do_POST  # noqa: N815 (http.server names)

        def _serve(self, body: bool) -> None:
            if len(self.headers) > MAX_HEADERS:
                self._refuse(HTTPStatus.REQUEST_HEADER_FIELDS_TOO_LARGE, f"more than {MAX_HEADERS} headers")
                return
            if self.headers.get("Content-Length", "0").strip() not in ("", "0") or "Transfer-Encoding" in self.headers:
                self._refuse(HTTPStatus.REQUEST_ENTITY_TOO_LARGE, "requests here carry no body")
                return
            path = self.path.split("?", 1)[0]
            if path == "/metrics":
                try:
                    payload = server.exposition()
                except Exception as exc:  # a bug in a collector must not take the server down
                    log.exception("metrics could not be produced")
                    self._send(HTTPStatus.INTERNAL_SERVER_ERROR, f"metrics failed: {exc}\n".encode(), body)
                    return
                self._send(HTTPStatus.OK, payload, body, CONTENT_TYPE_LATEST)
            elif path == "/healthz":
                ok, why = server.healthy()
                self._send(HTTPStatus.OK if ok else HTTPStatus.SERVICE_UNAVAILABLE, f"{why}\n".encode(), body)
            else:
                self._refuse(HTTPStatus.NOT_FOUND, "only /metrics and /healthz are served")

        def _refuse(self, status: HTTPStatus, why: str) -> None:
            self.close_connection = True
            self._send(status, f"{status.value} {status.phrase}: {why}\n".encode(), True)

        def _send(self, status: HTTPStatus, payload: bytes, body: bool,
                  content_type: str = "text/plain; charset=utf-8") -> None:
            self.send_response(status)
            self.send_header("Content-Type", content_type)
            self.send_header("Content-Length", str(len(payload)))
            if self.close_connection:
                self.send_header("Connection", "close")
            self.end_headers()
            if body:
                self.wfile.write(payload)

        def log_message(self, format: str, *args: object) -> None:
            log.debug("http %s - %s", self.address_string(), format % args)

    return Handler
