"""Connecting to the broker, shared by the daemon's sink and ``edgedsm watch``: the paho client
factory, the TLS context, and connection problems said in one clear sentence, logged at a
bounded rate."""

from __future__ import annotations

import logging
import math
import socket
import ssl
import time
from typing import Any

import paho.mqtt.client as mqtt
from paho.mqtt.enums import CallbackAPIVersion
from paho.mqtt.reasoncodes import ReasonCode

from edgedsm.errors import ConfigError
from edgedsm.publish.settings import PASSWORD_ENV, MqttSettings, MqttTlsSettings

log = logging.getLogger(__name__)

LOG_REPEAT_S = 60.0  # the same connection problem is logged again at most this often
_AUTH_CODES = {"Bad user name or password", "Not authorized", "Bad username or password"}


class _PahoNoiseFilter(logging.Filter):
    """paho 2.2 logs "Client is not connected" at ERROR on every ordinary disconnect (its loop
    polls once more without a socket); demote it so operators are not alarmed by a clean stop."""

    def filter(self, record: logging.LogRecord) -> bool:
        if record.levelno >= logging.ERROR and str(record.msg).startswith("Client is not connected"):
            record.levelno, record.levelname = logging.DEBUG, "DEBUG"
            return logging.getLogger(record.name).isEnabledFor(logging.DEBUG)
        return True


paho_log = logging.getLogger("edgedsm.publish.paho")
paho_log.addFilter(_PahoNoiseFilter())


def build_ssl_context(tls: MqttTlsSettings) -> ssl.SSLContext:
    """Client TLS context: verify the broker against ``ca_file`` (or the system CAs), present the
    client certificate when given; ``insecure`` skips only the host name check."""
    try:
        context = ssl.create_default_context(ssl.Purpose.SERVER_AUTH,
                                             cafile=str(tls.ca_file) if tls.ca_file else None)
    except (ssl.SSLError, OSError) as exc:
        raise ConfigError(f"mqtt.tls.ca_file: {tls.ca_file}: not a usable PEM CA file: {exc}") from None
    if tls.cert_file is not None and tls.key_file is not None:
        try:
            context.load_cert_chain(str(tls.cert_file), str(tls.key_file))
        except (ssl.SSLError, OSError) as exc:
            raise ConfigError(f"mqtt.tls: client certificate {tls.cert_file} with key {tls.key_file} "
                              f"cannot be loaded: {exc}") from None
    if tls.insecure:
        context.check_hostname = False
    return context


def make_client(settings: MqttSettings, *, client_id: str, password: str | None,
                ssl_context: ssl.SSLContext | None, protocol: str | None = None, clean_session: bool = True,
                will_topic: str | None = None) -> mqtt.Client:
    """A paho client (callback API 2) for ``settings``: timeouts, backoff, credentials, TLS and,
    with ``will_topic``, a retained ``offline`` last will. ``protocol`` overrides the settings'.
    Callbacks are the caller's; connect with :func:`connect_in_background`."""
    v5 = (protocol or settings.protocol) == "5"
    client = mqtt.Client(CallbackAPIVersion.VERSION2, client_id=client_id,
                         protocol=mqtt.MQTTv5 if v5 else mqtt.MQTTv311,
                         clean_session=None if v5 else clean_session)
    client.enable_logger(paho_log)  # callback exceptions would be silent otherwise
    client.suppress_exceptions = True  # a bug in a callback must not kill the network thread
    client.connect_timeout = settings.connect_timeout_s
    client.reconnect_delay_set(settings.reconnect_min_s, settings.reconnect_max_s)  # floats work
    if will_topic is not None:
        client.will_set(will_topic, b"offline", qos=1, retain=True)
    if settings.username is not None:
        client.username_pw_set(settings.username, password)
    if ssl_context is not None:
        client.tls_set_context(ssl_context)
        if settings.tls is not None and settings.tls.insecure:
            client.tls_insecure_set(True)
    return client


def connect_in_background(client: mqtt.Client, settings: MqttSettings, *, clean_start: bool = True) -> None:
    """Start paho's network thread connecting (and reconnecting with backoff); returns at once."""
    kwargs: dict[str, Any] = {}
    if client.protocol == mqtt.MQTTv5:
        kwargs["clean_start"] = clean_start
    client.connect_async(settings.host, settings.port, keepalive=settings.keepalive_s, **kwargs)
    client.loop_start()


def refuses_credentials(reason: ReasonCode | str) -> bool:
    """Whether a CONNACK refusal is about who we are (user name, password, authorisation): the
    same credentials will be refused again, whatever the retries."""
    return str(reason) in _AUTH_CODES


def describe_refusal(reason: ReasonCode | str, settings: MqttSettings, password_given: bool) -> str:
    """A CONNACK refusal as one sentence that says what to check."""
    text = f"broker {settings.host}:{settings.port} refused the connection: {reason}"
    if refuses_credentials(reason):
        who = f"user {settings.username!r}" if settings.username else "no user name"
        secret = "a password" if password_given else f"no password (set {PASSWORD_ENV})"
        text += f" (sent {who} with {secret})"
    return text


def diagnose(settings: MqttSettings, context: ssl.SSLContext | None) -> str:
    """Why a connection attempt failed, found by redoing the TCP (and TLS) part ourselves:
    paho's reconnect loop swallows the exception."""
    where = f"{settings.host}:{settings.port}"
    try:
        with socket.create_connection((settings.host, settings.port), timeout=settings.connect_timeout_s) as sock:
            if context is not None:
                with context.wrap_socket(sock, server_hostname=settings.host):
                    pass
    except ssl.SSLCertVerificationError as exc:
        return f"TLS: the certificate of {where} was not accepted: {exc.verify_message or exc}"
    except ssl.SSLError as exc:
        return f"TLS handshake with {where} failed: {exc.reason or exc}"
    except OSError as exc:
        return f"cannot reach {where}: {exc.strerror or exc}"
    return f"connection to {where} failed after TCP{'/TLS' if context else ''} succeeded"


class ProblemLog:
    """Logs a problem once, then again only when it changes or every ``LOG_REPEAT_S``, so a
    broker down for a day does not flood the journal."""

    def __init__(self, logger: logging.Logger = log) -> None:
        self._log = logger
        self._last: tuple[str, float] = ("", -math.inf)

    def due(self) -> bool:
        """True when the next problem would be logged even if unchanged."""
        return time.monotonic() - self._last[1] >= LOG_REPEAT_S

    def report(self, message: str, level: int) -> None:
        now = time.monotonic()
        if message != self._last[0] or now - self._last[1] >= LOG_REPEAT_S:
            self._log.log(level, "%s", message)
            self._last = (message, now)

    def reset(self) -> None:
        """All is well again: the next problem is logged at once."""
        self._last = ("", -math.inf)
