"""The MQTT link of the daemon (paho-mqtt 2.x, callback API version 2, paho's network thread):
one connection (:class:`edgedsm.publish.session.MqttSession`, which Home Assistant's discovery
shares), composed of small collaborators.

=================================  =========================================================
``<base>/availability``            ``online`` / ``offline``; retained; ``offline`` is also the
                                   last will, sent by the broker if we vanish uncleanly
``<base>/state``                   JSON; retained, QoS 0, republished after every (re)connection
``<base>/alerts``                  JSON events with ``seq`` and ``stream``; QoS 1 from the
                                   alert store (``alert_sender``, ``alertstore``)
``<base>/stats``                   JSON statistics plus the link's own counters under ``mqtt``
``<base>/map/<name>``              16-bit PNG of a map (``map_sender``, ``mapcodec``), QoS 0
``<base>/map/<name>/meta``         its JSON meta (offset, scale, shape, seq, t, png_crc32...)
``<base>/cmd/<name>``              commands in (``command_channel``, ``commands``)
``<base>/cmd/<name>/reply``        their replies (only there: an MQTT v5 Response Topic is ignored)
=================================  =========================================================

``<base>`` is ``<topic_prefix>/<device>`` (:class:`edgedsm.publish.topics.Topics`); payloads
are the typed messages of ``edgedsm.messages`` (see :class:`edgedsm.publish.json_sink.MqttSink`
and ``docs/mqtt.md``).

Delivery of alerts: every alert is first stored (on disk in the state directory; in memory
while the disk refuses writes, see ``alertstore``) and forgotten only when the broker
acknowledges it (PUBACK). Unacknowledged alerts are sent again after a reconnection (by paho)
and after a daemon restart (from the disk). That is *at least once*: a subscriber sees each
alert once after deduplicating on ``(stream, seq)`` — ``edgedsm watch`` does. Alerts go out in
``seq`` order except around a reconnection, when a resent one may follow newer ones. For alerts
to survive a *broker* restart on their way to a subscriber, the broker must keep its sessions
(mosquitto ``persistence true``) and the subscriber must use a persistent session.

Why state is QoS 0: paho resends unacknowledged QoS 1 messages after a reconnection *after*
our on-connect republish, so a stale QoS 1 state could overwrite the fresh retained one. The
state is republished on every connection anyway, which repairs a lost QoS 0 message.

Why no ``max_queued_messages_set``: it also refuses our own ``online`` after a reconnection.
Memory is bounded instead by publishing stats and maps only while connected, by one map job per
name, and by the alert window (``alerts_in_flight``).

Threads: paho's network thread runs the callbacks; three workers send alerts, send maps and run
command handlers, so neither fsync nor PNG encoding nor a slow handler stalls keepalives. No
public method waits on the network except :meth:`wait_connected`, the flushes and :meth:`close`,
which all take bounded timeouts.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import paho.mqtt.client as mqtt
from paho.mqtt.enums import MQTTErrorCode
from paho.mqtt.properties import Properties
from paho.mqtt.reasoncodes import ReasonCode

from edgedsm import _json
from edgedsm.errors import ConfigError
from edgedsm.publish.alert_sender import AlertSender
from edgedsm.publish.alertqueue import AlertQueue
from edgedsm.publish.alertstore import AlertStore
from edgedsm.publish.command_auth import CommandVerifier
from edgedsm.publish.command_channel import CommandChannel, CommandHandler
from edgedsm.publish.counters import Counters
from edgedsm.publish.errors import PublishError, StorageError
from edgedsm.publish.map_sender import MapSender
from edgedsm.publish.session import MqttSession
from edgedsm.publish.settings import COMMAND_KEY_CREDENTIAL, COMMAND_KEY_ENV, MqttSettings, resolve_command_keys
from edgedsm.publish.topics import Topics

log = logging.getLogger(__name__)

__all__ = ["CommandHandler", "MqttPublisher", "Topics"]


def open_alert_queue(settings: MqttSettings, state_dir: str | Path) -> AlertQueue:
    """The durable alert queue in ``state_dir``; ConfigError naming ``device.state_dir`` when the
    directory cannot be created or the queue not opened there (read-only, not a directory...)."""
    path = Path(state_dir) / f"mqtt-alerts-{settings.device}.sqlite3"
    try:
        return AlertQueue(path, settings.alert_queue_max)
    except StorageError as exc:
        raise ConfigError(f"device.state_dir: {state_dir}: the alert queue cannot be kept there: {exc}") from None


class MqttPublisher:
    """Publishes one camera's availability, state, alerts, stats and maps; receives commands.

    ``settings``: the ``[mqtt]`` table. ``state_dir``: where the alert queue lives
    (``$STATE_DIRECTORY`` under systemd; ConfigError when unusable). ``on_command``: the daemon's
    command handler (see ``CommandHandler``); without one, commands are refused with a reply.
    ``password``: overrides :func:`resolve_password` (tests). ``command_keys``: key id -> secret,
    overrides :func:`resolve_command_keys` (empty: read-only; ConfigError when a key source is bad).

    Nothing connects until :meth:`start` (or ``with``); the connection is then made and kept in
    the background with backoff between ``reconnect_min_s`` and ``reconnect_max_s``.
    """

    def __init__(self, settings: MqttSettings, state_dir: str | Path, on_command: CommandHandler | None = None,
                 *, password: str | None = None, command_keys: Mapping[str, bytes] | None = None) -> None:
        self.settings = settings
        keys = resolve_command_keys(settings) if command_keys is None else command_keys
        if not keys:
            log.warning("MQTT: no command key ([mqtt] command_key_file, $%s or the credential %r): "
                        "commands that change the laser or the measurement will be refused (read-only)",
                        COMMAND_KEY_ENV, COMMAND_KEY_CREDENTIAL)
        self.topics = Topics.from_settings(settings)
        #: The connection; Home Assistant publishes through it too (``homeassistant``).
        self.session = MqttSession(settings, client_id=settings.effective_client_id, label="MQTT", logger=log,
                                   password=password, will_topic=self.topics.availability)
        self._counters = Counters()
        self._store = AlertStore(open_alert_queue(settings, state_dir), self._counters)
        self._client = self.session.client
        self._connected = self.session.connected
        # Held around QoS 0 state publishes only: paho's QoS 0 path takes none of its own locks
        # in threaded mode, so this cannot deadlock with the network thread.
        self._state_lock = threading.Lock()
        self._retained: dict[str, bytes] = {}  # topic -> the newest retained payload, resent on reconnection
        self._started = False
        self._closed = False
        self._alerts = AlertSender(self._store, self._client, self.topics.alerts, self._connected, self._counters,
                                   in_flight=settings.alerts_in_flight)
        self._maps = MapSender(settings, self.topics, self._client, self._connected, self._counters)
        disabled = {} if settings.laser_command else {
            "laser": "cmd/laser is disabled by configuration ([mqtt] laser_command = false)"}
        self._commands = CommandChannel(self.topics, self._client.publish, on_command, self._counters,
                                        mqtt5=settings.protocol == "5", disabled=disabled,
                                        verifier=CommandVerifier(keys, settings.command_max_age_s))
        # retain-as-published (MQTT 5): a retained command shows its flag on first delivery too
        self.session.subscribe(self.topics.command_filter, 1, self._commands.receive, what="commands",
                               retain_as_published=True)
        self.session.on_connected(self._on_connected)
        self._client.on_publish = self._on_publish

    # -- life cycle --------------------------------------------------------------------------

    def start(self) -> MqttPublisher:
        """Start connecting in the background (returns at once)."""
        if self._closed:
            raise PublishError("this publisher was closed; make a new one")
        if self._started:
            return self
        self._started = True
        for worker in (self._alerts, self._maps, self._commands):
            worker.start()
        self.session.start()
        return self

    def wait_connected(self, timeout: float) -> None:
        """Wait (at most ``timeout`` s) until the broker accepted us and our command subscription;
        PublishError saying why not. A refusal by the broker (bad password...) raises at once."""
        self.session.wait_ready(timeout)

    @property
    def connected(self) -> bool:
        return self._connected.is_set()

    @property
    def last_error(self) -> str | None:
        """The latest connection problem, or None while all is well."""
        return self.session.last_error

    def close(self, timeout: float | None = None) -> None:
        """Publish ``offline`` (waiting at most ``shutdown_timeout_s`` for the broker's ack),
        disconnect cleanly and stop every thread; bounded by ``timeout`` (default
        ``shutdown_timeout_s + 0.5`` s). Unacknowledged alerts stay on disk for next time."""
        if self._closed:
            return
        self._closed = True
        budget = self.settings.shutdown_timeout_s + 0.5 if timeout is None else timeout
        deadline = time.monotonic() + budget
        workers = (self._alerts, self._maps, self._commands)
        for worker in workers:
            worker.stop()
        if self._started:
            for worker in workers:
                worker.thread.join(timeout=max(0.0, min(0.3, deadline - time.monotonic())))
            if self._connected.is_set():
                self.session.publish_and_wait(self.topics.availability, b"offline", qos=1, retain=True,
                                              timeout=min(self.settings.shutdown_timeout_s,
                                                          deadline - time.monotonic()))
        self.session.close(deadline - time.monotonic())
        if any(worker.thread.is_alive() for worker in workers):
            log.warning("MQTT worker still busy at shutdown; leaving the alert queue open")
        else:
            self._store.queue.close()

    def __enter__(self) -> MqttPublisher:
        return self.start()

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    # -- publishing --------------------------------------------------------------------------

    def publish_state(self, state: Mapping[str, Any]) -> None:
        """Retained state; kept and republished on every (re)connection."""
        self.publish_retained(self.topics.state, _json.dumps(state))

    def publish_retained(self, topic: str, payload: bytes) -> None:
        """A retained message (QoS 0), kept and republished on every (re)connection; an empty
        payload clears the topic on the broker (once, if connected) and is not kept."""
        with self._state_lock:  # vs. _on_connect: the newest payload must be the last one sent
            if payload:
                self._retained[topic] = payload
            else:
                self._retained.pop(topic, None)
            if self._connected.is_set():
                self._client.publish(topic, payload, qos=0, retain=True)

    def publish_alert(self, alert: Mapping[str, Any]) -> int:
        """Store the alert and send it (QoS 1) as soon as possible; returns its ``seq``.

        ``seq`` and ``stream`` are set here. A disk that refuses the write does not lose it (see
        ``alertstore``); PublishError only for an alert that is not JSON or too big.
        """
        item = self._store.put(alert)
        self._alerts.wake()
        return item.seq

    def publish_stats(self, stats: Mapping[str, Any]) -> bool:
        """Send statistics now (QoS 0) with the link's counters added under ``mqtt``; False (and
        counted) when not connected."""
        if not self._connected.is_set():
            self._counters.add("stats_dropped")
            return False
        payload = _json.dumps({**stats, "mqtt": self.counters()})
        return self._client.publish(self.topics.stats, payload, qos=0).rc == MQTTErrorCode.MQTT_ERR_SUCCESS

    def publish_map(self, name: str, values: np.ndarray, meta: Mapping[str, Any] | None = None) -> bool:
        """Hand one map to the map sender (returns at once); False (counted) when not connected.
        See :meth:`edgedsm.publish.map_sender.MapSender.submit`."""
        return self._maps.submit(name, values, meta)

    def flush_maps(self, timeout: float) -> bool:
        """Wait at most ``timeout`` s until every map handed over has left (or was dropped)."""
        return self._maps.flush(timeout)

    def flush_alerts(self, timeout: float) -> bool:
        """Wait at most ``timeout`` s until every stored alert is acknowledged; True if so."""
        return self._alerts.flush(timeout)

    @property
    def alert_stream(self) -> str:
        """The ``stream`` id written into every alert (with ``seq``, the deduplication key)."""
        return self._store.stream

    @property
    def pending_alerts(self) -> int:
        """Alerts stored and not yet acknowledged by the broker."""
        return len(self._store)

    def counters(self) -> dict[str, Any]:
        """Health of the link: connected, alerts pending/dropped, messages dropped, reconnects,
        and the storage fault (``storage_error``: the disk's refusal, None while it takes writes)."""
        return {"connected": self._connected.is_set(), "alerts_pending": len(self._store),
                "alerts_dropped": self._store.queue.dropped, "alerts_in_memory": self._store.in_memory,
                "storage_error": self._store.fault, "connects": self.session.connects,
                "disconnects": self.session.disconnects, **self._counters.snapshot()}

    # -- on paho's network thread ---------------------------------------------------------------

    def _on_connected(self) -> None:
        """Every (re)connection: ``online``, then the retained messages, then pending alerts."""
        self._client.publish(self.topics.availability, b"online", qos=1, retain=True)
        with self._state_lock:
            for topic, payload in self._retained.items():
                self._client.publish(topic, payload, qos=0, retain=True)
        self._alerts.wake()

    def _on_publish(self, client: mqtt.Client, userdata: Any, mid: int, reason: ReasonCode,
                    properties: Properties | None) -> None:
        self._alerts.on_publish(mid, reason)
