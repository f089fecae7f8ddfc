"""MQTT publisher of the daemon (paho-mqtt 2.x, callback API version 2, paho's network thread).

Topics (``<base>`` = ``<topic_prefix>/<device>``):

=================================  =========================================================
``<base>/availability``            ``online`` / ``offline``; retained; ``offline`` is also the
                                   last will, sent by the broker if we vanish uncleanly
``<base>/state``                   JSON given to :meth:`MqttPublisher.publish_state`; retained,
                                   QoS 0, republished after every (re)connection
``<base>/alerts``                  JSON events with ``seq`` and ``stream``; QoS 1 from the
                                   durable queue (see below)
``<base>/stats``                   JSON statistics plus the publisher's own counters under ``mqtt``
``<base>/map/<name>``              16-bit PNG of a map (``edgedsm.publish.mapcodec``), QoS 0
``<base>/map/<name>/meta``         its JSON meta (offset, scale, shape, seq, t, png_crc32...)
``<base>/cmd/<name>``              commands in (``edgedsm.publish.commands``)
``<base>/cmd/<name>/reply``        their replies (or the request's MQTT v5 Response Topic)
=================================  =========================================================

Delivery of alerts: every alert is first stored in the durable queue (``AlertQueue``, in the
state directory) and removed only when the broker acknowledges it (PUBACK). Unacknowledged
alerts are sent again after a reconnection (by paho) and after a daemon restart (from the
queue). That is *at least once*: a subscriber sees each alert once after deduplicating on
``(stream, seq)`` — ``edgedsm watch`` does. Alerts go out in ``seq`` order except around a
reconnection, when a resent one may follow newer ones: order by ``seq`` if order matters. For
alerts to survive a *broker* restart on their way to a subscriber, the broker must keep its
sessions (mosquitto ``persistence true``) and the subscriber must use a persistent session
(fixed client id, clean session off, QoS 1), as for any MQTT application.

Why state is QoS 0: paho resends unacknowledged QoS 1 messages after a reconnection *after*
our on-connect republish, so a stale QoS 1 state could overwrite the fresh retained one. The
state is republished on every connection anyway, which repairs a lost QoS 0 message.

Why no ``max_queued_messages_set``: it also refuses our own ``online`` after a reconnection
(DESIGN §7). Memory is bounded instead by publishing stats and maps only while connected, by
one map job at a time, and by the alert window (``alerts_in_flight``).

Threads: paho's network thread runs the callbacks; three small workers of ours send alerts
(and write acknowledgements to SQLite, so fsync never stalls the network thread), encode and
send maps, and run command handlers (so a slow handler never stalls keepalives). No public
method waits on the network except :meth:`wait_connected`, :meth:`flush_alerts` and
:meth:`close`, which all take bounded timeouts.
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import queue
import socket
import ssl
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import paho.mqtt.client as mqtt
from paho.mqtt.enums import CallbackAPIVersion, MQTTErrorCode
from paho.mqtt.packettypes import PacketTypes
from paho.mqtt.properties import Properties
from paho.mqtt.reasoncodes import ReasonCode
from pydantic import ValidationError

from edgedsm.errors import ConfigError, EdgedsmError
from edgedsm import _json
from edgedsm.publish.alertqueue import AlertQueue
from edgedsm.publish.commands import COMMANDS, Command
from edgedsm.publish.errors import MapCodecError, PublishError
from edgedsm.publish.mapcodec import encode_map
from edgedsm.publish.settings import PASSWORD_ENV, MqttSettings, MqttTlsSettings, resolve_password

log = logging.getLogger(__name__)


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

CommandHandler = Callable[[str, Command], Mapping[str, Any] | None]
"""``on_command(name, command) -> result``: run a validated command (``command`` is the pydantic
model of ``edgedsm.publish.commands``; ``command.model_dump()`` gives a plain dict). The returned
mapping (or None) becomes the reply's ``result``; to refuse, return ``{"ok": False, "error":
"why"}`` or raise (an EdgedsmError's message is sent as is). Runs in the publisher's command
thread, one command at a time, so it may wait (bounded) for the pipeline."""

COMMAND_BACKLOG = 8          # commands waiting for the handler before "busy" is answered
REQUEST_ID_MAX = 128         # characters of a string request_id
LOG_REPEAT_S = 60.0          # the same connection problem is logged again at most this often
WORKER_POLL_S = 0.25         # how often idle workers look at the stop flag
_AUTH_CODES = {"Bad user name or password", "Not authorized", "Bad username or password"}


@dataclass(frozen=True)
class Topics:
    """Every topic of one device, from ``<prefix>/<device>``."""

    base: str

    @classmethod
    def of(cls, prefix: str, device: str) -> Topics:
        return cls(f"{prefix.strip('/')}/{device}")

    @classmethod
    def from_settings(cls, settings: MqttSettings) -> Topics:
        return cls.of(settings.topic_prefix, settings.device)

    @property
    def availability(self) -> str:
        return f"{self.base}/availability"

    @property
    def state(self) -> str:
        return f"{self.base}/state"

    @property
    def alerts(self) -> str:
        return f"{self.base}/alerts"

    @property
    def stats(self) -> str:
        return f"{self.base}/stats"

    def map(self, name: str) -> str:
        return f"{self.base}/map/{name}"

    def map_meta(self, name: str) -> str:
        return f"{self.base}/map/{name}/meta"

    @property
    def maps_filter(self) -> str:
        """Subscription for every map PNG; metas are ``map/+/meta``."""
        return f"{self.base}/map/+"

    def command(self, name: str) -> str:
        return f"{self.base}/cmd/{name}"

    @property
    def command_filter(self) -> str:
        """What the publisher subscribes to (one level, so replies are not matched)."""
        return f"{self.base}/cmd/+"

    def reply(self, name: str) -> str:
        return f"{self.base}/cmd/{name}/reply"


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


def describe_refusal(reason: ReasonCode | str, settings: MqttSettings, password_given: bool) -> str:
    """A CONNACK refusal as one sentence that says what to check."""
    text = f"broker {settings.host}:{settings.port} refused the connection: {reason}"
    if str(reason) in _AUTH_CODES:
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


class MqttPublisher:
    """Publishes one camera's availability, state, alerts, stats and maps; receives commands.

    ``settings``: the ``[mqtt]`` table. ``state_dir``: where the durable alert queue lives
    (``$STATE_DIRECTORY`` under systemd). ``on_command``: the daemon's command handler (see
    ``CommandHandler``); without one, daemon commands are refused with a reply. ``password``:
    overrides :func:`resolve_password` (tests); ``clock``: monotonic seconds for the cadence.

    Nothing connects until :meth:`start` (or ``with``); the connection is then made and kept
    in the background with backoff between ``reconnect_min_s`` and ``reconnect_max_s``.
    """

    def __init__(self, settings: MqttSettings, state_dir: str | Path, on_command: CommandHandler | None = None,
                 *, password: str | None = None, clock: Callable[[], float] = time.monotonic) -> None:
        self.settings = settings
        self.topics = Topics.from_settings(settings)
        self._on_command = on_command
        self._clock = clock
        self._password = password if password is not None else resolve_password()
        self._ssl_context = build_ssl_context(settings.tls) if settings.tls is not None else None
        self._queue = AlertQueue(Path(state_dir) / f"mqtt-alerts-{settings.device}.sqlite3",
                                 settings.alert_queue_max)
        self._lock = threading.Lock()  # counters; never held while calling paho
        # Held around QoS 0 state publishes only: paho's QoS 0 path takes none of its own locks
        # in threaded mode, so this cannot deadlock with the network thread.
        self._state_lock = threading.Lock()
        self._connected = threading.Event()
        self._ready = threading.Event()  # connected AND subscribed to commands (SUBACK seen)
        self._subscribe_mid: int | None = None
        self._stop = threading.Event()
        self._alert_wake = threading.Event()
        self._acks: deque[tuple[int, ReasonCode]] = deque()   # appended by paho's thread
        self._inflight: dict[int, int] = {}                    # paho mid -> alert seq (alert worker)
        self._sent_upto = 0                                     # highest seq handed to paho
        self._state_payload: bytes | None = None
        # Latest map per name waiting for the map thread; a newer one replaces (and drops) it.
        self._map_jobs: dict[str, tuple[np.ndarray, dict[str, Any]]] = {}
        self._map_wake = threading.Event()
        self._map_sending = False  # the map worker holds a map it has taken off _map_jobs
        # None wakes the command thread at shutdown.
        self._commands: queue.Queue[tuple[str, Command, Any, str | None, bytes | None] | None] = \
            queue.Queue(maxsize=COMMAND_BACKLOG)
        self._last_stats = -math.inf
        self._last_maps = -math.inf
        self._maps_requested = False
        self._counts = {"connects": 0, "disconnects": 0, "alerts_sent": 0, "alerts_acked": 0,
                        "alerts_refused": 0, "stats_dropped": 0, "maps_sent": 0, "maps_dropped": 0,
                        "commands": 0, "commands_refused": 0}
        self._refusal: str | None = None
        self._last_error: str | None = None
        self._logged: tuple[str, float] = ("", -math.inf)
        self._threads: list[threading.Thread] = []
        self._started = False
        self._closed = False
        self._client = self._make_client()

    # -- life cycle --------------------------------------------------------------------------

    def start(self) -> MqttPublisher:
        """Start connecting in the background (returns at once)."""
        if self._closed:
            raise PublishError("this publisher was closed; make a new one")
        if self._started:
            return self
        self._started = True
        for name, target in (("alerts", self._alert_worker), ("maps", self._map_worker),
                             ("commands", self._command_worker)):
            thread = threading.Thread(target=target, name=f"edgedsm-mqtt-{name}", daemon=True)
            thread.start()
            self._threads.append(thread)
        self._client.connect_async(self.settings.host, self.settings.port, keepalive=self.settings.keepalive_s,
                                   **({"clean_start": True} if self.settings.protocol == "5" else {}))
        self._client.loop_start()
        return self

    def wait_connected(self, timeout: float) -> None:
        """Wait (at most ``timeout`` s) until the broker accepted us and our command subscription;
        PublishError saying why not. A refusal by the broker (bad password, not authorised...)
        raises at once.
        """
        deadline = time.monotonic() + timeout
        while not self._ready.wait(0.05):
            if self._refusal is not None:
                raise PublishError(self._refusal)
            if time.monotonic() >= deadline:
                why = self._last_error or "no answer yet"
                raise PublishError(f"no connection to the MQTT broker {self.settings.host}:{self.settings.port} "
                                   f"within {timeout:g} s: {why}")

    @property
    def connected(self) -> bool:
        return self._connected.is_set()

    @property
    def last_error(self) -> str | None:
        """The latest connection problem, or None while all is well."""
        return self._last_error

    def close(self, timeout: float | None = None) -> None:
        """Publish ``offline`` (waiting at most ``shutdown_timeout_s`` for the broker's ack),
        disconnect cleanly and stop every thread; bounded by ``timeout`` (default
        ``shutdown_timeout_s + 0.5`` s). Unacknowledged alerts stay in the queue for next time."""
        if self._closed:
            return
        self._closed = True
        budget = self.settings.shutdown_timeout_s + 0.5 if timeout is None else timeout
        deadline = time.monotonic() + budget
        self._stop.set()
        self._alert_wake.set()
        self._map_wake.set()
        with contextlib.suppress(queue.Full):
            self._commands.put_nowait(None)
        if self._started:
            for thread in self._threads:
                thread.join(timeout=max(0.0, min(0.3, deadline - time.monotonic())))
            if self._connected.is_set():
                info = self._client.publish(self.topics.availability, b"offline", qos=1, retain=True)
                with contextlib.suppress(RuntimeError, ValueError):  # not queued: nothing to wait for
                    info.wait_for_publish(timeout=max(0.0, min(self.settings.shutdown_timeout_s,
                                                              deadline - time.monotonic())))
            self._client.disconnect()
            # loop_stop() joins paho's thread, which may sit in a connect attempt: bound it.
            stopper = threading.Thread(target=self._client.loop_stop, name="edgedsm-mqtt-stop", daemon=True)
            stopper.start()
            stopper.join(timeout=max(0.05, deadline - time.monotonic()))
        self._connected.clear()
        self._ready.clear()
        if any(thread.is_alive() for thread in self._threads):
            log.warning("MQTT worker still busy at shutdown; leaving the alert queue open")
        else:
            self._queue.close()

    def __enter__(self) -> MqttPublisher:
        return self.start()

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    # -- publishing --------------------------------------------------------------------------

    def publish_state(self, state: Mapping[str, Any]) -> None:
        """Retained state (e.g. ``{"t": ..., "regions": {"A": {"state": "wet", "activity": 0.3,
        "since": ...}}}``); kept and republished on every (re)connection."""
        payload = _json.dumps(state)
        with self._state_lock:  # vs. _on_connect: the newest state must be the last one sent
            self._state_payload = payload
            if self._connected.is_set():
                self._client.publish(self.topics.state, payload, qos=0, retain=True)

    def publish_alert(self, alert: Mapping[str, Any]) -> int:
        """Store the alert durably and send it (QoS 1) as soon as possible; returns its ``seq``.

        Suggested keys: ``type, region, from, to, activity, t``; ``seq`` and ``stream`` are set
        here. Raises PublishError if it cannot be stored (it is then not sent either).
        """
        item = self._queue.put(alert)
        self._alert_wake.set()
        return item.seq

    def stats_due(self) -> bool:
        """True when ``stats_interval_s`` has passed since the last :meth:`publish_stats`."""
        return self._clock() - self._last_stats >= self.settings.stats_interval_s

    def publish_stats(self, stats: Mapping[str, Any]) -> bool:
        """Send a statistics message now (QoS 0) with the publisher's counters added under
        ``mqtt``; False (and counted) when not connected."""
        self._last_stats = self._clock()
        if not self._connected.is_set():
            self._count("stats_dropped")
            return False
        payload = _json.dumps({**stats, "mqtt": self.counters()})
        return self._client.publish(self.topics.stats, payload, qos=0).rc == MQTTErrorCode.MQTT_ERR_SUCCESS

    def maps_due(self) -> bool:
        """True when ``maps_interval_s`` has passed or a ``cmd/publish_maps`` asked for maps."""
        return self._maps_requested or self._clock() - self._last_maps >= self.settings.maps_interval_s

    def request_maps(self) -> None:
        """Make :meth:`maps_due` true at once (what ``cmd/publish_maps`` does)."""
        self._maps_requested = True

    def publish_maps(self, maps: Mapping[str, np.ndarray], *, seq: int | None = None, t: float | None = None,
                     window: int | None = None, lag: int | None = None,
                     extra: Mapping[str, Any] | None = None) -> bool:
        """:meth:`publish_map` for each of ``maps`` (name -> 2-D float array) with one shared meta;
        True if every one was accepted."""
        meta = {**(extra or {}), "seq": seq, "t": t, "window": window, "lag": lag}
        return all([self.publish_map(name, values, meta) for name, values in maps.items()])

    def publish_map(self, name: str, values: np.ndarray, meta: Mapping[str, Any] | None = None) -> bool:
        """Hand one map to the map thread, which downsamples, encodes and sends it as PNG + meta
        (``edgedsm.publish.mapcodec``). Returns at once; False (counted) when not connected.

        ``meta``: ``seq`` (frame number the map belongs to; ``frames`` is taken when there is no
        ``seq``), ``t`` (s since the epoch), ``window``, ``lag``; other keys are passed through
        into the published meta. If the previous map of the same name has not left yet it is
        replaced by this one (counted as dropped), so a slow link never piles maps up. The array
        is read after this returns: pass one nobody modifies (``SlidingWindow.maps()`` makes new
        ones).
        """
        self._last_maps = self._clock()
        self._maps_requested = False
        if not self._connected.is_set():
            self._count("maps_dropped")
            return False
        info = dict(meta or {})
        if info.get("estimator") == name:
            del info["estimator"]  # the codec writes it
        if "seq" not in info and "frames" in info:
            info["seq"] = info["frames"]
        with self._lock:
            replaced = self._map_jobs.pop(str(name), None) is not None
            self._map_jobs[str(name)] = (values, info)
            if replaced:
                self._counts["maps_dropped"] += 1
        self._map_wake.set()
        return True

    def flush_maps(self, timeout: float) -> bool:
        """Wait at most ``timeout`` s until every map handed over has left (or was dropped);
        True if so. ``close()`` abandons maps still waiting, so a finite run flushes first."""
        deadline = time.monotonic() + timeout
        while True:
            with self._lock:
                idle = not self._map_jobs and not self._map_sending
            if idle:
                return True
            if time.monotonic() >= deadline:
                return False
            self._map_wake.set()
            time.sleep(0.02)

    def flush_alerts(self, timeout: float) -> bool:
        """Wait at most ``timeout`` s until every queued alert is acknowledged; True if so."""
        deadline = time.monotonic() + timeout
        while len(self._queue) > 0:
            if time.monotonic() >= deadline:
                return False
            self._alert_wake.set()
            time.sleep(0.02)
        return True

    @property
    def alert_stream(self) -> str:
        """The ``stream`` id written into every alert (with ``seq``, the deduplication key)."""
        return self._queue.stream

    @property
    def pending_alerts(self) -> int:
        """Alerts stored and not yet acknowledged by the broker."""
        return len(self._queue)

    def counters(self) -> dict[str, Any]:
        """Health of the link: connected, alerts pending/dropped, messages dropped, reconnects."""
        with self._lock:
            counts = dict(self._counts)
        return {"connected": self._connected.is_set(), "alerts_pending": len(self._queue),
                "alerts_dropped": self._queue.dropped, **counts}

    # -- paho client and callbacks (paho's network thread) -------------------------------------

    def _make_client(self) -> mqtt.Client:
        settings = self.settings
        v5 = settings.protocol == "5"
        client = mqtt.Client(CallbackAPIVersion.VERSION2, client_id=settings.effective_client_id,
                             protocol=mqtt.MQTTv5 if v5 else mqtt.MQTTv311,
                             clean_session=None if v5 else True)
        client.enable_logger(paho_log)  # callback exceptions would be silent otherwise
        client.suppress_exceptions = True  # a bug in a callback must not kill the network thread
        client.connect_timeout = settings.connect_timeout_s
        client.reconnect_delay_set(settings.reconnect_min_s, settings.reconnect_max_s)  # floats work
        client.will_set(self.topics.availability, b"offline", qos=1, retain=True)
        if settings.username is not None:
            client.username_pw_set(settings.username, self._password)
        if self._ssl_context is not None:
            client.tls_set_context(self._ssl_context)
            if settings.tls is not None and settings.tls.insecure:
                client.tls_insecure_set(True)
        client.on_connect = self._on_connect
        client.on_connect_fail = self._on_connect_fail
        client.on_disconnect = self._on_disconnect
        client.on_subscribe = self._on_subscribe
        client.on_publish = self._on_publish
        client.on_message = self._on_message
        return client

    def _on_connect(self, client: mqtt.Client, userdata: Any, flags: Any, reason: ReasonCode,
                    properties: Properties | None) -> None:
        if reason.is_failure:
            message = describe_refusal(reason, self.settings, self._password is not None)
            self._refusal = self._last_error = message
            self._log_problem(message, logging.ERROR)
            return
        self._refusal = self._last_error = None
        self._logged = ("", -math.inf)
        self._count("connects")
        log.info("MQTT connected to %s:%d as %r", self.settings.host, self.settings.port,
                 self.settings.effective_client_id)
        client.publish(self.topics.availability, b"online", qos=1, retain=True)
        _, self._subscribe_mid = client.subscribe(self.topics.command_filter, qos=1)
        with self._state_lock:
            self._connected.set()
            if self._state_payload is not None:
                client.publish(self.topics.state, self._state_payload, qos=0, retain=True)
        self._alert_wake.set()

    def _on_subscribe(self, client: mqtt.Client, userdata: Any, mid: int, reasons: list[ReasonCode],
                      properties: Properties | None) -> None:
        if mid != self._subscribe_mid:
            return
        failed = [str(reason) for reason in reasons if reason.is_failure]
        if failed:  # e.g. an ACL: publishing still works, commands will not arrive
            self._last_error = f"broker refused the subscription to {self.topics.command_filter}: {failed[0]}"
            log.error("MQTT: %s; commands will not be received", self._last_error)
        self._ready.set()

    def _on_connect_fail(self, client: mqtt.Client, userdata: Any) -> None:
        self._connected.clear()
        self._ready.clear()
        now = time.monotonic()
        if now - self._logged[1] >= LOG_REPEAT_S or self._last_error is None:
            # Costs one extra connection attempt, so only when we are about to log anyway.
            self._last_error = diagnose(self.settings, self._ssl_context)
        self._log_problem(f"MQTT: {self._last_error}; retrying", logging.WARNING)

    def _on_disconnect(self, client: mqtt.Client, userdata: Any, flags: Any, reason: ReasonCode,
                       properties: Properties | None) -> None:
        was_connected = self._connected.is_set()
        self._connected.clear()
        self._ready.clear()
        if self._closed:
            return
        if was_connected:
            self._count("disconnects")
            self._last_error = f"connection lost: {reason}"
            log.warning("MQTT connection to %s:%d lost (%s); reconnecting", self.settings.host,
                        self.settings.port, reason)

    def _on_publish(self, client: mqtt.Client, userdata: Any, mid: int, reason: ReasonCode,
                    properties: Properties | None) -> None:
        # Called with paho's message lock held: only hand the ack over to the alert worker.
        self._acks.append((mid, reason))
        self._alert_wake.set()

    def _on_message(self, client: mqtt.Client, userdata: Any, message: mqtt.MQTTMessage) -> None:
        try:
            self._receive_command(message)
        except Exception:  # never let one message take the network thread down
            log.exception("MQTT: error while handling a message on %r", message.topic)

    # -- commands ----------------------------------------------------------------------------

    def _receive_command(self, message: mqtt.MQTTMessage) -> None:
        prefix = f"{self.topics.base}/cmd/"
        if not message.topic.startswith(prefix):
            return
        name = message.topic[len(prefix):]
        props = getattr(message, "properties", None)
        reply_to = getattr(props, "ResponseTopic", None) or None
        correlation = getattr(props, "CorrelationData", None) or None
        if reply_to is not None and any(c in reply_to for c in "#+"):
            reply_to = None  # a wildcard topic cannot be published to
        request_id: Any = None

        def refuse(reason: str) -> None:
            self._count("commands_refused")
            log.warning("MQTT command %r refused: %s", name, reason)
            self._reply(name, request_id, reply_to, correlation, ok=False, error=reason)

        if not message.payload:
            # Zero bytes is how a retained message is cleared; the clearing is delivered too.
            log.debug("MQTT: empty message on %r ignored", message.topic)
            return
        if message.retain:
            refuse(f"retained commands are refused (they would run again on every reconnection); "
                   f"clear it with: mosquitto_pub -r -n -t '{message.topic}'")
            return
        try:
            data = json.loads(message.payload.decode("utf-8"))
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            refuse(f"payload is not valid JSON: {exc}")
            return
        if not isinstance(data, dict):
            refuse(f"payload must be a JSON object, got {type(data).__name__}")
            return
        request_id = data.pop("request_id", None)
        if request_id is not None and not (
                (isinstance(request_id, str) and len(request_id) <= REQUEST_ID_MAX)
                or (isinstance(request_id, int) and not isinstance(request_id, bool))):
            request_id = None
            refuse(f"request_id must be a string of at most {REQUEST_ID_MAX} characters or an integer")
            return
        model = COMMANDS.get(name)
        if model is None:
            refuse(f"unknown command {name!r}; known commands: {', '.join(COMMANDS)}")
            return
        try:
            command = model.model_validate(data)
        except ValidationError as exc:
            refuse("; ".join(f"{'.'.join(str(p) for p in err['loc']) or 'payload'}: "
                             f"{'unknown key' if err['type'] == 'extra_forbidden' else err['msg']}"
                             for err in exc.errors()))
            return
        if name == "publish_maps":
            self.request_maps()  # for callers that pace maps with maps_due()
            if self._on_command is None:
                self._count("commands")
                self._reply(name, request_id, reply_to, correlation, ok=True, result={"scheduled": True})
                return
        if self._on_command is None:
            refuse("this process does not carry out commands (no handler)")
            return
        try:
            self._commands.put_nowait((name, command, request_id, reply_to, correlation))
        except queue.Full:
            refuse(f"busy: {COMMAND_BACKLOG} commands are already waiting; try again")

    def _command_worker(self) -> None:
        while not self._stop.is_set():
            try:
                item = self._commands.get(timeout=WORKER_POLL_S)
            except queue.Empty:
                continue
            if item is None:
                return
            name, command, request_id, reply_to, correlation = item
            assert self._on_command is not None
            try:
                result = dict(self._on_command(name, command) or {})
            except EdgedsmError as exc:
                self._count("commands_refused")
                self._reply(name, request_id, reply_to, correlation, ok=False, error=str(exc))
                continue
            except Exception as exc:
                log.exception("MQTT command %r failed in its handler", name)
                self._count("commands_refused")
                self._reply(name, request_id, reply_to, correlation, ok=False,
                            error=f"internal error: {type(exc).__name__}: {exc}")
                continue
            # A handler may answer {"ok": False, "error": "..."} instead of raising.
            ok = result.pop("ok", True) is not False
            error = result.pop("error", None)
            self._count("commands" if ok else "commands_refused")
            self._reply(name, request_id, reply_to, correlation, ok=ok,
                        error=None if ok else str(error or "refused by the handler"), result=result or None)

    def _reply(self, name: str, request_id: Any, reply_to: str | None, correlation: bytes | None, *,
               ok: bool, error: str | None = None, result: Mapping[str, Any] | None = None) -> None:
        body = {"ok": ok, "command": name, "request_id": request_id, "error": error,
                "result": result, "t": time.time()}
        try:
            payload = _json.dumps(body)
        except (TypeError, ValueError) as exc:
            payload = _json.dumps({**body, "ok": False, "result": None,
                                   "error": f"handler result is not JSON: {exc}"})
        properties = None
        if correlation is not None and self.settings.protocol == "5":
            properties = Properties(PacketTypes.PUBLISH)
            properties.CorrelationData = correlation
        self._client.publish(reply_to or self.topics.reply(name), payload, qos=1, properties=properties)

    # -- alerts --------------------------------------------------------------------------------

    def _alert_worker(self) -> None:
        while not self._stop.is_set():
            self._alert_wake.wait(WORKER_POLL_S)
            self._alert_wake.clear()
            try:
                self._settle_acks()
                self._send_alerts()
            except Exception:  # keep the worker alive; the queue still holds every alert
                log.exception("MQTT alert worker error")
                self._stop.wait(1.0)

    def _settle_acks(self) -> None:
        while self._acks:
            mid, reason = self._acks.popleft()
            seq = self._inflight.pop(mid, None)
            if seq is None:
                continue  # a QoS 0 message or a reply, not an alert
            if reason.is_failure:
                # The broker will never take it (e.g. ACL): retrying would block the queue forever.
                self._count("alerts_refused")
                log.error("broker refused alert %d (%s); dropped", seq, reason)
            else:
                self._count("alerts_acked")
            self._queue.ack(seq)

    def _send_alerts(self) -> None:
        room = self.settings.alerts_in_flight - len(self._inflight)
        if room <= 0 or not self._connected.is_set():
            return
        for item in self._queue.pending(after_seq=self._sent_upto, limit=room):
            if not self._connected.is_set():
                return
            info = self._client.publish(self.topics.alerts, item.payload, qos=1)
            if info.rc not in (MQTTErrorCode.MQTT_ERR_SUCCESS, MQTTErrorCode.MQTT_ERR_NO_CONN):
                log.error("paho refused alert %d: %s; will retry", item.seq, mqtt.error_string(info.rc))
                return
            # NO_CONN still means "stored by paho and sent after the reconnection".
            self._inflight[info.mid] = item.seq
            self._sent_upto = item.seq
            self._count("alerts_sent")

    # -- maps ----------------------------------------------------------------------------------

    def _map_worker(self) -> None:
        while not self._stop.is_set():
            self._map_wake.wait(WORKER_POLL_S)
            self._map_wake.clear()
            while not self._stop.is_set():
                with self._lock:
                    if not self._map_jobs:
                        break
                    name = next(iter(self._map_jobs))
                    values, meta = self._map_jobs.pop(name)
                    self._map_sending = True
                try:
                    if not self._connected.is_set():
                        self._count("maps_dropped")
                        continue
                    self._send_map(name, values, meta)
                except Exception:  # keep the worker alive for the next maps
                    self._count("maps_dropped")
                    log.exception("map %r could not be published", name)
                finally:
                    with self._lock:
                        self._map_sending = False

    def _send_map(self, name: str, values: np.ndarray, meta: dict[str, Any]) -> None:
        extra = {key: value for key, value in meta.items() if key not in ("seq", "t", "window", "lag")}
        try:
            png, info = encode_map(values, estimator=name, seq=meta.get("seq"), t=meta.get("t"),
                                   window=meta.get("window"), lag=meta.get("lag"),
                                   max_size=self.settings.map_max_size,
                                   compression=self.settings.map_png_compression, extra=extra)
        except MapCodecError as exc:
            self._count("maps_dropped")
            log.error("map %r not published: %s", name, exc)
            return
        # Meta first: a subscriber that pairs by png_crc32 does not care, one that takes "the last
        # meta" gets the right one.
        self._client.publish(self.topics.map_meta(name), _json.dumps(info), qos=0)
        sent = self._client.publish(self.topics.map(name), png, qos=0)
        # Back-pressure: wait (in this thread only) until the PNG left, so maps never pile up.
        deadline = time.monotonic() + max(5.0, self.settings.maps_interval_s)
        while not sent.is_published() and sent.rc == MQTTErrorCode.MQTT_ERR_SUCCESS:
            if self._stop.is_set() or time.monotonic() >= deadline:
                return
            time.sleep(0.01)
        self._count("maps_sent")

    # -- helpers -------------------------------------------------------------------------------

    def _count(self, key: str, amount: int = 1) -> None:
        with self._lock:
            self._counts[key] += amount

    def _log_problem(self, message: str, level: int) -> None:
        """Log a connection problem once, then again only when it changes or every minute."""
        now = time.monotonic()
        last_message, last_time = self._logged
        if message != last_message or now - last_time >= LOG_REPEAT_S:
            log.log(level, "%s", message)
            self._logged = (message, now)
