"""Who may read the dashboard: the Host allow-list (against DNS rebinding), the optional viewer
login (a password, a session cookie, failures rate-limited) and the optional HTTPS context
(docs/dashboard.md, "Security"). Connection limits and timeouts are ``edgedsm.publish.http_guard``'s."""

from __future__ import annotations

import base64
import hashlib
import hmac
import ipaddress
import logging
import re
import secrets
import socket
import ssl
import threading
import time
from collections import deque
from http import HTTPStatus
from pathlib import Path
from typing import Any
from urllib.parse import parse_qs

from pydantic import Field, field_validator, model_validator

from edgedsm.errors import ConfigError
from edgedsm.publish.http_guard import ConnectionLimits
from edgedsm.validation import StrictModel

log = logging.getLogger(__name__)

HOST_NAME_PATTERN = r"^[A-Za-z0-9]([A-Za-z0-9.-]{0,252})$"
COOKIE = "edgedsm_session"
MIN_PASSWORD = 8
FAILURE_WINDOW_S = 60.0
FAILURES_PER_CLIENT = 5  # wrong passwords from one address per window, then 429 until the window passes
FAILURES_TOTAL = 30  # from all addresses per window (a distributed guess), then 429 for everyone
MAX_SESSIONS = 256  # the oldest session is dropped beyond this
MAX_FAILING_CLIENTS = 4096  # addresses remembered with their failures (beyond, only the total counts)
LOGIN_BODY = 4096
LOGIN_CSP = ("default-src 'none'; style-src 'unsafe-inline'; form-action 'self'; frame-ancestors 'none'; "
             "base-uri 'none'")


class AccessSettings(StrictModel):
    """The dashboard's web-facing settings beside ``--listen``."""

    allowed_hosts: list[str] = Field(default_factory=list, max_length=64,
                                     description="extra host names the page may be reached by (the Host header); "
                                                 "IP addresses, localhost and this machine's names always are")
    tls_cert: Path | None = Field(None, description="PEM certificate (chain) for HTTPS; with tls_key")
    tls_key: Path | None = Field(None, description="PEM private key for HTTPS; with tls_cert")
    session_hours: float = Field(12.0, gt=0, le=720, description="a viewer login lasts this long")
    limits: ConnectionLimits = Field(default_factory=ConnectionLimits,
                                     description="connection caps and timeouts (edgedsm.publish.http_guard)")

    @field_validator("allowed_hosts")
    @classmethod
    def _names(cls, names: list[str]) -> list[str]:
        for name in names:
            if not re.match(HOST_NAME_PATTERN, name):
                raise ValueError(f"{name!r} is not a host name (letters, digits, '.', '-'; no port)")
        return [name.lower().rstrip(".") for name in names]

    @model_validator(mode="after")
    def _pair(self) -> AccessSettings:
        if (self.tls_cert is None) != (self.tls_key is None):
            raise ValueError("tls_cert and tls_key go together")
        return self


def tls_context(settings: AccessSettings) -> ssl.SSLContext | None:
    """The server's TLS context (TLS 1.2 or newer), or None for plain HTTP; unreadable files are a
    config error."""
    if settings.tls_cert is None or settings.tls_key is None:
        return None
    context = ssl.create_default_context(ssl.Purpose.CLIENT_AUTH)
    context.minimum_version = ssl.TLSVersion.TLSv1_2
    try:
        context.load_cert_chain(settings.tls_cert, settings.tls_key)
    except (OSError, ssl.SSLError) as exc:
        raise ConfigError(f"--tls-cert {settings.tls_cert} / --tls-key {settings.tls_key}: {exc}") from None
    return context


class HostGuard:
    """Accepts a request only if its Host header names this server: any IP address (a browser sends
    the address itself, which DNS rebinding cannot forge), ``localhost``, this machine's host name and
    FQDN, the listen address and the configured names. A name an attacker's DNS points here is refused."""

    def __init__(self, listen_host: str, extra: list[str]) -> None:
        names = {"localhost", socket.gethostname(), socket.getfqdn(), listen_host, *extra}
        self.names = {name.lower().rstrip(".") for name in names if name}

    def allows(self, header: str | None) -> bool:
        host = host_of(header)
        if host is None:
            return False
        try:
            ipaddress.ip_address(host)
            return True
        except ValueError:
            return host in self.names


def host_of(header: str | None) -> str | None:
    """The host of a Host header (``name``, ``name:port``, ``[v6]:port``), lower case; None if malformed."""
    if not header or len(header) > 300:
        return None
    header = header.strip()
    if header.startswith("["):
        end = header.find("]")
        rest = header[end + 1:]
        if end < 0 or (rest and not (rest.startswith(":") and rest[1:].isdigit())):
            return None
        return header[1:end].lower()
    host, colon, port = header.partition(":")
    if colon and not port.isdigit():
        return None
    return host.lower().rstrip(".") or None


class ViewerLogin:
    """A password to view the page: ``POST /login`` sets an HttpOnly, SameSite=Strict session cookie
    (Secure over HTTPS); scripts may send HTTP Basic auth with the password instead. Passwords are
    compared in constant time; failures are rate-limited per address and in total."""

    def __init__(self, password: str, *, secure: bool, session_s: float) -> None:
        if len(password) < MIN_PASSWORD:
            raise ConfigError(f"the viewer password must have at least {MIN_PASSWORD} characters")
        self._password = hashlib.sha256(password.encode()).digest()
        self.secure = secure
        self.session_s = session_s
        self._sessions: dict[bytes, float] = {}  # sha256(cookie) -> expiry (monotonic)
        self._failures: dict[str, deque[float]] = {}
        self._all_failures: deque[float] = deque()
        self._lock = threading.Lock()

    def password_ok(self, given: str) -> bool:
        return hmac.compare_digest(hashlib.sha256(given.encode()).digest(), self._password)

    def session_ok(self, cookie_header: str | None) -> bool:
        token = _cookie(cookie_header, COOKIE)
        if not token:
            return False
        key = hashlib.sha256(token.encode()).digest()
        with self._lock:
            expiry = self._sessions.get(key)
            if expiry is not None and expiry < time.monotonic():
                del self._sessions[key]
                expiry = None
        return expiry is not None

    def basic_ok(self, authorization: str | None) -> bool:
        if not authorization or not authorization.startswith("Basic "):
            return False
        try:
            _, _, password = base64.b64decode(authorization[6:], validate=True).decode().partition(":")
        except ValueError:
            return False
        return self.password_ok(password)

    def limited(self, client: str) -> float:
        """Seconds until ``client`` may try again (0: now)."""
        now = time.monotonic()
        with self._lock:
            self._prune(now)
            mine = self._failures.get(client, deque())
            waits = [mine[0] + FAILURE_WINDOW_S - now if len(mine) >= FAILURES_PER_CLIENT else 0.0,
                     self._all_failures[0] + FAILURE_WINDOW_S - now
                     if len(self._all_failures) >= FAILURES_TOTAL else 0.0]
        return max(0.0, *waits)

    def failed(self, client: str) -> None:
        now = time.monotonic()
        with self._lock:
            self._prune(now)
            self._all_failures.append(now)
            if client in self._failures or len(self._failures) < MAX_FAILING_CLIENTS:  # memory stays bounded
                self._failures.setdefault(client, deque()).append(now)

    def _prune(self, now: float) -> None:
        while self._all_failures and self._all_failures[0] < now - FAILURE_WINDOW_S:
            self._all_failures.popleft()
        for client in [c for c, times in self._failures.items() if times[-1] < now - FAILURE_WINDOW_S]:
            del self._failures[client]
        for times in self._failures.values():
            while times and times[0] < now - FAILURE_WINDOW_S:
                times.popleft()

    def new_session(self) -> str:
        token = secrets.token_urlsafe(32)
        with self._lock:
            now = time.monotonic()
            for key in [k for k, expiry in self._sessions.items() if expiry < now]:
                del self._sessions[key]
            while len(self._sessions) >= MAX_SESSIONS:
                del self._sessions[next(iter(self._sessions))]
            self._sessions[hashlib.sha256(token.encode()).digest()] = now + self.session_s
        return token

    def cookie(self, token: str) -> str:
        return (f"{COOKIE}={token}; Path=/; HttpOnly; SameSite=Strict; Max-Age={int(self.session_s)}"
                + ("; Secure" if self.secure else ""))


def _cookie(header: str | None, name: str) -> str | None:
    for part in (header or "").split(";"):
        key, _, value = part.strip().partition("=")
        if key == name:
            return value
    return None


LOGIN_PAGE = """<!doctype html>
<html lang="en"><head><meta charset="utf-8"><meta name="viewport" content="width=device-width, initial-scale=1">
<title>edgedsm plant dashboard: login</title>
<style>body{font-family:system-ui,sans-serif;max-width:22rem;margin:4rem auto}input,button{font-size:1rem}
.error{color:#b00}</style></head>
<body><h1>edgedsm plant dashboard</h1><p class="error">%s</p>
<form method="post" action="/login"><label>password <input id="password" name="password" type="password"
autocomplete="current-password" autofocus required></label> <button id="login" type="submit">view</button></form>
</body></html>
"""


def gate(handler: Any) -> bool:
    """Whether the request may go on to the dashboard's routes; answers it otherwise (421 for a
    foreign Host, the login page and form, 303 to it or 401 without a login)."""
    server = handler.server
    if not server.hosts.allows(handler.headers.get("Host")):
        handler.close_connection = True
        _reply(handler, HTTPStatus.MISDIRECTED_REQUEST,
               b'{"error": "unknown Host: add it with --allowed-host NAME"}', "application/json")
        return False
    login: ViewerLogin | None = server.login
    if login is None:
        return True
    path = handler.path.split("?", 1)[0]
    if path == "/login":
        if handler.command == "POST":
            _login(handler, login)
        else:
            _login_page(handler, "wrong password" if "failed" in handler.path else "", HTTPStatus.OK)
        return False
    if login.session_ok(handler.headers.get("Cookie")):
        return True
    authorization = handler.headers.get("Authorization", "")
    if authorization.startswith("Basic "):  # a script's password: rate-limited as the form's
        client = handler.client_address[0]
        wait = login.limited(client)
        if wait > 0:
            handler.close_connection = True
            _reply(handler, HTTPStatus.TOO_MANY_REQUESTS, b'{"error": "too many wrong passwords"}',
                   "application/json", {"Retry-After": str(max(1, round(wait)))})
            return False
        if login.basic_ok(authorization):
            return True
        login.failed(client)
        log.warning("dashboard: wrong viewer password (basic auth) from %s", client)
    handler.close_connection = handler.command != "GET"  # a body left unread must not become a request
    if handler.command == "GET" and path in ("/", "/index.html"):
        _reply(handler, HTTPStatus.SEE_OTHER, b"", "text/plain", {"Location": "/login"})
    else:
        _reply(handler, HTTPStatus.UNAUTHORIZED, b'{"error": "login required"}', "application/json")
    return False


def _login(handler: Any, login: ViewerLogin) -> None:
    client = handler.client_address[0]
    wait = login.limited(client)
    if wait > 0:
        handler.close_connection = True
        _login_page(handler, f"too many wrong passwords: try again in {wait:.0f} s", HTTPStatus.TOO_MANY_REQUESTS,
                    {"Retry-After": str(max(1, round(wait)))})
        return
    try:
        length = int(handler.headers.get("Content-Length", "0"))
    except ValueError:
        length = -1
    if not 0 <= length <= LOGIN_BODY:
        handler.close_connection = True
        _reply(handler, HTTPStatus.BAD_REQUEST, b'{"error": "bad login form"}', "application/json")
        return
    form = parse_qs(handler.rfile.read(length).decode("utf-8", "replace"), max_num_fields=4)
    if login.password_ok((form.get("password") or [""])[0]):
        _reply(handler, HTTPStatus.SEE_OTHER, b"", "text/plain",
               {"Location": "/", "Set-Cookie": login.cookie(login.new_session())})
        return
    login.failed(client)
    log.warning("dashboard: wrong viewer password from %s", client)
    _reply(handler, HTTPStatus.SEE_OTHER, b"", "text/plain", {"Location": "/login?failed"})


def _login_page(handler: Any, message: str, status: HTTPStatus, extra: dict[str, str] | None = None) -> None:
    _reply(handler, status, (LOGIN_PAGE % message).encode(), "text/html; charset=utf-8", extra)


def _reply(handler: Any, status: HTTPStatus, body: bytes, kind: str, extra: dict[str, str] | None = None) -> None:
    handler.send_response(status)
    handler.send_header("Content-Type", kind)
    handler.send_header("Content-Length", str(len(body)))
    handler.send_header("Cache-Control", "no-store")
    handler.send_header("Content-Security-Policy", LOGIN_CSP)
    handler.send_header("X-Content-Type-Options", "nosniff")
    for key, value in (extra or {}).items():
        handler.send_header(key, value)
    if handler.close_connection:
        handler.send_header("Connection", "close")
    handler.end_headers()
    handler.wfile.write(body)
