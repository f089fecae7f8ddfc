"""Command bounds and reply-topic rules, without a broker (the wire is tested in test_mqtt.py)."""

from __future__ import annotations

import json

import pytest

from edgedsm.publish import Topics
from edgedsm.publish.command_channel import (
    COMMAND_MAX_DEPTH,
    RESPONSE_TOPIC_MAX,
    json_depth_exceeds,
    response_topic_refusal,
)

TOPICS = Topics.of("edgedsm", "line3")
OWN = TOPICS.reply("laser")


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


@pytest.mark.parametrize(("topic", "allowed"), [
    (OWN, True),
    ("ops/replies/7", True),
    ("edgedsmx/replies", True),              # only the prefix as a whole level counts
    (TOPICS.alerts, False),
    (TOPICS.state, False),
    (TOPICS.reply("dark"), False),           # another command's reply topic
    ("edgedsm/other/cmd/laser/reply", False),
    ("edgedsm", False),
    ("ops/+/x", False),
    ("ops/#", False),
    ("$SYS/broker", False),
    ("r" * (RESPONSE_TOPIC_MAX + 1), False),
])
def test_replies_go_only_to_the_own_reply_topic_or_outside_our_prefix(topic, allowed):
    why = response_topic_refusal(topic, OWN, TOPICS)
    assert (why is None) is allowed
    if why is not None:
        assert "response topic" in why
