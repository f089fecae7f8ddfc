"""Who may read the dashboard: Host allow-list parsing, the viewer login's sessions, Basic auth and
rate limit, the settings' validation and the options' errors (exit 78)."""

from __future__ import annotations

import argparse
import base64
import socket
import time

import pytest

from edgedsm.commands import dashboard as command
from edgedsm.dashboard import access
from edgedsm.dashboard.access import AccessSettings, HostGuard, ViewerLogin, host_of
from edgedsm.errors import ConfigError


@pytest.mark.parametrize(("header", "host"), [
    ("localhost", "localhost"), ("LocalHost:8080", "localhost"), ("dash.plant.local.:443", "dash.plant.local"),
    ("[::1]:8080", "::1"), ("[::1]", "::1"), ("127.0.0.1:80", "127.0.0.1"),
    ("", None), (None, None), ("host:port", None), ("[::1", None), ("[::1]x", None), ("a" * 301, None),
])
def test_the_host_of_a_host_header(header: str | None, host: str | None) -> None:
    assert host_of(header) == host


def test_ip_addresses_and_this_machines_names_pass_a_rebinding_name_does_not() -> None:
    guard = HostGuard("0.0.0.0", ["dash.plant.local"])
    for header in ("127.0.0.1:8080", "192.168.7.20:8080", "[::1]:8080", "[fe80::1]", "localhost:8080",
                   f"{socket.gethostname()}:8080", "DASH.plant.local"):
        assert guard.allows(header), header
    for header in ("attacker.example:8080", "dash.plant.local.attacker.example", None, "", "evil:xx"):
        assert not guard.allows(header), header


def test_the_listen_name_is_allowed() -> None:
    assert HostGuard("dash-box", []).allows("dash-box:8080")


def test_a_session_cookie_is_valid_until_it_expires_and_only_its_own() -> None:
    login = ViewerLogin("correct horse", secure=True, session_s=0.2)
    token = login.new_session()
    assert login.session_ok(f"theme=dark; {access.COOKIE}={token}")
    assert not login.session_ok(f"{access.COOKIE}={token[:-1]}x") and not login.session_ok(None)
    cookie = login.cookie(token)
    assert "HttpOnly" in cookie and "SameSite=Strict" in cookie and cookie.endswith("; Secure")
    time.sleep(0.25)
    assert not login.session_ok(f"{access.COOKIE}={token}")


def test_sessions_are_bounded() -> None:
    login = ViewerLogin("correct horse", secure=False, session_s=60)
    first = login.new_session()
    for _ in range(access.MAX_SESSIONS):
        login.new_session()
    assert not login.session_ok(f"{access.COOKIE}={first}") and len(login._sessions) == access.MAX_SESSIONS


def test_basic_auth_carries_the_password() -> None:
    login = ViewerLogin("correct horse", secure=False, session_s=60)
    good = "Basic " + base64.b64encode(b"anyone:correct horse").decode()
    bad = "Basic " + base64.b64encode(b"anyone:wrong horse").decode()
    assert login.basic_ok(good) and not login.basic_ok(bad) and not login.basic_ok("Basic !!!")


def test_failures_are_rate_limited_per_address_and_in_total() -> None:
    login = ViewerLogin("correct horse", secure=False, session_s=60)
    for _ in range(access.FAILURES_PER_CLIENT):
        assert login.limited("10.0.0.1") == 0
        login.failed("10.0.0.1")
    assert 55 < login.limited("10.0.0.1") <= access.FAILURE_WINDOW_S
    assert login.limited("10.0.0.2") == 0
    for i in range(access.FAILURES_TOTAL - access.FAILURES_PER_CLIENT):
        login.failed(f"10.0.1.{i}")
    assert login.limited("10.0.0.99") > 55  # a distributed guess stops everyone for the window


def test_a_short_password_is_refused() -> None:
    with pytest.raises(ConfigError, match="at least 8"):
        ViewerLogin("short", secure=False, session_s=60)


def _args(*argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    command.add_arguments(parser)
    return parser.parse_args(list(argv))


def test_behind_a_proxy_the_per_client_caps_can_reach_the_totals() -> None:
    limits = command.access_settings(_args("--max-per-client", "128", "--max-event-streams-per-client", "32")).limits
    assert (limits.max_per_client, limits.max_event_streams_per_client) == (128, 32)


def test_the_options_make_the_settings() -> None:
    settings = command.access_settings(_args("--allowed-host", "Dash.Plant.Local", "--max-connections", "64",
                                             "--max-per-client", "16", "--max-event-streams", "4",
                                             "--header-timeout", "5", "--idle-timeout", "20"))
    assert settings.allowed_hosts == ["dash.plant.local"]
    got = settings.limits.model_dump()
    assert got == {"max_connections": 64, "max_per_client": 16, "max_event_streams": 4,
                   "max_event_streams_per_client": 4, "header_timeout_s": 5, "idle_timeout_s": 20,
                   "request_timeout_s": 60}


@pytest.mark.parametrize(("argv", "message"), [
    (["--max-per-client", "0"], "--max-per-client: Input should be greater than or equal to 1"),
    (["--max-connections", "8", "--max-per-client", "9"], "max_per_client must not exceed max_connections"),
    (["--header-timeout", "0"], "--header-timeout: Input should be greater than 0"),
    (["--max-event-streams-per-client", "33"], "max_event_streams_per_client must not exceed max_event_streams"),
    (["--allowed-host", "evil.example:80"], "--allowed-host"),
    (["--tls-cert", "x.pem"], "tls_cert and tls_key go together"),
])
def test_bad_options_are_config_errors_naming_them(argv: list[str], message: str) -> None:
    with pytest.raises(ConfigError, match=message.replace("(", r"\(")):
        command.access_settings(_args(*argv))


def test_unreadable_tls_files_are_a_config_error(tmp_path) -> None:
    settings = AccessSettings(tls_cert=tmp_path / "none.crt", tls_key=tmp_path / "none.key")
    with pytest.raises(ConfigError, match="--tls-cert"):
        access.tls_context(settings)


def test_the_viewer_password_comes_from_the_environment_or_the_credential(tmp_path) -> None:
    (tmp_path / command.VIEWER_CREDENTIAL).write_text("from-credential\n")
    assert command.resolve_viewer_password({"CREDENTIALS_DIRECTORY": str(tmp_path)}) == "from-credential"
    assert command.resolve_viewer_password({command.VIEWER_ENV: "from-environment"}) == "from-environment"
    assert command.resolve_viewer_password({}) is None
    with pytest.raises(ConfigError, match="at least 8"):
        command.resolve_viewer_password({command.VIEWER_ENV: "short"})
