"""The Sparkplug B 3.0 edge node: a :class:`edgedsm.publish.sink.Sink` with its own MQTT session.

The daemon is the edge node (``spBv1.0/<group>/N*/<edge_node>``: its session, bdSeq, rebirth
command); the camera with its regions is one device (``spBv1.0/<group>/D*/<edge_node>/<device>``),
so that hosts see the node's session and the camera's measurements as separate things, the way
the spec models a gateway and what it measures. Births carry every metric with name, alias,
datatype and unit; DDATA carries, by alias, only what changed (floats beyond a deadband).

Threads: ``publish_*`` (the evaluator thread) only update the metric books and queue a QoS 0
message; births, session restarts and the explicit NDEATH happen on this node's own worker
thread; paho's network thread runs the callbacks. One lock orders them (``seq`` follows the
order in which messages are queued). See docs/sparkplug.md.
"""

from __future__ import annotations

import contextlib
import itertools
import logging
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import paho.mqtt.client as mqtt
from paho.mqtt.packettypes import PacketTypes
from paho.mqtt.properties import Properties
from paho.mqtt.reasoncodes import ReasonCode

from edgedsm import __version__
from edgedsm.messages import Alert, Clock, MapFrame, StateReport, Stats
from edgedsm.publish.connection import (
    ProblemLog,
    build_ssl_context,
    connect_in_background,
    describe_refusal,
    diagnose,
    make_client,
)
from edgedsm.publish.settings import MqttSettings, resolve_password
from edgedsm.publish.sparkplug import commands as ncmd
from edgedsm.publish.sparkplug.book import Deadband, MetricBook
from edgedsm.publish.sparkplug.metrics import Reading, alert_readings, declared_readings, state_readings, stats_readings
from edgedsm.publish.sparkplug.payload import DataType, Metric, encode, now_ms
from edgedsm.publish.sparkplug.session import BdSeqStore, BirthLimiter, PrimaryHost, SeqCounter
from edgedsm.publish.sparkplug.settings import SparkplugSettings

log = logging.getLogger(__name__)

NAMESPACE = "spBv1.0"
BDSEQ = "bdSeq"
COUNTER_NAMES = ("connects", "disconnects", "births", "rebirth_requests", "commands_refused", "ndata_sent",
                 "ddata_sent", "state_refused")


def _release_wakeup_sockets(client: mqtt.Client) -> None:
    """Close the socket pair paho 2.2's ``loop_start`` opens and never closes (a second
    ``loop_start`` after a session restart would leak the first pair)."""
    reset = getattr(client, "_reset_sockets", None)
    if reset is not None:
        reset(sockpair_only=True)


@dataclass(frozen=True)
class SparkplugTopics:
    """The topics of one edge node and its camera device."""

    group_id: str
    edge_node_id: str
    device_id: str

    def node(self, message_type: str) -> str:
        return f"{NAMESPACE}/{self.group_id}/{message_type}/{self.edge_node_id}"

    def device(self, message_type: str) -> str:
        return f"{self.node(message_type)}/{self.device_id}"


class SparkplugSink:
    """Implements :class:`edgedsm.publish.sink.Sink` as a Sparkplug B edge node (see the module
    docstring). ``regions`` and ``maps`` name the device metrics known before the first message;
    others appear with a new birth. ``state_dir`` keeps the bdSeq (ConfigError naming
    ``device.state_dir`` when unusable). Nothing connects until :meth:`start`."""

    def __init__(self, settings: SparkplugSettings, mqtt_settings: MqttSettings, state_dir: str | Path, *,
                 regions: tuple[str, ...] | list[str] = (), maps: tuple[str, ...] | list[str] = (),
                 password: str | None = None, clock: Clock | None = None) -> None:
        self.settings, self.mqtt_settings = settings, mqtt_settings
        self.clock = clock or Clock()
        self.topics = SparkplugTopics(settings.group_id, settings.edge_node_id or mqtt_settings.device,
                                      settings.device_id)
        self.client_id = settings.client_id or f"{mqtt_settings.effective_client_id}-sparkplug"
        self._bdseq = BdSeqStore(state_dir)
        self._connect_bdseq: int | None = None  # in the will of the CONNECT under way
        self.session_bdseq: int | None = None  # of the current session
        aliases = itertools.count(1)
        deadband = Deadband(settings.deadband_rel, settings.deadband_abs)
        self.node = MetricBook(aliases, deadband, no_alias=frozenset({ncmd.REBIRTH}))
        self.device = MetricBook(aliases, deadband)
        self.node.declare({BDSEQ: Reading(DataType.INT64, 0), ncmd.REBIRTH: Reading(DataType.BOOLEAN, False),
                           "Properties/Software": Reading(DataType.STRING, f"edgedsm {__version__}"),
                           "Node Info/commands_refused": Reading(DataType.UINT64, 0),
                           "Node Info/rebirth_requests": Reading(DataType.UINT64, 0)})
        self.device.declare(declared_readings(regions, maps))
        self._seq = SeqCounter()
        self.host = PrimaryHost(settings.primary_host_id) if settings.primary_host_id else None
        self._limiter = BirthLimiter(settings.rebirth_min_interval_s)
        self._lock = threading.RLock()
        self._wake = threading.Condition(self._lock)
        self._connected = self._subscribed = self.born = False
        self._birth_wanted = self._restart_wanted = self._closing = False
        self._subscribe_mid: int | None = None
        self._alerts_seen = 0
        self._counts = dict.fromkeys(COUNTER_NAMES, 0)
        self._refusals = ncmd.RefusalLog(log)
        self._problems = ProblemLog(log)
        self._password = password if password is not None else resolve_password()
        self._ssl_context = build_ssl_context(mqtt_settings.tls) if mqtt_settings.tls is not None else None
        self._client = make_client(mqtt_settings, client_id=self.client_id, password=self._password,
                                   ssl_context=self._ssl_context, clean_session=True)
        self._client.on_pre_connect = self._on_pre_connect
        self._client.on_connect = self._on_connect
        self._client.on_connect_fail = self._on_connect_fail
        self._client.on_disconnect = self._on_disconnect
        self._client.on_subscribe = self._on_subscribe
        self._client.on_message = self._on_message
        self._worker = threading.Thread(target=self._run, name="edgedsm-sparkplug", daemon=True)
        self._started = False

    def start(self) -> SparkplugSink:
        """Start connecting in the background (returns at once)."""
        self._started = True
        self._worker.start()
        connect_in_background(self._client, self.mqtt_settings, clean_start=True)  # spec: clean session
        return self

    # -- the Sink protocol (evaluator thread) -----------------------------------------------------

    def publish_state(self, report: StateReport) -> None:
        self._record(state_readings(report), report.t)

    def publish_stats(self, stats: Stats) -> None:
        self._record(stats_readings(stats), stats.t)

    def publish_alert(self, alert: Alert) -> None:
        """The latest alert as metrics; QoS 0 like every Sparkplug data message (the JSON sink is
        the one that delivers every alert at least once)."""
        with self._lock:
            self._alerts_seen += 1
            readings = alert_readings(alert, self._alerts_seen)
        self._record(readings, alert.t)

    def publish_map(self, frame: MapFrame) -> None:
        return None  # maps stay on the JSON topics: Sparkplug carries scalar metrics

    def flush(self, timeout_s: float) -> bool:
        return True  # QoS 0 only: nothing is waited for

    def close(self, timeout_s: float) -> None:
        """Publish NDEATH (spec: before an intentional disconnect), disconnect, stop the threads."""
        deadline = time.monotonic() + timeout_s
        with self._lock:
            if self._closing:
                return
            self._closing = True
            connected, self.born = self._connected, False
            self._wake.notify_all()
        if self._started:
            self._worker.join(timeout=max(0.05, (deadline - time.monotonic()) / 3))  # no restart under way
            if connected:
                self._send_death(max(0.0, min(0.5, deadline - time.monotonic())))
            self._client.disconnect(reasoncode=self._disconnect_reason())
            # loop_stop() joins paho's thread, which may sit in a connect attempt: bound it
            stopper = threading.Thread(target=self._client.loop_stop, name="edgedsm-sparkplug-stop", daemon=True)
            stopper.start()
            stopper.join(timeout=max(0.05, deadline - time.monotonic()))
            if not stopper.is_alive():
                _release_wakeup_sockets(self._client)

    # -- health, for tests and the docs -----------------------------------------------------------

    @property
    def connected(self) -> bool:
        return self._connected

    def counters(self) -> dict[str, int]:
        with self._lock:
            return dict(self._counts)

    # -- metrics and data messages ----------------------------------------------------------------

    def _record(self, readings: dict[str, Reading], wall_t: float) -> None:
        with self._lock:
            self.device.update(readings, now_ms(wall_t))
            if not self.born:
                return  # the next birth carries the values
            if self.device.needs_birth or self.node.needs_birth:
                self._want_birth()  # a new metric: only a birth may announce it
                return
            self._send_changes()

    def _send_changes(self) -> None:
        """NDATA and DDATA with what changed (lock held, born)."""
        sent_ms = now_ms(self.clock.wall())
        for book, topic, counter in ((self.node, self.topics.node("NDATA"), "ndata_sent"),
                                     (self.device, self.topics.device("DDATA"), "ddata_sent")):
            changes = book.changes()
            if changes:
                self._publish(topic, encode(changes, timestamp_ms=sent_ms, seq=self._seq.next(), birth=False))
                self._counts[counter] += 1

    def _publish(self, topic: str, payload: bytes) -> None:
        # QoS 0, not retained: every Sparkplug message an edge node publishes except its death
        self._client.publish(topic, payload, qos=0, retain=False)

    def _want_birth(self) -> None:
        """Stop data messages and let the worker send a birth as soon as allowed (lock held)."""
        self.born, self._birth_wanted = False, True
        self._wake.notify_all()

    def _birth(self) -> None:
        """NBIRTH (seq 0, this session's bdSeq) then DBIRTH (lock held)."""
        self._limiter.record(time.monotonic())
        self._birth_wanted = False
        sent_ms = now_ms(self.clock.wall())
        self.node.update({BDSEQ: Reading(DataType.INT64, self.session_bdseq),
                          ncmd.REBIRTH: Reading(DataType.BOOLEAN, False)}, sent_ms)
        self._publish(self.topics.node("NBIRTH"),
                      encode(self.node.birth(sent_ms), timestamp_ms=sent_ms, seq=self._seq.birth(), birth=True))
        self._publish(self.topics.device("DBIRTH"),
                      encode(self.device.birth(sent_ms), timestamp_ms=sent_ms, seq=self._seq.next(), birth=True))
        self.born = True
        self._counts["births"] += 1
        log.info("Sparkplug birth on %s (bdSeq %s): %d node and %d device metrics", self.topics.node("NBIRTH"),
                 self.session_bdseq, len(self.node), len(self.device))

    def _death_payload(self, bdseq: int) -> bytes:
        sent_ms = now_ms(self.clock.wall())
        return encode([Metric(BDSEQ, DataType.INT64, bdseq, sent_ms)], timestamp_ms=sent_ms, seq=None, birth=True)

    def _send_death(self, wait_s: float) -> None:
        """Publish this session's NDEATH ourselves (QoS 1), waiting at most ``wait_s`` for it."""
        with self._lock:
            bdseq = self.session_bdseq
        if bdseq is None:
            return
        info = self._client.publish(self.topics.node("NDEATH"), self._death_payload(bdseq), qos=1, retain=False)
        with contextlib.suppress(RuntimeError, ValueError):  # not queued: nothing to wait for
            info.wait_for_publish(timeout=wait_s)

    def _disconnect_reason(self) -> ReasonCode | None:
        # MQTT 5: 'Disconnect with Will Message' so the broker sends the NDEATH too
        # (spec: tck-id-payloads-ndeath-will-message-publisher-disconnect-mqtt50)
        if self._client.protocol != mqtt.MQTTv5:
            return None
        return ReasonCode(PacketTypes.DISCONNECT, "Disconnect with will message")

    # -- the worker: births when allowed, session restarts ----------------------------------------

    def _can_birth(self) -> bool:
        return self._connected and self._subscribed and (self.host is None or self.host.online)

    def _run(self) -> None:
        while True:
            with self._lock:
                while not self._closing and not self._restart_wanted:
                    if self._birth_wanted and self._can_birth():
                        wait = self._limiter.wait_s(time.monotonic())
                        if wait <= 0.0:
                            self._birth()
                            continue
                        self._wake.wait(timeout=wait)
                    else:
                        self._wake.wait(timeout=1.0)
                if self._closing:
                    return
                self._restart_wanted = False
            self._restart_session()

    def _restart_session(self) -> None:
        """The primary host went offline: NDEATH, disconnect, connect again (a new bdSeq) and wait
        for it to come back (spec: tck-id-message-flow-edge-node-birth-publish-phid-offline)."""
        log.warning("Sparkplug: primary host %r is offline: ending the session and connecting again",
                    self.settings.primary_host_id)
        self._send_death(0.5)
        self._client.disconnect(reasoncode=self._disconnect_reason())
        self._client.loop_stop()
        _release_wakeup_sockets(self._client)
        with self._lock:
            if self._closing:
                return
        connect_in_background(self._client, self.mqtt_settings, clean_start=True)

    # -- paho callbacks (network thread) ----------------------------------------------------------

    def _on_pre_connect(self, client: mqtt.Client, userdata: Any) -> None:
        # the will is the NDEATH with the bdSeq of this CONNECT; the NBIRTH will repeat it
        with self._lock:
            self._connect_bdseq = self._bdseq.next()
            client.will_set(self.topics.node("NDEATH"), self._death_payload(self._connect_bdseq), qos=1, retain=False)

    def _on_connect(self, client: mqtt.Client, userdata: Any, flags: Any, reason: ReasonCode,
                    properties: Properties | None) -> None:
        with self._lock:
            if self._connect_bdseq is not None:
                self._bdseq.commit(self._connect_bdseq)  # a CONNECT went out with it, accepted or not
            if reason.is_failure:
                refusal = describe_refusal(reason, self.mqtt_settings, self._password is not None)
                self._problems.report(f"Sparkplug: {refusal}", logging.ERROR)
                return
            self._problems.reset()
            self.session_bdseq = self._connect_bdseq
            self._connected, self._subscribed, self.born = True, False, False
            self._birth_wanted = True
            self._counts["connects"] += 1
            topics = [(self.topics.node("NCMD"), 1)]  # spec: QoS 1, before the NBIRTH
            if self.host is not None:
                topics.append((self.host.topic, 1))
            _, self._subscribe_mid = client.subscribe(topics)
        log.info("Sparkplug connected as %s (bdSeq %d)%s", self.client_id, self.session_bdseq,
                 f"; waiting for primary host {self.host.host_id!r}" if self.host and not self.host.online else "")

    def _on_subscribe(self, client: mqtt.Client, userdata: Any, mid: int, reasons: list[ReasonCode],
                      properties: Properties | None) -> None:
        failed = [str(reason) for reason in reasons if reason.is_failure]
        if failed:  # an ACL: rebirth requests (or the host's STATE) will not arrive
            log.error("Sparkplug: the broker refused a subscription (%s)", failed[0])
        with self._lock:
            if mid == self._subscribe_mid:
                self._subscribed = True
                self._wake.notify_all()

    def _on_connect_fail(self, client: mqtt.Client, userdata: Any) -> None:
        with self._lock:
            self._connected = self._subscribed = self.born = False
        if self._problems.due():  # diagnosing costs a connection attempt: only when it will be logged
            self._problems.report(f"Sparkplug: {diagnose(self.mqtt_settings, self._ssl_context)}; retrying",
                                  logging.WARNING)

    def _on_disconnect(self, client: mqtt.Client, userdata: Any, flags: Any, reason: ReasonCode,
                       properties: Properties | None) -> None:
        with self._lock:
            was_connected = self._connected
            self._connected = self._subscribed = self.born = False
            if was_connected:
                self._counts["disconnects"] += 1
            closing = self._closing
        if was_connected and not closing:
            log.warning("Sparkplug connection lost (%s); reconnecting with a new bdSeq", reason)

    def _on_message(self, client: mqtt.Client, userdata: Any, message: mqtt.MQTTMessage) -> None:
        try:
            if message.topic == self.topics.node("NCMD"):
                self._on_command(bytes(message.payload), bool(message.retain))
            elif self.host is not None and message.topic == self.host.topic:
                self._on_host_state(bytes(message.payload))
        except Exception:  # never let one message take the network thread down
            log.exception("Sparkplug: error while handling a message on %r", message.topic)

    def _on_command(self, payload: bytes, retained: bool) -> None:
        with self._lock:
            verdict = ncmd.judge(payload, retained, self.node, self.device)
            for refusal in verdict.refusals:
                self._counts["commands_refused"] += 1
                self._refusals.refused(refusal)
            if verdict.rebirth:
                self._counts["rebirth_requests"] += 1
            self.node.update({"Node Info/commands_refused": Reading(DataType.UINT64, self._counts["commands_refused"]),
                              "Node Info/rebirth_requests": Reading(DataType.UINT64, self._counts["rebirth_requests"])},
                             now_ms(self.clock.wall()))
            if verdict.rebirth:
                self._want_birth()  # spec: stop data at once, then a complete birth sequence

    def _on_host_state(self, payload: bytes) -> None:
        if self.host is None:
            return
        with self._lock:
            try:
                event = self.host.on_state(payload)
            except ValueError as exc:
                self._counts["state_refused"] += 1
                self._refusals.refused(str(exc))
                return
            if event == "online" and not self.born:
                self._birth_wanted = True
                self._wake.notify_all()
            elif event == "offline" and self.born:  # only a node in a session has one to end
                self.born, self._restart_wanted = False, True
                self._wake.notify_all()
            elif event == "stale":
                log.info("Sparkplug: ignored an out-of-date STATE of primary host %r", self.host.host_id)
