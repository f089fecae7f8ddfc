"""A client that resets its connection in the middle of a request (a browser closing a keep-alive
socket, a scraper killed) is routine: no traceback on stderr (the journal), a debug line only."""

from __future__ import annotations

import logging
import socket
import struct
import threading
import time
from http.server import BaseHTTPRequestHandler

import pytest

from edgedsm.publish.http_guard import GuardedServer, QuietDisconnects


class _Slow(BaseHTTPRequestHandler):
    def do_GET(self) -> None:  # pragma: no cover - the client never completes a request
        self.send_response(204)
        self.end_headers()


def _reset_mid_request(port: int) -> None:
    client = socket.create_connection(("127.0.0.1", port))
    client.sendall(b"GET / HTTP/1.1\r\nHost: x\r\n")  # headers not ended: the server keeps reading
    time.sleep(0.2)
    client.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
    client.close()  # RST, not FIN: the server's read fails with ConnectionResetError


def test_a_client_reset_mid_request_prints_no_traceback(capfd: pytest.CaptureFixture[str],
                                                        caplog: pytest.LogCaptureFixture) -> None:
    assert issubclass(GuardedServer, QuietDisconnects)
    server = GuardedServer(("127.0.0.1", 0), _Slow)
    thread = threading.Thread(target=server.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True)
    thread.start()
    try:
        with caplog.at_level(logging.DEBUG, logger="edgedsm.publish.http_guard"):
            _reset_mid_request(server.server_address[1])
            deadline = time.monotonic() + 5
            while not any("went away" in r.getMessage() for r in caplog.records) and time.monotonic() < deadline:
                time.sleep(0.05)
    finally:
        server.shutdown()
        server.server_close()
    assert "Traceback" not in capfd.readouterr().err
    assert any("went away" in r.getMessage() and r.levelno == logging.DEBUG for r in caplog.records)


def test_other_errors_of_a_connection_are_still_logged_with_their_traceback(
        caplog: pytest.LogCaptureFixture) -> None:
    server = QuietDisconnects()
    with caplog.at_level(logging.DEBUG, logger="edgedsm.publish.http_guard"):
        try:
            raise ValueError("a bug in a handler")
        except ValueError:
            server.handle_error(None, ("127.0.0.1", 1234))
    record = caplog.records[-1]
    assert record.levelno == logging.ERROR and record.exc_info is not None and "127.0.0.1" in record.getMessage()
