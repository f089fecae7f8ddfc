"""Command bounds, authorisation and the reply topic, without a broker (the wire is tested in
tests/integration/test_mqtt.py and test_command_security.py)."""

from __future__ import annotations

import json
import threading

import pytest
from paho.mqtt.client import MQTTMessage
from paho.mqtt.packettypes import PacketTypes
from paho.mqtt.properties import Properties

from edgedsm.publish import Topics
from edgedsm.publish.command_auth import READ_ONLY, CommandVerifier, sign
from edgedsm.publish.command_channel import COMMAND_MAX_DEPTH, CommandChannel, json_depth_exceeds
from edgedsm.publish.counters import Counters

TOPICS = Topics.of("edgedsm", "line3")


@pytest.mark.parametrize(("payload", "too_deep"), [
    (b"{}", False),
    (json.dumps({"a": [[[[[[[1]]]]]]]}).encode(), False),   # 8 levels: the limit itself
    (json.dumps({"a": [[[[[[[[1]]]]]]]]}).encode(), True),  # 9 levels
    (b"[" * 100_000, True),                                  # unbalanced: still a linear scan
    (json.dumps({"s": "[[[[[[[[[[[[[[[[{{{{{{{{"}).encode(), False),    # brackets inside a string
    (b'{"s": "\\"[[[[[[[[[[[[[["}', False),                 # an escaped quote does not end it
    (b"]]]]]]]]]]]][", False),
])
def test_depth_is_counted_outside_strings(payload, too_deep):
    assert COMMAND_MAX_DEPTH == 8
    assert json_depth_exceeds(payload, COMMAND_MAX_DEPTH) is too_deep


KEYS = {"alice": b"a" * 32}
NOW = 1_733_260_000.0


class Recorder:
    """The channel's publish function."""

    def __init__(self) -> None:
        self.replies: list[tuple[str, dict, object]] = []
        self.done = threading.Event()

    def __call__(self, topic: str, payload: bytes | str, **kwargs) -> None:
        self.replies.append((topic, json.loads(payload), kwargs.get("properties")))
        self.done.set()


@pytest.fixture()
def rig():
    recorder, ran = Recorder(), []

    def handler(name, command):
        ran.append((name, command.model_dump()))
        return {"laser": "on"} if name == "laser" else None

    channel = CommandChannel(TOPICS, recorder, handler, Counters(), mqtt5=True,
                             verifier=CommandVerifier(KEYS, max_age_s=30.0), clock=lambda: NOW)
    channel.start()
    yield channel, recorder, ran
    channel.stop()


def deliver(channel, recorder, name: str, payload: dict | bytes, *, topic: str | None = None,
            retain: bool = False, properties: Properties | None = None) -> dict:
    message = MQTTMessage(topic=(topic or TOPICS.command(name)).encode())
    message.payload = payload if isinstance(payload, bytes) else json.dumps(payload).encode()
    message.retain = retain
    if properties is not None:
        message.properties = properties
    recorder.done.clear()
    channel.receive(message)
    assert recorder.done.wait(5), "no reply"
    return recorder.replies[-1]


def signed(name: str, args: dict, *, device: str = "line3", now: float = NOW, nonce: str | None = None) -> dict:
    return {**sign("alice", KEYS["alice"], Topics.of("edgedsm", device).command(name), args, now=now, nonce=nonce),
            "request_id": "r1"}


def test_a_signed_laser_command_runs_and_an_unsigned_one_does_not(rig):
    channel, recorder, ran = rig
    topic, reply, _ = deliver(channel, recorder, "laser", {"state": "on", "request_id": "r0"})
    assert (topic, reply["ok"], reply["request_id"]) == (TOPICS.reply("laser"), False, "r0")
    assert reply["error"].startswith("not signed: issued, nonce, key_id, sig missing")
    topic, reply, _ = deliver(channel, recorder, "laser", signed("laser", {"state": "on"}))
    assert (topic, reply["ok"], reply["result"]) == (TOPICS.reply("laser"), True, {"laser": "on"})
    assert ran == [("laser", {"state": "on"})]


@pytest.mark.parametrize("case", ["replayed", "expired", "other device", "retained", "unknown key"])
def test_refused_signed_commands_never_reach_the_handler(rig, case):
    channel, recorder, ran = rig
    payload = signed("dark", {}, nonce="n" * 32)
    retain = False
    if case == "replayed":
        assert deliver(channel, recorder, "dark", payload)[1]["ok"] is True
        ran.clear()
    elif case == "expired":
        payload = signed("dark", {}, now=NOW - 31)
    elif case == "other device":
        payload = signed("dark", {}, device="line4")
    elif case == "retained":
        retain = True
    else:
        payload["key_id"] = "mallory"
    _, reply, _ = deliver(channel, recorder, "dark", payload, retain=retain)
    assert reply["ok"] is False
    assert {"replayed": "replayed", "expired": "expired: issued 31 s ago", "other device": "bad signature",
            "retained": "retained commands are refused", "unknown key": "unknown key id"}[case] in reply["error"]
    assert ran == []


def test_without_a_key_the_daemon_is_read_only_but_publish_maps_is_open():
    recorder, ran = Recorder(), []
    channel = CommandChannel(TOPICS, recorder, lambda name, command: ran.append(name), Counters(), mqtt5=True)
    channel.start()
    try:
        for name, args in [("laser", {"state": "on"}), ("rebaseline", {}), ("dark", {}), ("record", {})]:
            _, reply, _ = deliver(channel, recorder, name, signed(name, args))
            assert (reply["ok"], reply["error"]) == (False, READ_ONLY)
        assert deliver(channel, recorder, "publish_maps", {"request_id": 2})[1]["ok"] is True
    finally:
        channel.stop()
    assert ran == ["publish_maps"]


def test_replies_ignore_the_response_topic_and_echo_the_correlation_data(rig):
    channel, recorder, _ = rig
    for response_topic in ["homeassistant/switch/x/config", "edgedsm/line4/cmd/laser", "ops/replies"]:
        properties = Properties(PacketTypes.PUBLISH)
        properties.ResponseTopic = response_topic
        properties.CorrelationData = b"c-7"
        topic, reply, sent = deliver(channel, recorder, "publish_maps", {"request_id": 7}, properties=properties)
        assert (topic, reply["ok"], sent.CorrelationData) == (TOPICS.reply("publish_maps"), True, b"c-7")
    assert {topic for topic, _, _ in recorder.replies} == {TOPICS.reply("publish_maps")}
