"""A test Sparkplug host: a paho client that records every spBv1.0 message with its QoS and
retain flag, decodes payloads with the independent wire reader (tests/sparkplug_decoder.py),
and sends NCMD and STATE messages as a host application would."""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import paho.mqtt.client as mqtt
import pytest
from helpers_mqtt import WAIT_S, wait_until
from paho.mqtt.enums import CallbackAPIVersion
from sparkplug_decoder import DecodedPayload, decode


@dataclass
class SpMessage:
    topic: str
    qos: int
    retain: bool
    raw: bytes
    arrived: float

    @property
    def kind(self) -> str:
        """NBIRTH, DDATA, ... (the message_type topic element)."""
        return self.topic.split("/")[2]

    @property
    def payload(self) -> DecodedPayload:
        return decode(self.raw)


class SparkplugHost:
    """Subscribes to ``spBv1.0/#`` at QoS 1 (so the QoS it receives is the one published)."""

    def __init__(self, port: int) -> None:
        self.port = port
        self.messages: list[SpMessage] = []
        self._lock = threading.Lock()
        self._subscribed = threading.Event()
        self.client = mqtt.Client(CallbackAPIVersion.VERSION2, protocol=mqtt.MQTTv311)
        self.client.reconnect_delay_set(0.05, 0.3)
        self.client.on_connect = lambda client, *args: client.subscribe("spBv1.0/#", qos=1)
        self.client.on_subscribe = lambda *args: self._subscribed.set()
        self.client.on_message = self._on_message

    def _on_message(self, client: mqtt.Client, userdata: Any, message: mqtt.MQTTMessage) -> None:
        with self._lock:
            self.messages.append(SpMessage(message.topic, message.qos, bool(message.retain), bytes(message.payload),
                                           time.monotonic()))

    def start(self) -> SparkplugHost:
        self.client.connect_async("127.0.0.1", self.port, keepalive=10)
        self.client.loop_start()
        if not self._subscribed.wait(WAIT_S):
            pytest.fail(f"the test host could not subscribe on port {self.port}")
        return self

    def expect_resubscribe(self) -> None:
        """Before a broker restart: :meth:`wait_subscribed` then waits for the new subscription."""
        self._subscribed.clear()

    def wait_subscribed(self) -> None:
        if not self._subscribed.wait(WAIT_S):
            pytest.fail("the test host did not subscribe again")

    def stop(self) -> None:
        self.client.disconnect()
        self.client.loop_stop()

    def of(self, kind: str) -> list[SpMessage]:
        with self._lock:
            return [m for m in self.messages if m.kind == kind]

    def all(self) -> list[SpMessage]:
        with self._lock:
            return list(self.messages)

    def wait_for(self, kind: str, what: str, predicate: Callable[[SpMessage], bool] = lambda m: True,
                 count: int = 1, timeout: float = WAIT_S) -> list[SpMessage]:
        found: list[SpMessage] = []

        def check() -> bool:
            found[:] = [m for m in self.of(kind) if predicate(m)]
            return len(found) >= count

        wait_until(check, timeout, what)
        return found

    def clear(self) -> None:
        with self._lock:
            self.messages.clear()

    def send(self, topic: str, payload: bytes, qos: int = 0, retain: bool = False) -> None:
        self.client.publish(topic, payload, qos=qos, retain=retain).wait_for_publish(WAIT_S)

    def state(self, host_id: str, online: bool, timestamp_ms: int) -> None:
        """A primary host's STATE (spec: JSON, QoS 1, retained)."""
        self.send(f"spBv1.0/STATE/{host_id}", json.dumps({"online": online, "timestamp": timestamp_ms}).encode(),
                  qos=1, retain=True)
