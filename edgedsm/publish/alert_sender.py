"""The alert sender: a worker that publishes stored alerts (QoS 1, ``alerts_in_flight`` at a
time) and forgets each one when the broker acknowledges it (PUBACK).

Acknowledgements arrive on paho's network thread and are only handed over here, so the SQLite
write (with its fsync) never stalls the network thread. Unacknowledged alerts are sent again by
paho after a reconnection, and from the store after a restart: *at least once*.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque

import paho.mqtt.client as mqtt
from paho.mqtt.enums import MQTTErrorCode
from paho.mqtt.reasoncodes import ReasonCode

from edgedsm.publish.alertstore import AlertStore
from edgedsm.publish.counters import Counters

log = logging.getLogger(__name__)

WORKER_POLL_S = 0.25  # how often the idle worker looks at the stop flag (and retries the disk)


class AlertSender:
    """Publishes what ``store`` holds on ``topic`` while ``connected`` is set."""

    def __init__(self, store: AlertStore, client: mqtt.Client, topic: str, connected: threading.Event,
                 counters: Counters, *, in_flight: int) -> None:
        self.store = store
        self._client = client
        self._topic = topic
        self._connected = connected
        self._counters = counters
        self._in_flight_max = in_flight
        self._acks: deque[tuple[int, ReasonCode]] = deque()  # appended by paho's thread
        self._inflight: dict[int, int] = {}                   # paho mid -> alert seq (this thread)
        self._sent_upto = 0                                    # highest seq handed to paho
        self._wake = threading.Event()
        self._stop = threading.Event()
        self.thread = threading.Thread(target=self._work, name="edgedsm-mqtt-alerts", daemon=True)

    def start(self) -> None:
        self.thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._wake.set()

    def wake(self) -> None:
        """Something to do: a new alert, a (re)connection."""
        self._wake.set()

    def on_publish(self, mid: int, reason: ReasonCode) -> None:
        """paho's on_publish (its message lock held): only hand the ack over."""
        self._acks.append((mid, reason))
        self._wake.set()

    def flush(self, timeout: float) -> bool:
        """Wait at most ``timeout`` s until every stored alert is acknowledged; True if so."""
        deadline = time.monotonic() + timeout
        while len(self.store) > 0:
            if time.monotonic() >= deadline:
                return False
            self._wake.set()
            time.sleep(0.02)
        return True

    def _work(self) -> None:
        while not self._stop.is_set():
            self._wake.wait(WORKER_POLL_S)
            self._wake.clear()
            try:
                self._settle_acks()
                self.store.retry()
                self._send()
            except Exception:  # keep the worker alive; the store still holds every alert
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
                self._counters.add("alerts_refused")
                log.error("broker refused alert %d (%s); dropped", seq, reason)
            else:
                self._counters.add("alerts_acked")
            self.store.ack(seq)

    def _send(self) -> None:
        room = self._in_flight_max - len(self._inflight)
        if room <= 0 or not self._connected.is_set():
            return
        for item in self.store.pending(after_seq=self._sent_upto, limit=room):
            if not self._connected.is_set():
                return
            info = self._client.publish(self._topic, item.payload, qos=1)
            if info.rc not in (MQTTErrorCode.MQTT_ERR_SUCCESS, MQTTErrorCode.MQTT_ERR_NO_CONN):
                log.error("paho refused alert %d: %s; will retry", item.seq, mqtt.error_string(info.rc))
                return
            # NO_CONN still means "stored by paho and sent after the reconnection".
            self._inflight[info.mid] = item.seq
            self._sent_upto = item.seq
            self._counters.add("alerts_sent")
