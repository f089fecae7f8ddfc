"""One MQTT connection's life cycle, shared by every sink that publishes on it.

:class:`MqttSession` builds the paho client (:func:`~edgedsm.publish.connection.make_client`),
connects in the background with backoff, tracks whether it is connected (an ``Event``), renews
its subscriptions on every (re)connection and runs its owners' hooks there, says connection
problems once at a bounded rate (:class:`~edgedsm.publish.connection.ProblemLog`), and closes
within a bounded time. The JSON link (with Home Assistant attached to it) and the Sparkplug node
each have one; Sparkplug needs a session of its own (its client id, its will, clean start).

Hooks and message handlers run on paho's network thread (a hook registered while the session
is connected also runs once at once, on the caller's thread); they must not wait on the network.
An exception in one is logged and the others still run.
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from collections.abc import Callable
from typing import Any

import paho.mqtt.client as mqtt
from paho.mqtt.properties import Properties
from paho.mqtt.reasoncodes import ReasonCode
from paho.mqtt.subscribeoptions import SubscribeOptions

from edgedsm.publish.connection import (
    ProblemLog,
    build_ssl_context,
    connect_in_background,
    describe_refusal,
    diagnose,
    make_client,
    refuses_credentials,
)
from edgedsm.publish.errors import PublishError
from edgedsm.publish.settings import MqttSettings, resolve_password

log = logging.getLogger(__name__)

Hook = Callable[[], None]
MessageHandler = Callable[[mqtt.MQTTMessage], None]


def _release_wakeup_sockets(client: mqtt.Client) -> None:
    """Close the socket pair paho 2.2's ``loop_start`` opens and never closes (a second
    ``loop_start`` after a restart would leak the first pair)."""
    reset = getattr(client, "_reset_sockets", None)
    if reset is not None:
        reset(sockpair_only=True)


class _Subscription:
    def __init__(self, qos: int, what: str, retain_as_published: bool = False) -> None:
        self.qos = qos
        self.retain_as_published = retain_as_published
        self.what = what  # what is not received when the broker refuses it ("commands")
        self.handlers: list[MessageHandler] = []


class MqttSession:
    """One MQTT client connected (and reconnected) in the background.

    ``label`` starts every log line (``MQTT``, ``Sparkplug``); ``logger`` is the owner's.
    ``will_topic``: a retained ``offline`` last will. ``clean_start``: MQTT v5 clean start (v3.1.1
    always uses a clean session here). ``password`` overrides :func:`resolve_password` (tests).
    Nothing connects until :meth:`start`.
    """

    def __init__(self, settings: MqttSettings, *, client_id: str, label: str = "MQTT",
                 logger: logging.Logger = log, password: str | None = None, will_topic: str | None = None,
                 clean_start: bool = True) -> None:
        self.settings = settings
        self.client_id = client_id
        self.label = label
        self._log = logger
        self.password = password if password is not None else resolve_password()
        self.ssl_context = build_ssl_context(settings.tls) if settings.tls is not None else None
        self.client = make_client(settings, client_id=client_id, password=self.password,
                                  ssl_context=self.ssl_context, will_topic=will_topic)
        self.clean_start = clean_start
        #: Set while the broker has accepted us.
        self.connected = threading.Event()
        #: Set once connected AND the broker answered the subscriptions made at that connection.
        self.ready = threading.Event()
        self.refusal: str | None = None  # the broker's refusal of our CONNECT, None once accepted
        #: The refusal is about the credentials (bad user name or password, not authorised).
        self.refused_credentials = False
        #: Set at the first answer to a connection attempt: accepted, refused or failed.
        self.answered = threading.Event()
        self.last_error: str | None = None  # the latest problem, None while all is well
        self.connects = self.disconnects = 0
        self._problems = ProblemLog(logger)
        self._lock = threading.Lock()
        self._subscriptions: dict[str, _Subscription] = {}
        self._pending: dict[int, list[str]] = {}  # SUBSCRIBE mid -> its topic filters
        self._batch_mid: int | None = None  # the subscriptions renewed at the latest connection
        self._hooks: dict[str, list[Callable[..., None]]] = {
            "before_connect": [], "connected": [], "ready": [], "disconnected": [], "refused": []}
        self._started = self._closed = self._leaving = False
        client = self.client
        client.on_pre_connect = self._on_pre_connect
        client.on_connect = self._on_connect
        client.on_connect_fail = self._on_connect_fail
        client.on_disconnect = self._on_disconnect
        client.on_subscribe = self._on_subscribe
        client.on_message = self._on_message

    # -- hooks and subscriptions ----------------------------------------------------------------

    def on_connected(self, hook: Hook) -> None:
        """Run ``hook`` on every (re)connection, after the subscriptions were renewed; at once
        (on this thread) if connected now."""
        with self._lock:
            self._hooks["connected"].append(hook)
            now = self.connected.is_set()
        if now:
            self._run(hook, "connected")

    def on_ready(self, hook: Hook) -> None:
        """Run ``hook`` when the broker answered the subscriptions of a connection."""
        self._add("ready", hook)

    def on_disconnected(self, hook: Hook) -> None:
        """Run ``hook`` when a connection ends (lost or closed)."""
        self._add("disconnected", hook)

    def before_connect(self, hook: Hook) -> None:
        """Run ``hook`` before every CONNECT is sent (e.g. to set a will that changes)."""
        self._add("before_connect", hook)

    def on_refused(self, hook: Callable[[str], None]) -> None:
        """Run ``hook(reason)`` when the broker answers a CONNECT with a refusal."""
        self._add("refused", hook)

    def _add(self, event: str, hook: Callable[..., None]) -> None:
        with self._lock:
            self._hooks[event].append(hook)

    def remove_hooks(self, *hooks: Callable[..., None]) -> None:
        """Forget ``hooks`` (a sink leaving a session it does not own)."""
        with self._lock:
            for registered in self._hooks.values():
                registered[:] = [hook for hook in registered if hook not in hooks]

    def subscribe(self, topic: str, qos: int, handler: MessageHandler, *, what: str,
                  retain_as_published: bool = False) -> None:
        """Receive ``topic`` (a filter) with ``handler``, subscribed again at every connection;
        at once if connected now. ``what`` names what is missed when the broker refuses it.
        ``retain_as_published`` (MQTT 5 only; 3.1.1 has no such option): the broker keeps the
        retain flag of a message published while we are subscribed, instead of clearing it."""
        with self._lock:
            subscription = self._subscriptions.setdefault(topic, _Subscription(qos, what, retain_as_published))
            subscription.handlers.append(handler)
            now = self.connected.is_set()
        if now:
            self._send_subscribe([(topic, self._options(subscription))])

    def unsubscribe(self, topic: str, handler: MessageHandler) -> None:
        """Stop handing ``topic`` to ``handler``; the last handler of a filter unsubscribes."""
        with self._lock:
            subscription = self._subscriptions.get(topic)
            if subscription is None or handler not in subscription.handlers:
                return
            subscription.handlers.remove(handler)
            last = not subscription.handlers
            if last:
                del self._subscriptions[topic]
            now = self.connected.is_set()
        if last and now:
            self.client.unsubscribe(topic)

    def subscriptions(self) -> list[str]:
        with self._lock:
            return list(self._subscriptions)

    # -- life cycle -------------------------------------------------------------------------------

    def start(self) -> MqttSession:
        """Start connecting in the background (returns at once)."""
        with self._lock:
            if self._closed:
                raise PublishError(f"this {self.label} session was closed; make a new one")
            if self._started:
                return self
            self._started = True
        connect_in_background(self.client, self.settings, clean_start=self.clean_start)
        return self

    def wait_ready(self, timeout: float) -> None:
        """Wait (at most ``timeout`` s) until connected and subscribed; PublishError saying why
        not. A refusal by the broker (bad password...) raises at once."""
        deadline = time.monotonic() + timeout
        while not self.ready.wait(0.05):
            if self.refusal is not None:
                raise PublishError(self.refusal)
            if time.monotonic() >= deadline:
                why = self.last_error or "no answer yet"
                raise PublishError(f"no connection to the MQTT broker {self.settings.host}:{self.settings.port} "
                                   f"within {timeout:g} s: {why}")

    def publish_and_wait(self, topic: str, payload: bytes, *, qos: int, retain: bool, timeout: float) -> None:
        """Publish and wait at most ``timeout`` s for the broker's acknowledgement (QoS 1)."""
        info = self.client.publish(topic, payload, qos=qos, retain=retain)
        with contextlib.suppress(RuntimeError, ValueError):  # not queued: nothing to wait for
            info.wait_for_publish(timeout=max(0.0, timeout))

    def restart(self, reasoncode: ReasonCode | None = None) -> None:
        """End this connection on purpose and connect again (a new session for the broker).
        Waits for paho's thread: call it from a thread of the owner's, never from a hook."""
        with self._lock:
            if self._closed:
                return
            self._leaving = True
        self.client.disconnect(reasoncode=reasoncode)
        self._stop_network(None)
        with self._lock:
            if self._closed:
                return
            self._leaving = False
        connect_in_background(self.client, self.settings, clean_start=self.clean_start)

    def close(self, timeout: float, reasoncode: ReasonCode | None = None) -> bool:
        """Disconnect and stop paho's thread, waiting at most ``timeout`` s for it (it may sit in
        a connect attempt to an unreachable broker); True if it stopped. Whatever the owner
        publishes on the way out (``offline``, NDEATH) goes before this."""
        with self._lock:
            if self._closed:
                return True
            self._closed = self._leaving = True
            started = self._started
        stopped = True
        if started:
            self.client.disconnect(reasoncode=reasoncode)
            stopped = self._stop_network(timeout)
        self.connected.clear()
        self.ready.clear()
        return stopped

    def _stop_network(self, timeout: float | None) -> bool:
        # loop_stop() joins paho's thread, which may sit in a connect attempt: bound it
        stopper = threading.Thread(target=self.client.loop_stop, name=f"edgedsm-{self.label.lower()}-stop",
                                   daemon=True)
        stopper.start()
        stopper.join(timeout=None if timeout is None else max(0.05, timeout))
        if stopper.is_alive():
            return False
        _release_wakeup_sockets(self.client)
        return True

    @property
    def closed(self) -> bool:
        return self._closed

    # -- paho callbacks (paho's network thread) ------------------------------------------------------

    def _run(self, hook: Callable[..., None], event: str, *args: Any) -> None:
        try:
            hook(*args)
        except Exception:  # one owner's bug must not keep the others' hooks from running
            self._log.exception("%s: error in a %s hook", self.label, event)

    def _run_all(self, event: str, *args: Any) -> None:
        with self._lock:
            hooks = list(self._hooks[event])
        for hook in hooks:
            self._run(hook, event, *args)

    def _options(self, subscription: _Subscription) -> int | SubscribeOptions:
        """What paho's subscribe takes for one filter: the QoS, or MQTT 5's options."""
        if self.settings.protocol == "5" and subscription.retain_as_published:
            return SubscribeOptions(qos=subscription.qos, retainAsPublished=True)
        return subscription.qos

    def _send_subscribe(self, topics: list[tuple[str, int | SubscribeOptions]]) -> int | None:
        if not topics:
            return None
        _, mid = self.client.subscribe(topics)
        if mid is not None:
            with self._lock:
                self._pending[mid] = [topic for topic, _ in topics]
        return mid

    def _on_pre_connect(self, client: mqtt.Client, userdata: Any) -> None:
        self._run_all("before_connect")

    def _on_connect(self, client: mqtt.Client, userdata: Any, flags: Any, reason: ReasonCode,
                    properties: Properties | None) -> None:
        if reason.is_failure:
            message = describe_refusal(reason, self.settings, self.password is not None)
            self.refusal = self.last_error = message
            self.refused_credentials = refuses_credentials(reason)
            self.answered.set()
            self._problems.report(f"{self.label}: {message}", logging.ERROR)
            self._run_all("refused", message)
            return
        self.refusal = self.last_error = None
        self.refused_credentials = False
        self.answered.set()
        self._problems.reset()
        self.connects += 1
        self._log.info("%s connected to %s:%d as %r", self.label, self.settings.host, self.settings.port,
                       self.client_id)
        with self._lock:  # a subscription or hook added from now on is served at once, not here
            self.ready.clear()
            self.connected.set()
            topics = [(topic, self._options(subscription)) for topic, subscription in self._subscriptions.items()]
            self._pending.clear()
        # the SUBACK is handled on this thread, after this callback: the mid is stored in time
        self._batch_mid = self._send_subscribe(topics)
        if self._batch_mid is None:
            self.ready.set()
        self._run_all("connected")
        if self._batch_mid is None:
            self._run_all("ready")

    def _on_subscribe(self, client: mqtt.Client, userdata: Any, mid: int, reasons: list[ReasonCode],
                      properties: Properties | None) -> None:
        with self._lock:
            topics = self._pending.pop(mid, [])
            whats = {topic: self._subscriptions[topic].what for topic in topics if topic in self._subscriptions}
        for topic, reason in zip(topics, reasons, strict=False):
            if reason.is_failure:  # e.g. an ACL: publishing still works, these messages will not arrive
                self.last_error = f"broker refused the subscription to {topic}: {reason}"
                self._log.error("%s: %s; %s will not be received", self.label, self.last_error,
                                whats.get(topic, "its messages"))
        if mid == self._batch_mid and self.connected.is_set():
            self.ready.set()
            self._run_all("ready")

    def _on_connect_fail(self, client: mqtt.Client, userdata: Any) -> None:
        self.connected.clear()
        self.ready.clear()
        if self._leaving:  # an attempt that ends after close(): no retry to announce, nothing to diagnose
            return
        if self._problems.due() or self.last_error is None:
            # Costs one extra connection attempt, so only when we are about to log anyway.
            self.last_error = diagnose(self.settings, self.ssl_context)
        self.answered.set()
        self._problems.report(f"{self.label}: {self.last_error}; retrying", logging.WARNING)

    def _on_disconnect(self, client: mqtt.Client, userdata: Any, flags: Any, reason: ReasonCode,
                       properties: Properties | None) -> None:
        with self._lock:
            was_connected = self.connected.is_set()
            self.connected.clear()
            self.ready.clear()
            leaving = self._leaving
        if not was_connected:
            return
        self.disconnects += 1
        if not leaving:
            self.last_error = f"connection lost: {reason}"
            self._log.warning("%s connection to %s:%d lost (%s); reconnecting", self.label, self.settings.host,
                              self.settings.port, reason)
        self._run_all("disconnected")

    def _on_message(self, client: mqtt.Client, userdata: Any, message: mqtt.MQTTMessage) -> None:
        with self._lock:
            handlers = [handler for topic, subscription in self._subscriptions.items()
                        if mqtt.topic_matches_sub(topic, message.topic) for handler in subscription.handlers]
        for handler in handlers:
            try:
                handler(message)
            except Exception:  # never let one message take the network thread down
                self._log.exception("%s: error while handling a message on %r", self.label, message.topic)
