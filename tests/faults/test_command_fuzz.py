"""Fuzzing the command payloads against the real command channel's validation (config files are
fuzzed in tests/unit/config/test_config_fuzz.py). Property: every non-empty message on ``cmd/<name>``
gets exactly one reply, a JSON object with ``ok`` true, or ``ok`` false and a reason; never an
exception, never no reply. (An empty payload is how a retained message is cleared: no reply.)
"""

from __future__ import annotations

import json
import threading
import time
from collections import Counter
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from paho.mqtt.client import MQTTMessage

from edgedsm.publish import Topics
from edgedsm.publish.command_channel import COMMAND_BACKLOG, CommandChannel
from edgedsm.publish.commands import COMMANDS, Command
from edgedsm.publish.counters import Counters

pytestmark = [pytest.mark.faults]

TOPICS = Topics.of("edgedsm", "fuzz")
NAMES = [*COMMANDS, "self_destruct", "", "laser/x", "ünïcode"]
REPLY_WAIT_S = 5.0

json_scalars = st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False) | st.text(max_size=20)
json_values = st.recursive(json_scalars, lambda inner: st.lists(inner, max_size=4)
                           | st.dictionaries(st.text(max_size=10), inner, max_size=4), max_leaves=30)
command_objects = st.fixed_dictionaries(
    {}, optional={"state": st.sampled_from(["on", "off", "auto", "dim", ""]) | json_values,
                  "request_id": st.text(max_size=200) | st.integers() | json_values,
                  "extra": json_values})
payloads = (st.binary(min_size=1, max_size=64)
            | command_objects.map(lambda d: json.dumps(d).encode())
            | json_values.map(lambda v: json.dumps(v).encode())
            | st.integers(1, 40).map(lambda n: b"[" * n + b"]" * n)
            | st.text(min_size=1).map(lambda s: s.encode("utf-8", "surrogatepass")))


class Recorder:
    """The channel's publish function: records every reply."""

    def __init__(self) -> None:
        self.replies: list[tuple[str, dict[str, Any]]] = []
        self.lock = threading.Lock()

    def __call__(self, topic: str, payload: bytes | str, **kwargs: Any) -> None:
        with self.lock:
            self.replies.append((topic, json.loads(payload)))

    def count(self) -> int:
        with self.lock:
            return len(self.replies)


def handler(name: str, command: Command) -> dict[str, Any]:
    """A daemon-like handler: refuses some commands, takes a moment (so the backlog fills)."""
    time.sleep(0.001)
    if name == "dark":
        return {"ok": False, "error": "no relay"}
    return {"done": command.model_dump()}


@pytest.fixture(scope="module")
def channel() -> Any:
    recorder = Recorder()
    channel = CommandChannel(TOPICS, recorder, handler, Counters(), mqtt5=True)
    channel.start()
    yield channel, recorder
    channel.stop()


def message(name: str, payload: bytes, retain: bool) -> MQTTMessage:
    msg = MQTTMessage(topic=TOPICS.command(name).encode("utf-8"))
    msg.payload = payload
    msg.retain = retain
    return msg


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(batch=st.lists(st.tuples(st.sampled_from(NAMES), payloads, st.booleans()),
                      min_size=1, max_size=2 * COMMAND_BACKLOG))
def test_every_command_payload_gets_one_clear_reply(channel: Any, batch: list[tuple[str, bytes, bool]]) -> None:
    channel_, recorder = channel
    before = recorder.count()
    for name, payload, retain in batch:  # as fast as paho's thread would hand them over
        channel_.receive(message(name, payload, retain))
    expected = before + len(batch)
    deadline = time.monotonic() + REPLY_WAIT_S
    while recorder.count() < expected and time.monotonic() < deadline:
        time.sleep(0.002)
    time.sleep(0.01)  # a reply too many would show up now
    with recorder.lock:
        replies = recorder.replies[before:]
    assert len(replies) == len(batch), (batch, replies)
    per_topic = Counter(topic for topic, _ in replies)
    assert per_topic == Counter(TOPICS.reply(name) for name, _, _ in batch)
    for _, reply in replies:
        assert isinstance(reply["ok"], bool)
        if not reply["ok"]:
            assert isinstance(reply["error"], str) and reply["error"].strip(), reply
            assert "internal error" not in reply["error"] and "Traceback" not in reply["error"], reply
