"""The dashboard's server under its limits: live event streams capped (503 beyond), the viewer
login and Host allow-list in front of every route, the exposure warnings of ``app``, and bad
options as exit 78."""

from __future__ import annotations

import http.client
import logging
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest

from edgedsm.dashboard.access import ViewerLogin
from edgedsm.dashboard.app import DashboardSettings, _warn_exposure
from edgedsm.dashboard.history import History
from edgedsm.dashboard.plant import Plant
from edgedsm.dashboard.server import DashboardServer, EventHub
from edgedsm.publish.http_guard import ConnectionLimits
from edgedsm.publish.settings import MqttSettings

LIMITS = ConnectionLimits(max_connections=16, max_per_client=16, max_event_streams=2, max_event_streams_per_client=2)


@pytest.fixture
def server(tmp_path: Path) -> Iterator[DashboardServer]:
    history = History(tmp_path / "history.sqlite3", retention_s=86400.0)
    plant = Plant("edgedsm", history, lambda kind, data: None, {})
    made = DashboardServer(("127.0.0.1", 0), plant, history, EventHub(), token=None, send_command=None,
                           limits=LIMITS, login=ViewerLogin("viewer-pass", secure=False, session_s=60))
    thread = threading.Thread(target=made.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True)
    thread.start()
    yield made
    made.stop()
    thread.join(5)
    history.close()


class _Request:
    """One GET on its own connection; the response kept open (an event stream lives as long as it)."""

    def __init__(self, server: DashboardServer, path: str, headers: dict[str, str] | None = None) -> None:
        self.connection = http.client.HTTPConnection("127.0.0.1", server.server_address[1], timeout=5)
        self.connection.request("GET", path, headers=headers or {})
        self.response = self.connection.getresponse()
        self.status = self.response.status

    def close(self) -> None:
        self.response.close()
        self.connection.close()


def _status(server: DashboardServer, path: str, headers: dict[str, str] | None = None) -> int:
    request = _Request(server, path, headers)
    request.close()
    return request.status


def test_event_streams_beyond_the_cap_get_503_and_a_closed_one_frees_its_place(server: DashboardServer) -> None:
    basic = {"Authorization": "Basic YW55OnZpZXdlci1wYXNz"}  # any:viewer-pass
    streams = [_Request(server, "/api/events", basic) for _ in range(2)]
    try:
        assert [stream.status for stream in streams] == [200, 200]
        assert _status(server, "/api/events", basic) == 503 and server.limiter.counts()["streams"] == 2
        streams[0].close()
        for _ in range(60):  # the stream's thread sees the end of file within its 1 s queue wait
            if server.limiter.counts()["streams"] < 2:
                break
            threading.Event().wait(0.05)
        assert _status(server, "/api/events", basic) == 200
    finally:
        for stream in streams:
            stream.close()


def test_without_a_login_nothing_is_served_and_a_foreign_host_is_refused_first(server: DashboardServer) -> None:
    paths = ("/", "/static/app.js", "/api/devices", "/api/events", "/api/map.png?device=a&name=s1")
    assert {path: _status(server, path) for path in paths} == {
        "/": 303, "/static/app.js": 401, "/api/devices": 401, "/api/events": 401, "/api/map.png?device=a&name=s1": 401}
    assert _status(server, "/login", {"Host": "rebound.example"}) == 421


def _settings(host: str, *, password: str | None, token: str | None) -> DashboardSettings:
    return DashboardSettings(mqtt=MqttSettings(), listen=(host, 8080), database=Path("x"), retention_s=1.0,
                             token=token, daemon_configs=[], viewer_password=password)


@pytest.mark.parametrize(("host", "password", "token", "warnings"), [
    ("127.0.0.1", "viewer-pass", "t" * 16, []),
    ("localhost", None, None, []),
    ("192.0.2.7", None, None, ["without a viewer login"]),
    ("0.0.0.0", "viewer-pass", None, ["travel in clear"]),
    ("dash.plant.local", None, "t" * 16, ["travel in clear", "without a viewer login"]),
])
def test_what_a_listen_address_exposes_is_logged(host: str, password: str | None, token: str | None,
                                                 warnings: list[str], caplog: pytest.LogCaptureFixture) -> None:
    with caplog.at_level(logging.WARNING, logger="edgedsm.dashboard.app"):
        _warn_exposure(_settings(host, password=password, token=token), tls_on=False)
    assert [next(w for w in warnings if w in r.getMessage()) for r in caplog.records] == warnings


def test_https_silences_the_clear_text_warning(caplog: pytest.LogCaptureFixture) -> None:
    with caplog.at_level(logging.WARNING, logger="edgedsm.dashboard.app"):
        _warn_exposure(_settings("0.0.0.0", password="viewer-pass", token=None), tls_on=True)
    assert caplog.records == []


@pytest.mark.parametrize(("argv", "message"), [
    (["--max-per-client", "0"], "--max-per-client"),
    (["--tls-cert", "/nonexistent.crt", "--tls-key", "/nonexistent.key"], "--tls-cert /nonexistent.crt"),
    (["--allowed-host", "a b"], "--allowed-host"),
])
def test_bad_options_exit_78_with_one_line(argv: list[str], message: str, tmp_path: Path,
                                           capsys: pytest.CaptureFixture[str]) -> None:
    from edgedsm.cli import main

    assert main(["dashboard", "--database", str(tmp_path / "h.sqlite3"), *argv]) == 78
    error = capsys.readouterr().err.strip()
    assert message in error and "Traceback" not in error
