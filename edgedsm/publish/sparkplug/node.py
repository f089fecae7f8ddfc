"""The Sparkplug B 3.0 edge node: a :class:`edgedsm.publish.sink.Sink` with its own MQTT session
(an :class:`edgedsm.publish.session.MqttSession` of its own: its client id, its NDEATH will, clean
start, the bdSeq of each CONNECT).

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

import itertools
import logging
import threading
import time
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import paho.mqtt.client as mqtt
from paho.mqtt.packettypes import PacketTypes
from paho.mqtt.reasoncodes import ReasonCode

from edgedsm import __version__
from edgedsm.messages import Alert, Clock, LaserState, MapFrame, StateReport, Stats
from edgedsm.publish.session import MqttSession
from edgedsm.publish.settings import MqttSettings
from edgedsm.publish.sparkplug import commands as ncmd
from edgedsm.publish.sparkplug.book import Deadband, MetricBook
from edgedsm.publish.sparkplug.metrics import Reading, alert_readings, declared_readings, state_readings, stats_readings
from edgedsm.publish.sparkplug.payload import DataType, Metric, encode, now_ms
from edgedsm.publish.sparkplug.session import BdSeqStore, BirthLimiter, PrimaryHost, SeqCounter
from edgedsm.publish.sparkplug.settings import SparkplugSettings

log = logging.getLogger(__name__)

NAMESPACE = "spBv1.0"
BDSEQ = "bdSeq"
COUNTER_NAMES = ("births", "rebirth_requests", "commands_refused", "ndata_sent",
                 "ddata_sent", "state_refused")


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
    docstring). ``regions`` and ``maps`` name the device metrics known before the first message,
    with each region's signal quality when ``signal`` (``estimator.noise_floor``) and its
    activity's unit when ``judged`` names the estimator it is of; others appear with a new birth.
    ``state_dir`` keeps the bdSeq (ConfigError naming ``device.state_dir`` when unusable). Nothing
    connects until :meth:`start`."""

    def __init__(self, settings: SparkplugSettings, mqtt_settings: MqttSettings, state_dir: str | Path, *,
                 regions: tuple[str, ...] | list[str] = (), maps: tuple[str, ...] | list[str] = (),
                 signal: bool = True, judged: Mapping[str, str] | None = None, password: str | None = None,
                 clock: Clock | None = None) -> None:
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
        self.device.declare(declared_readings(regions, maps, signal=signal, judged=judged))
        self._seq = SeqCounter()
        self.host = PrimaryHost(settings.primary_host_id) if settings.primary_host_id else None
        self._limiter = BirthLimiter(settings.rebirth_min_interval_s)
        self._lock = threading.RLock()
        self._wake = threading.Condition(self._lock)
        self.born = self._birth_wanted = self._restart_wanted = self._closing = False
        self._alerts_seen = 0
        self._counts = dict.fromkeys(COUNTER_NAMES, 0)
        self._refusals = ncmd.RefusalLog(log)
        # spec: clean session (v5: clean start, no session expiry), the NDEATH as will
        self.session = MqttSession(mqtt_settings, client_id=self.client_id, label="Sparkplug", logger=log,
                                   password=password, clean_start=True)
        self._client = self.session.client
        self.session.before_connect(self._on_pre_connect)
        self.session.on_refused(self._on_refused)
        # spec: QoS 1, subscribed before the NBIRTH (births wait for the SUBACK: on_ready)
        self.session.subscribe(self.topics.node("NCMD"), 1, self._on_ncmd, what="rebirth requests (NCMD)")
        if self.host is not None:
            self.session.subscribe(self.host.topic, 1, self._on_host_message, what="the primary host's STATE")
        self.session.on_connected(self._on_connected)
        self.session.on_ready(self._on_ready)
        self.session.on_disconnected(self._on_disconnected)
        self._worker = threading.Thread(target=self._run, name="edgedsm-sparkplug", daemon=True)
        self._started = False

    def start(self) -> SparkplugSink:
        """Start connecting in the background (returns at once)."""
        self._started = True
        self._worker.start()
        self.session.start()
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

    def stopping(self, laser: LaserState, t: float) -> None:
        """The daemon stops (``FanOut.stopping``, before :meth:`close` and its NDEATH): a last
        DDATA with the laser as confirmed at stop and no time to dry, so a host's last values of
        them are not ``on`` and an extrapolation (the NDEATH then marks every metric stale)."""
        with self._lock:
            regions = [name.removeprefix("regions/").removesuffix("/time_to_dry_s")
                       for name in self.device.names() if name.endswith("/time_to_dry_s")]
        readings = {"laser": Reading(DataType.STRING, laser)}
        readings.update((f"regions/{region}/time_to_dry_s", Reading(DataType.DOUBLE, None, "s")) for region in regions)
        self._record(readings, t)

    def close(self, timeout_s: float) -> None:
        """Publish NDEATH (spec: before an intentional disconnect), disconnect, stop the threads."""
        deadline = time.monotonic() + timeout_s
        with self._lock:
            if self._closing:
                return
            self._closing = True
            connected, self.born = self.connected, False
            self._wake.notify_all()
        if self._started:
            self._worker.join(timeout=max(0.05, (deadline - time.monotonic()) / 3))  # no restart under way
            if connected:
                self._send_death(max(0.0, min(0.5, deadline - time.monotonic())))
        self.session.close(deadline - time.monotonic(), reasoncode=self._disconnect_reason())

    # -- health, for tests and the docs -----------------------------------------------------------

    @property
    def connected(self) -> bool:
        return self.session.connected.is_set()

    def counters(self) -> dict[str, int]:
        with self._lock:
            return {"connects": self.session.connects, "disconnects": self.session.disconnects, **self._counts}

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
        self.session.publish_and_wait(self.topics.node("NDEATH"), self._death_payload(bdseq), qos=1, retain=False,
                                      timeout=wait_s)

    def _disconnect_reason(self) -> ReasonCode | None:
        # MQTT 5: 'Disconnect with Will Message' so the broker sends the NDEATH too
        # (spec: tck-id-payloads-ndeath-will-message-publisher-disconnect-mqtt50)
        if self._client.protocol != mqtt.MQTTv5:
            return None
        return ReasonCode(PacketTypes.DISCONNECT, "Disconnect with will message")

    # -- the worker: births when allowed, session restarts ----------------------------------------

    def _can_birth(self) -> bool:
        return self.session.ready.is_set() and (self.host is None or self.host.online)

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
        self.session.restart(self._disconnect_reason())

    # -- session hooks (paho's network thread) ------------------------------------------------------

    def _on_pre_connect(self) -> None:
        # the will is the NDEATH with the bdSeq of this CONNECT; the NBIRTH will repeat it
        with self._lock:
            self._connect_bdseq = self._bdseq.next()
            self._client.will_set(self.topics.node("NDEATH"), self._death_payload(self._connect_bdseq), qos=1,
                                  retain=False)

    def _commit_bdseq(self) -> None:
        """A CONNECT went out with ``_connect_bdseq``, accepted or not: it is used (lock held)."""
        if self._connect_bdseq is not None:
            self._bdseq.commit(self._connect_bdseq)

    def _on_refused(self, reason: str) -> None:
        with self._lock:
            self._commit_bdseq()

    def _on_connected(self) -> None:
        with self._lock:
            self._commit_bdseq()
            self.session_bdseq = self._connect_bdseq
            self.born, self._birth_wanted = False, True
        log.info("Sparkplug session with bdSeq %s%s", self.session_bdseq,
                 f"; waiting for primary host {self.host.host_id!r}" if self.host and not self.host.online else "")

    def _on_ready(self) -> None:
        with self._lock:
            self._wake.notify_all()  # subscribed: a birth may go out

    def _on_disconnected(self) -> None:
        with self._lock:
            self.born = False

    def _on_ncmd(self, message: mqtt.MQTTMessage) -> None:
        self._on_command(bytes(message.payload), bool(message.retain))

    def _on_host_message(self, message: mqtt.MQTTMessage) -> None:
        self._on_host_state(bytes(message.payload))

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
